"""Queries of the archive for an out-of-tolerance look-back: the runs that used one piece of
reference equipment in a period (ISO/IEC 17025 clause 7.10; `calib impact`).
"""

from __future__ import annotations

from datetime import date, datetime
from typing import Any

from sqlalchemy import select

from storage.db import Archive
from storage.queries._common import (
    EQUIPMENT_SERIAL_LEN,
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
        select(Run.run_id, Device.serial, Run.model, Run.procedure, Run.started_at,
               Equipment.kind, Equipment.model, RunEquipment.calibration_due,
               CalibrationRow.verdict, CalibrationRow.revision)
        .join(Device, Device.id == Run.device_id)
        .join(RunEquipment, RunEquipment.run_id == Run.id)
        .join(Equipment, Equipment.id == RunEquipment.equipment_id)
        .join(CalibrationRow,
              (CalibrationRow.run_id == Run.id) & CalibrationRow.superseded_by.is_(None))
        .where(Equipment.serial == equipment_serial)
        .order_by(Run.started_at, Run.run_id)
    )  # fmt: skip
    if kind is not None:
        stmt = stmt.where(Equipment.kind == check_text(kind, "equipment kind", 100))
    stmt = where_model_and_start(stmt, None, t0, t1)
    keys = ("run_id", "serial", "model", "procedure", "started_at", "equipment_kind",
            "equipment_model", "calibration_due", "verdict", "revision")  # fmt: skip
    with archive.engine().connect() as conn:
        return [dict(zip(keys, row, strict=True)) for row in conn.execute(stmt).all()]
