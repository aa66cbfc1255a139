"""Queries of the archive about reference equipment and its effect on results: the runs
that used one piece of it in a period (an out-of-tolerance look-back, ISO/IEC 17025 clause
7.10; `calib impact`), and each run's reference and Type B budget (shared references in
trends and repeatability).
"""

from __future__ import annotations

from datetime import date, datetime
from typing import Any

from sqlalchemy import select

from storage.current import CURRENT, is_current
from storage.db import Archive
from storage.queries._common import (
    IN_CHUNK,
    as_instant,
    where_model_and_start,
)
from storage.queries.equipment import runs_with_equipment
from storage.schema import CalibrationRow, Device, Equipment, Run, RunEquipment

# A run, its unit's serial and the run's own model, procedure and start.
_RUN_OF_UNIT = (Run.run_id, Device.serial, Run.model, Run.procedure, Run.started_at)


def equipment_runs(
    archive: Archive,
    equipment_serial: str,
    since: date | datetime | str | None = None,
    until: date | datetime | str | None = None,
    kind: str | None = None,
) -> list[dict[str, Any]]:
    """The runs whose archived equipment snapshot (`run_equipment`, sealed with each
    revision) names `equipment_serial`, started in [since, until], oldest first.

    Parameters
    ----------
    equipment_serial : the equipment's serial (every kind with this serial unless `kind`).
    since, until : run start, inclusive; dates are whole UTC days; None: open.
    kind : "rate_table", "centrifuge", "thermal_chamber", "daq", "cube", ...

    Returns
    -------
    list of dicts: run_id, serial (the unit), model, procedure, started_at,
    equipment_kind, equipment_model, calibration_due (of the equipment, as recorded with
    the run), verdict and revision of the run's current calibration.

    Raises ValueError naming the filter for a malformed value, before any SQL runs.
    """
    equipment = (Equipment.kind, Equipment.model, RunEquipment.calibration_due)
    current = (CalibrationRow.verdict, CalibrationRow.revision)
    stmt = runs_with_equipment(equipment_serial, kind, *_RUN_OF_UNIT, *equipment, *current)
    t0 = as_instant(since, "from", end_of_day=False)
    t1 = as_instant(until, "to", end_of_day=True)
    stmt = stmt.join(CalibrationRow, (CalibrationRow.run_id == Run.id) & CURRENT).order_by(
        Run.started_at, Run.run_id
    )
    stmt = where_model_and_start(stmt, None, t0, t1)
    keys = (
        "run_id",
        "serial",
        "model",
        "procedure",
        "started_at",
        "equipment_kind",
        "equipment_model",
        "calibration_due",
        "verdict",
        "revision",
    )
    with archive.engine().connect() as conn:
        return [dict(zip(keys, row, strict=True)) for row in conn.execute(stmt).all()]


def run_references(archive: Archive, run_ids: list[str]) -> dict[str, dict[str, Any]]:
    """What each run's reference was and how much of each value's uncertainty it carries.

    Parameters
    ----------
    run_ids : full run ids (unknown ones are left out of the answer).

    Returns
    -------
    {run_id: {"equipment": [(kind, serial), ...] sorted, "site": the run's site document,
    "budgets": {parameter: budget document of the current revision's uncertainty step}}}.
    """
    from storage.schema import ProcessingStep

    out: dict[str, dict[str, Any]] = {}
    ids = list(dict.fromkeys(run_ids))
    with archive.engine().connect() as conn:
        for start in range(0, len(ids), IN_CHUNK):
            chunk = ids[start : start + IN_CHUNK]
            for run_id, site, stats in conn.execute(
                select(Run.run_id, Run.site, ProcessingStep.statistics)
                .join(
                    CalibrationRow,
                    (CalibrationRow.run_id == Run.id) & CURRENT,
                )
                .outerjoin(
                    ProcessingStep,
                    (ProcessingStep.calibration_id == CalibrationRow.id)
                    & (ProcessingStep.name == "uncertainty"),
                )
                .where(Run.run_id.in_(chunk))
            ):
                out[run_id] = {
                    "equipment": [],
                    "site": site,
                    "budgets": (stats or {}).get("budgets", {}),
                }
            for run_id, kind, serial in conn.execute(
                select(Run.run_id, Equipment.kind, Equipment.serial)
                .join(RunEquipment, RunEquipment.run_id == Run.id)
                .join(Equipment, Equipment.id == RunEquipment.equipment_id)
                .where(Run.run_id.in_(chunk))
                .order_by(Equipment.kind, Equipment.serial)
            ):
                if run_id in out:
                    out[run_id]["equipment"].append((kind, serial))
    return out


def impact_records(archive: Archive) -> list[dict[str, Any]]:
    """The applied out-of-tolerance look-backs (`calib impact --apply`), newest first.

    An impact record is the set of revisions whose ``reference_correction`` step holds an
    impact (the step's statistics) for the same reason "out-of-tolerance reference
    SERIAL: QUANTITY=VALUE" (the reason of their ``reprocess`` step).

    Returns
    -------
    list of dicts: key (12 hex digits of the reason's SHA-256, the record's address),
    reason, equipment_serial, equipment_kind, quantity, value, unit, face, about,
    applied_at (the first revision's time), period (from, to: as given to the look-back),
    and ``runs``: per revision its run_id, serial
    (the unit), model, procedure, started_at, revision_before, revision (the one written),
    current (whether it still is the run's current revision), verdict_before,
    verdict_after, moved (name, before, after, U_before, change_in_U), temperature_c
    (before, after: a chamber offset's correction, else None), checks_changed (name,
    passed_before, passed_after, detail), what.
    """
    import hashlib

    from storage.schema import ProcessingStep

    step = ProcessingStep.__table__.alias("correction")
    why = ProcessingStep.__table__.alias("why")
    stmt = (
        select(
            *_RUN_OF_UNIT,
            CalibrationRow.revision,
            CalibrationRow.created_at,
            CalibrationRow.superseded_by,
            step.c.settings,
            step.c.statistics,
            why.c.settings,
        )
        .join(Device, Device.id == Run.device_id)
        .join(CalibrationRow, CalibrationRow.run_id == Run.id)
        .join(
            step,
            (step.c.calibration_id == CalibrationRow.id) & (step.c.name == "reference_correction"),
        )
        .join(why, (why.c.calibration_id == CalibrationRow.id) & (why.c.name == "reprocess"))
        .order_by(CalibrationRow.created_at, Run.started_at, Run.run_id)
    )
    records: dict[str, dict[str, Any]] = {}
    with archive.engine().connect() as conn:
        rows = conn.execute(stmt).all()
    for run_id, serial, model, proc, started, rev, created, sup, corr, stats, reprocess in rows:
        impact = (stats or {}).get("impact")
        reason = (reprocess or {}).get("reason")
        if not impact or not reason:  # a correction carried over by a later reprocessing
            continue
        key = hashlib.sha256(reason.encode("utf-8")).hexdigest()[:12]
        rec = records.setdefault(
            key,
            {
                "key": key,
                "reason": reason,
                "equipment_serial": corr.get("equipment_serial"),
                "equipment_kind": corr.get("equipment_kind"),
                "quantity": corr.get("quantity"),
                "value": corr.get("value"),
                "unit": corr.get("unit"),
                "face": corr.get("face"),
                "about": corr.get("about"),
                "applied_at": created,
                "period": impact.get("period") or {"from": "", "to": None},
                "runs": [],
            },
        )
        rec["runs"].append(
            {
                "run_id": run_id,
                "serial": serial,
                "model": model,
                "procedure": proc,
                "started_at": started,
                "revision_before": impact.get("revision_before"),
                "revision": rev,
                "current": is_current(sup),
                "verdict_before": impact.get("verdict_before"),
                "verdict_after": impact.get("verdict_after"),
                "moved": impact.get("moved", []),
                "temperature_c": impact.get("temperature_c"),
                "checks_changed": impact.get("checks_changed", []),
                "what": stats.get("what"),
            }
        )
    return sorted(records.values(), key=lambda r: r["applied_at"], reverse=True)


def calibration_temperatures(archive: Archive, calibration_ids: list[int]) -> dict[int, float]:
    """The temperature (degC) each calibration's parameters are archived at
    (``parameters.temperature_c``: the run's recorded temperature, corrected in a revision
    made for a chamber found offset); calibrations without one are left out."""
    from storage.schema import ParameterRow

    ids = list(dict.fromkeys(int(i) for i in calibration_ids))
    out: dict[int, float] = {}
    with archive.engine().connect() as conn:
        for start in range(0, len(ids), IN_CHUNK):
            chunk = ids[start : start + IN_CHUNK]
            for cal_id, temp in conn.execute(
                select(ParameterRow.calibration_id, ParameterRow.temperature_c)
                .where(
                    ParameterRow.calibration_id.in_(chunk), ParameterRow.temperature_c.is_not(None)
                )
                .distinct()
            ):
                out[int(cal_id)] = float(temp)
    return out
