"""Thermal compensation, the pipeline glue: a campaign (the runs of one serial at several
temperature points) fitted and archived as a thermal model.

The numbers come from calib_core.thermal (the science of the same name), the rows
from storage.queries. `fit_campaign_step` / `thermal_fit`: the runs of a serial
(environment.temperature_c of each run's manifest, or the temperature its current
revision's parameters hold when a chamber offset was corrected), in the order they were run
(which also tells heating from cooling). The Prefect flow `thermal_campaign` is in
pipelines.flows.
"""

from __future__ import annotations

from typing import Any

from calib_core import thermal
from calib_core.calibration import Calibration, StepRecord
from storage import queries
from storage import thermal as thermal_store
from storage.db import Archive
from storage.queries.impact import calibration_temperatures

DEFAULT_FIT = {
    "max_order": thermal.DEFAULT_MAX_ORDER,
    "alpha": thermal.DEFAULT_ALPHA,
    "min_range_c": thermal.MIN_RANGE_C,
    "t_ref": None,
}


def campaign_from_archive(
    archive: Archive, serial: str, run_ids: list[str] | None = None
) -> tuple[list[thermal.CampaignPoint], list[dict[str, Any]]]:
    """The campaign of a serial: its current calibrations with a temperature, in run order.

    Returns (points, rows) where rows are storage.queries.campaign_calibrations
    entries (calibration ids, run ids) of the points, same order.
    Raises ValueError when runs lack environment.temperature_c.
    """
    rows = queries.campaign_calibrations(archive, serial, run_ids)
    # A revision corrected for a chamber found offset (`calib impact`) holds the true
    # temperature of its parameters: it takes the place of the manifest's reading.
    true_t = calibration_temperatures(archive, [r["calibration_id"] for r in rows])
    rows = [
        {**r, "temperature_c": true_t[r["calibration_id"]]}
        if true_t.get(r["calibration_id"]) is not None
        else r
        for r in rows
    ]
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
    *,
    reason: str | None = None,
) -> dict[str, Any]:
    """Fit the campaign of `serial` found in the archive and archive the model.

    `reason`: why it is fitted again (e.g. an out-of-tolerance chamber, `calib impact`),
    kept in the model's info.

    Returns a JSON-able summary: model_id, serial, runs, t_ref, t_min, t_max,
    orders, hysteresis (per parameter where two directions were run), benefit.
    """
    points, rows = campaign_from_archive(archive, serial, run_ids)
    model, step = fit_campaign_step(points, settings)
    model.info.update(
        {
            "serial": serial,
            "runs": [r["run_id"] for r in rows],
            **({"reason": reason} if reason else {}),
            "step": {
                "name": step.name,
                "settings": step.settings,
                "statistics": step.statistics,
                "software_version": step.software_version,
            },
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
