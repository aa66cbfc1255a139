"""Queries of the archive about reference equipment and its effect on results: the runs
that used one piece of it in a period (an out-of-tolerance look-back, ISO/IEC 17025 clause
7.10; `calib impact`), and each run's reference and Type B budget (shared references in
trends and repeatability).
"""

from __future__ import annotations

from datetime import date, datetime
from typing import Any

from sqlalchemy import select

from storage.db import Archive
from storage.queries._common import (
    EQUIPMENT_SERIAL_LEN,
    IN_CHUNK,
    as_instant,
    check_text,
    where_model_and_start,
)
from storage.schema import CalibrationRow, Device, Equipment, Run, RunEquipment


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
    check_text(equipment_serial, "equipment serial", EQUIPMENT_SERIAL_LEN)
    t0 = as_instant(since, "from", end_of_day=False)
    t1 = as_instant(until, "to", end_of_day=True)
    stmt = (
        select(
            Run.run_id,
            Device.serial,
            Run.model,
            Run.procedure,
            Run.started_at,
            Equipment.kind,
            Equipment.model,
            RunEquipment.calibration_due,
            CalibrationRow.verdict,
            CalibrationRow.revision,
        )
        .join(Device, Device.id == Run.device_id)
        .join(RunEquipment, RunEquipment.run_id == Run.id)
        .join(Equipment, Equipment.id == RunEquipment.equipment_id)
        .join(
            CalibrationRow,
            (CalibrationRow.run_id == Run.id) & CalibrationRow.superseded_by.is_(None),
        )
        .where(Equipment.serial == equipment_serial)
        .order_by(Run.started_at, Run.run_id)
    )
    if kind is not None:
        stmt = stmt.where(Equipment.kind == check_text(kind, "equipment kind", 100))
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
                    (CalibrationRow.run_id == Run.id) & CalibrationRow.superseded_by.is_(None),
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
