"""Drift trends and fleets, the pipeline glue: tables and PNG plots (matplotlib Agg).

The numbers come from calib_core.drift, the rows from storage.queries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from calib_core import drift, params
from pipelines import shared_reference
from storage import queries
from storage.db import Archive

if TYPE_CHECKING:
    import pandas as pd  # imported where a table is made: a recall needs none

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
CONDITION_BIN_C = 5.0  # runs whose lab temperatures differ by less are one condition
TREND_MIN_RUNS = 3  # a drift needs three calibrations (calib_core.drift.fit_trend)


@dataclass(frozen=True)
class Pooled:
    """The runs a drift in time compares: those at one condition (lab temperature)."""

    indices: list[int]  # into the runs given, oldest first as given
    condition: str  # "20 deg C", "temperature not recorded"
    conditions: list[str]  # every condition of the runs given, e.g. ["0 deg C", "20 deg C"]
    note: str  # why fewer runs than given, or why no trend ("" when all pooled)

    def said(self, n_runs: int) -> str:
        """e.g. "4 of 4 runs, all at 20 deg C"."""
        every = "all " if len(self.indices) == n_runs else ""
        return f"{len(self.indices)} of {n_runs} runs, {every}at {self.condition}"


def _condition(t: float | None) -> str:
    if t is None or not math.isfinite(t):
        return "temperature not recorded"
    return f"{CONDITION_BIN_C * round(t / CONDITION_BIN_C):g} deg C"


def pooled_runs(temperatures: list[float | None], reference_c: float = 20.0) -> Pooled:
    """Which runs a drift in time may pool: like with like. Runs at different lab
    temperatures (a thermal campaign) differ by the temperature effect, which a straight
    line over the dates would read as drift; they are compared by temperature (the
    thermal model) instead. The trend takes the runs of the condition with most runs
    (ties: nearest `reference_c`); runs without a temperature form their own condition.
    """
    keys = [_condition(t) for t in temperatures]
    groups: dict[str, list[int]] = {}
    for i, k in enumerate(keys):
        groups.setdefault(k, []).append(i)

    def rank(item: tuple[str, list[int]]) -> tuple[int, float]:
        name, idx = item
        temps = [temperatures[i] for i in idx if temperatures[i] is not None]
        dist = abs(temps[0] - reference_c) if temps else math.inf
        return (-len(idx), dist)

    condition, indices = min(groups.items(), key=rank)
    conditions = sorted(groups, key=lambda k: rank((k, groups[k]))[1])
    note = ""
    if len(groups) > 1:
        note = (
            f"the runs are at {len(groups)} conditions ({', '.join(conditions)}): "
            f"a drift in time compares the {len(indices)} at {condition}; the others "
            "differ by the temperature effect (thermal model), not by drift"
        )
        if len(indices) < TREND_MIN_RUNS:
            note = (
                f"the runs are at {len(groups)} conditions ({', '.join(conditions)}), "
                f"at most {len(indices)} at one: compared by temperature (calib thermal "
                "show), not fitted as a drift in time"
            )
    return Pooled(indices, condition, conditions, note)


def days_since_epoch(when: datetime | pd.Timestamp) -> float:
    """Time-zone-aware datetime -> days since 1970-01-01 UTC (the drift module's time axis)."""
    if type(when) is not datetime:  # a pandas Timestamp (or what one is made of)
        import pandas as pd

        when = pd.Timestamp(when).to_pydatetime()
    return (when - EPOCH).total_seconds() / 86400.0


def date_of_days(days: float) -> str:
    import pandas as pd

    return (pd.Timestamp(EPOCH) + pd.Timedelta(days=days)).date().isoformat()


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
    import pandas as pd  # loaded already: `df` is a frame

    temps = [None if pd.isna(t) else float(t) for t in df["temperature_c"]]  # NULL: NaN or None
    pooled = pooled_runs(temps)
    if len(pooled.indices) < TREND_MIN_RUNS and len(pooled.conditions) > 1:
        raise ValueError(f"{name} of {serial}: {pooled.note}")
    all_runs = len(df)
    df = df.iloc[pooled.indices].reset_index(drop=True)
    stds = [None if pd.isna(s) else s for s in df["std"]]
    # Runs on one reference share its Type B: a generalised least-squares trend when every
    # point has a budget (pipelines.shared_reference), else the independent fit.
    shared = shared_reference.trend_inputs(archive, list(df["run_id"]), name, stds)
    if shared is None:
        trend = drift.fit_trend(df["day"].to_numpy(), df["value"].to_numpy(), stds)
    else:
        trend = drift.fit_trend_shared(df["day"].to_numpy(), df["value"].to_numpy(), *shared)
    if profile is None:
        latest = queries.latest_calibration(archive, serial)
        profile = None if latest is None else latest.profile_name
    low, high = _tolerance(profile, name)
    forecast = (
        drift.forecast_exit(trend, low, high) if math.isfinite(low) or math.isfinite(high) else None
    )
    summary = {
        "serial": serial,
        "parameter": name,
        "unit": df["unit"].iloc[0],
        "calibrations": int(len(df)),
        "pooled": pooled.said(all_runs),
        "pooled_runs": df["run_id"].tolist(),
        "conditions": pooled.conditions,
        "note": pooled.note or None,
        "slope_per_year": trend.slope * 365.25,
        "slope_std_per_year": trend.slope_std * 365.25,
        "fit": "independent" if shared is None else "shared reference (GLS)",
        "references": None if shared is None else len(set(shared[2])),
        "birge_ratio": None if shared is None else trend.sigma,
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
    df = queries.fleet_history(archive, model, name)
    if df.empty:
        raise LookupError(f"no archived values of {name} for device model {model!r}")
    temps = df["temperature_c"].astype(float).to_numpy()
    bins = drift.fleet_statistics(df["value"].to_numpy(), temps, df["serial"].tolist(), bin_c=bin_c)
    import pandas as pd

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
    import pandas as pd

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    x = pd.to_datetime(df["started_at"], utc=True)
    ax.errorbar(
        x,
        df["value"],
        yerr=df["std"].astype(float).fillna(0.0),
        fmt="o",
        ms=4,
        label="calibrations",
    )
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
    ax.errorbar(
        table["temperature"][ok],
        table["mean"][ok],
        yerr=table["std"][ok].fillna(0.0),
        fmt="s-",
        color="k",
        label="mean ± std per bin",
    )
    ax.set_xlabel("temperature (deg C)")
    ax.set_ylabel(df["unit"].iloc[0])
    ax.set_title(f"{name} across {model} ({df['serial'].nunique()} units)")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
