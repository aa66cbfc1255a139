"""Thermal campaigns, applying archived calibrations to new data, drift trends and fleets.

Glue only: the numbers come from calib_core.thermal and calib_core.drift, the
rows from storage.thermal and storage.queries.

- `fit_campaign_step` / `thermal_fit`: the runs of one serial at several
  temperature points (environment.temperature_c of each run's manifest), in the
  order they were run (which also tells heating from cooling), fitted and
  archived as a thermal model.
- `apply_calibration`: the latest valid calibration of a serial as of a date,
  with its thermal model, applied to new raw data in any ingest format and
  written as Parquet or CSV.
- `trend_report`, `fleet_report`: tables and PNG plots (matplotlib Agg).
- `thermal_campaign`: the Prefect flow (process the run folders, then fit).
"""

from __future__ import annotations

import functools
import math
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from calib_core import drift, params, thermal
from calib_core.calibration import Calibration, StepRecord
from calib_core.recording import Recording
from pipelines.ingest import IngestError, RunSource, discover_runs, load_run, read_mpu6000_file
from pipelines.ingest.mpu6000 import parse_file_name
from pipelines.process import samples_table
from storage import queries
from storage import thermal as thermal_store
from storage.db import Archive

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
DEFAULT_FIT = {
    "max_order": thermal.DEFAULT_MAX_ORDER,
    "alpha": thermal.DEFAULT_ALPHA,
    "min_range_c": thermal.MIN_RANGE_C,
    "t_ref": None,
}


def days_since_epoch(when: datetime | pd.Timestamp) -> float:
    """Time-zone-aware datetime -> days since 1970-01-01 UTC (the drift module's time axis)."""
    return (pd.Timestamp(when).to_pydatetime() - EPOCH).total_seconds() / 86400.0


def date_of_days(days: float) -> str:
    return (pd.Timestamp(EPOCH) + pd.Timedelta(days=days)).date().isoformat()


# --- thermal campaign ------------------------------------------------------------


def campaign_from_archive(
    archive: Archive, serial: str, run_ids: list[str] | None = None
) -> tuple[list[thermal.CampaignPoint], list[dict[str, Any]]]:
    """The campaign of a serial: its current calibrations with a temperature, in run order.

    Returns (points, rows) where rows are storage.thermal.campaign_calibrations
    entries (calibration ids, run ids) of the points, same order.
    Raises ValueError when runs lack environment.temperature_c.
    """
    rows = thermal_store.campaign_calibrations(archive, serial, run_ids)
    without = [r["run_id"] for r in rows if r["temperature_c"] is None]
    if without and run_ids:
        raise ValueError(
            f"runs {without} of {serial} have no environment.temperature_c in their manifest: "
            f"a thermal campaign needs the temperature of every run"
        )
    rows = [r for r in rows if r["temperature_c"] is not None]
    if not rows:
        raise ValueError(f"no archived run of {serial} has environment.temperature_c")
    temps = [float(r["temperature_c"]) for r in rows]
    directions = thermal.directions_from_sequence(temps)
    # One direction only (a plain series of points) means no hysteresis term.
    if len(set(directions)) == 1:
        directions = [""] * len(rows)
    points = [
        thermal.CampaignPoint(t, Calibration.from_dict(r["document"]), d)
        for t, r, d in zip(temps, rows, directions, strict=True)
    ]
    return points, rows


def fit_campaign_step(
    points: list[thermal.CampaignPoint], settings: dict[str, Any] | None = None
) -> tuple[thermal.ThermalModel, StepRecord]:
    """Pipeline step: campaign points -> ThermalModel, with orders, hysteresis and benefit."""
    cfg = {**DEFAULT_FIT, **(settings or {})}
    unknown = set(cfg) - set(DEFAULT_FIT)
    if unknown:
        raise ValueError(
            f"thermal fit settings: unknown keys {sorted(unknown)}; expected {sorted(DEFAULT_FIT)}"
        )
    pts = thermal.campaign_points(points)
    model = thermal.fit_model(
        pts,
        t_ref=cfg["t_ref"],
        max_order=int(cfg["max_order"]),
        alpha=float(cfg["alpha"]),
        min_range=float(cfg["min_range_c"]),
    )
    gain = thermal.benefit(model, pts)
    model.info["benefit"] = {
        b.name: {"rms_before": b.rms_before, "rms_after": b.rms_after, "rms_holdout": b.rms_holdout}
        for b in gain
    }
    stats = {
        "points": len(points),
        "temperatures": sorted({p.temperature for p in points}),
        "t_ref": model.t_ref,
        "orders": {n: c.order for n, c in model.curves.items()},
        "hysteresis_detected": sorted(
            n for n, c in model.curves.items() if c.hysteresis is not None and c.hysteresis.detected
        ),
    }
    return model, StepRecord("thermal_fit", settings=cfg, statistics=stats)


def thermal_fit(
    archive: Archive,
    serial: str,
    run_ids: list[str] | None = None,
    settings: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Fit the campaign of `serial` found in the archive and archive the model.

    Returns a JSON-able summary: model_id, serial, runs, t_ref, t_min, t_max,
    orders, hysteresis (per parameter where two directions were run), benefit.
    """
    points, rows = campaign_from_archive(archive, serial, run_ids)
    model, step = fit_campaign_step(points, settings)
    model.info.update(
        {
            "serial": serial,
            "runs": [r["run_id"] for r in rows],
            "step": {
                "name": step.name,
                "settings": step.settings,
                "statistics": step.statistics,
                "software_version": step.software_version,
            },  # fmt: skip
        }
    )
    model_id = thermal_store.archive_thermal_model(
        archive, serial, model.to_dict(), [r["calibration_id"] for r in rows]
    )
    return {
        "model_id": model_id,
        "serial": serial,
        "runs": [r["run_id"] for r in rows],
        "t_ref": model.t_ref,
        "t_min": model.t_min,
        "t_max": model.t_max,
        "orders": step.statistics["orders"],
        "hysteresis": {
            n: c.hysteresis.to_dict() for n, c in model.curves.items() if c.hysteresis is not None
        },
        "benefit": model.info["benefit"],
    }


# --- apply -----------------------------------------------------------------------


def read_input(path: Path, serial: str | None = None) -> tuple[dict[str, Recording], float | None]:
    """New raw data in any ingest format -> (segments, manifest temperature or None).

    path : a run folder with run.toml (or the run.toml), a folder of MPU-6000
        files (the runs of `serial`), or one MPU-6000 file.
    """
    path = Path(path)
    if path.is_file() and parse_file_name(path.name) is not None:
        rec = read_mpu6000_file(path)
        return {rec.label or path.stem: rec}, None
    sources = [s for s in discover_runs([path], depth=0) if s.serial in (None, serial)]
    if len(sources) != 1:
        raise IngestError(
            f"expected one run (of serial {serial}) here, found {len(sources)}: "
            f"give a run folder, its run.toml or one MPU-6000 file",
            file=path,
        )
    loaded = load_run(
        sources[0] if sources[0].kind == "manifest" else RunSource(path, "mpu6000", serial)
    )
    return loaded.segments, loaded.manifest.environment.temperature_c


def load_compensation(
    archive: Archive, serial: str, at: datetime | None
) -> tuple[Calibration, float | None, thermal.ThermalModel | None, dict[str, Any]]:
    """(calibration, its temperature, thermal model or None, facts) valid for `serial` at `at`."""
    latest = queries.latest_calibration(archive, serial, at)
    if latest is None:
        when = "now" if at is None else at.isoformat()
        raise LookupError(f"no valid (passed, current) calibration of {serial!r} as of {when}")
    cal = Calibration.from_dict(latest["document"])
    temps = {p["temperature_c"] for p in latest["parameters"] if p["temperature_c"] is not None}
    cal_temp = float(temps.pop()) if len(temps) == 1 else None
    tm = thermal_store.latest_thermal_model(archive, serial, None)
    model = None if tm is None else thermal.ThermalModel.from_dict(tm["document"])
    facts = {
        "serial": serial,
        "run_id": latest["run_id"],
        "calibration_id": latest["calibration_id"],
        "calibration_temperature_c": cal_temp,
        "thermal_model_id": None if tm is None else tm["id"],
    }
    return cal, cal_temp, model, facts


def calibrate_segments(
    segments: dict[str, Recording],
    cal: Calibration,
    cal_temp: float | None,
    model: thermal.ThermalModel | None,
    fallback_temp: float | None = None,
) -> tuple[dict[str, Recording], StepRecord]:
    """Pipeline step: apply calibration (+ thermal model) to each segment."""
    out = {}
    clipped = 0
    for label, rec in segments.items():
        if model is None:
            out[label] = cal.apply(rec)
            continue
        temp = rec.temp if rec.temp is not None else fallback_temp
        if temp is None:
            raise ValueError(
                f"segment {label!r} ({rec.source}): no temperature channel and no "
                f"environment.temperature_c: the thermal model needs a temperature"
            )
        t = np.broadcast_to(np.asarray(temp, dtype=float), (len(rec),))
        clipped += int(np.sum((t < model.t_min) | (t > model.t_max)))
        acc, gyr = model.correct(rec.acc, rec.gyr, t, cal, cal_temp)
        out[label] = Recording(rec.t, acc, gyr, rec.temp, rec.reference, rec.label, rec.source)
    stats = {
        "segments": len(out),
        "samples": sum(len(r) for r in out.values()),
        "thermal_model": model is not None,
        "samples_outside_thermal_range": clipped,
    }
    return out, StepRecord(
        "apply", settings={"calibration_temperature_c": cal_temp}, statistics=stats
    )


def write_samples(table: pa.Table, output: Path) -> Path:
    """Parquet for .parquet / .pq, CSV for .csv; anything else is refused."""
    output = Path(output)
    suffix = output.suffix.lower()
    if suffix in (".parquet", ".pq"):
        pq.write_table(table, output, compression="zstd")
    elif suffix == ".csv":
        pacsv.write_csv(table, output)
    else:
        raise ValueError(
            f"output {output}: unknown suffix {suffix!r}; expected .parquet, .pq or .csv"
        )
    return output


def apply_calibration(
    archive: Archive, serial: str, at: datetime | None, source: Path, output: Path
) -> dict[str, Any]:
    """Calibrate new raw data with the calibration (and thermal model) valid at `at`.

    Returns the facts: which calibration and thermal model were used, samples
    written, samples outside the thermal model's range (clipped), output path.
    """
    if Path(output).suffix.lower() not in (".parquet", ".pq", ".csv"):
        raise ValueError(f"output {output}: expected a .parquet, .pq or .csv file name")
    cal, cal_temp, model, facts = load_compensation(archive, serial, at)
    segments, env_temp = read_input(Path(source), serial)
    done, step = calibrate_segments(segments, cal, cal_temp, model, env_temp)
    write_samples(samples_table(done), Path(output))
    return {**facts, **step.statistics, "output": str(output)}


# --- trends and fleets -------------------------------------------------------------


def _tolerance(profile_name: str | None, name: str) -> tuple[float, float]:
    from pipelines.tolerances import load_profile

    if not profile_name:
        return -math.inf, math.inf
    lim = load_profile(profile_name).limit_for(name)
    return (-math.inf, math.inf) if lim is None else (lim.low, lim.high)


def trend_report(
    archive: Archive,
    serial: str,
    name: str,
    *,
    profile: str | None = None,
    plot: Path | None = None,
) -> dict[str, Any]:
    """Trend of one parameter of a unit over its calibrations, with the tolerance forecast.

    profile : tolerance profile for the band; default the one of the unit's latest run.
    Returns {"table": DataFrame, "trend": Trend, "forecast": Forecast | None, "summary": {...}}.
    """
    params.validate(name)
    df = queries.parameter_history(archive, serial, name)
    if df.empty:
        raise LookupError(f"no archived values of {name} for serial {serial!r}")
    df = df.assign(day=[days_since_epoch(t) for t in df["started_at"]])
    stds = [None if s is None or (isinstance(s, float) and math.isnan(s)) else s for s in df["std"]]
    trend = drift.fit_trend(df["day"].to_numpy(), df["value"].to_numpy(), stds)
    if profile is None:
        latest = queries.latest_calibration(archive, serial)
        profile = None if latest is None else latest["profile_name"]
    low, high = _tolerance(profile, name)
    forecast = (
        drift.forecast_exit(trend, low, high) if math.isfinite(low) or math.isfinite(high) else None
    )
    summary = {
        "serial": serial,
        "parameter": name,
        "unit": df["unit"].iloc[0],
        "calibrations": int(len(df)),
        "slope_per_year": trend.slope * 365.25,
        "slope_std_per_year": trend.slope_std * 365.25,
        "profile": profile,
        "tolerance": [low, high],
        "leaves_tolerance": None
        if forecast is None or forecast.crossing is None
        else date_of_days(forecast.crossing),
        "earliest_exit": None
        if forecast is None or forecast.earliest is None
        else date_of_days(forecast.earliest),
        "out_now": None if forecast is None else forecast.out_now,
    }
    if plot is not None:
        plot_trend(df, trend, forecast, summary, Path(plot))
        summary["plot"] = str(plot)
    table = df[["run_id", "started_at", "value", "std", "temperature_c"]].copy()
    table["fitted"] = trend.value(df["day"].to_numpy())
    return {"table": table, "trend": trend, "forecast": forecast, "summary": summary}


def fleet_report(
    archive: Archive, model: str, name: str, *, bin_c: float = 5.0, plot: Path | None = None
) -> pd.DataFrame:
    """Distribution of a parameter over the units of a device model, per temperature bin."""
    params.validate(name)
    df = thermal_store.fleet_parameter(archive, model, name)
    if df.empty:
        raise LookupError(f"no archived values of {name} for device model {model!r}")
    temps = df["temperature_c"].astype(float).to_numpy()
    bins = drift.fleet_statistics(df["value"].to_numpy(), temps, df["serial"].tolist(), bin_c=bin_c)
    table = pd.DataFrame([b.__dict__ for b in bins])
    if plot is not None:
        plot_fleet(df, table, model, name, Path(plot))
    return table


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    return plt


def plot_trend(df: pd.DataFrame, trend: drift.Trend, forecast, summary: dict, path: Path) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    x = pd.to_datetime(df["started_at"], utc=True)
    ax.errorbar(x, df["value"], yerr=df["std"].astype(float).fillna(0.0), fmt="o", ms=4,
                label="calibrations")  # fmt: skip
    end = (
        trend.t_last + 365.0
        if forecast is None or forecast.crossing is None
        else max(trend.t_last + 30.0, min(forecast.crossing + 30.0, trend.t_last + 3650.0))
    )
    grid = np.linspace(trend.t_first, end, 200)
    gx = pd.to_datetime(EPOCH) + pd.to_timedelta(grid, unit="D")
    ax.plot(gx, trend.value(grid), "-", label=f"trend {summary['slope_per_year']:.3g} /year")
    band = 2.0 * trend.std(grid)
    centre = trend.value(grid)
    ax.fill_between(gx, centre - band, centre + band, alpha=0.2, label="±2 std of the line")
    for lim in summary["tolerance"]:
        if math.isfinite(lim):
            ax.axhline(lim, color="r", ls="--", lw=1)
    ax.set_title(f"{summary['parameter']} of {summary['serial']}")
    ax.set_ylabel(summary["unit"])
    ax.legend(loc="best", fontsize=8)
    fig.autofmt_xdate()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_fleet(df: pd.DataFrame, table: pd.DataFrame, model: str, name: str, path: Path) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax.plot(df["temperature_c"].astype(float), df["value"], ".", alpha=0.4, label="calibrations")
    ok = table["temperature"].notna()
    ax.errorbar(table["temperature"][ok], table["mean"][ok], yerr=table["std"][ok].fillna(0.0),
                fmt="s-", color="k", label="mean ± std per bin")  # fmt: skip
    ax.set_xlabel("temperature (deg C)")
    ax.set_ylabel(df["unit"].iloc[0])
    ax.set_title(f"{name} across {model} ({df['serial'].nunique()} units)")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# --- Prefect flow -------------------------------------------------------------------


@functools.cache
def _flow():
    from prefect import flow

    @flow(name="thermal_campaign")
    def thermal_campaign(
        paths: list[str],
        archive: str | None = None,
        serial: str | None = None,
        settings: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """Process a campaign's run folders (process_batch), then fit and archive the model."""
        from pipelines.flows import process_batch
        from storage.db import resolve_archive

        outcomes = process_batch(paths, archive)
        ok = [o for o in outcomes if o["status"] in ("ok", "duplicate")]
        serials = sorted({o["serial"] for o in ok})
        if serial is None:
            if len(serials) != 1:
                raise ValueError(f"the campaign holds runs of {serials}; name the serial")
            serial = serials[0]
        arch = resolve_archive(archive)
        arch.upgrade()
        run_ids = [o["run_id"] for o in ok if o["serial"] == serial]
        return {"runs": outcomes, "thermal": thermal_fit(arch, serial, run_ids, settings)}

    return thermal_campaign


def __getattr__(name: str):
    # The flow is built on first use so that importing this module does not load Prefect.
    if name == "thermal_campaign":
        return _flow()
    raise AttributeError(name)
