"""Queries of the archive about equipment: the runs made while it was past its due date.
"""

from __future__ import annotations

from datetime import UTC
from typing import TYPE_CHECKING

from sqlalchemy import select
from sqlalchemy.engine import make_url

from storage.db import Archive
from storage.queries._common import (
    EQUIPMENT_SERIAL_LEN,
    _frame,
    _run_day,
    check_text,
)
from storage.schema import (
    Device,
    Equipment,
    Run,
    RunEquipment,
)

if TYPE_CHECKING:
    import pandas as pd  # imported where a frame is made (slow to import)

LAPSED_COLUMNS = [
    "equipment_kind",
    "equipment_serial",
    "run_id",
    "serial",
    "started_at",
    "operator",
    "calibration_due",
    "days_overdue",
]


def lapsed_runs(archive: Archive, equipment_serial: str, kind: str | None = None) -> pd.DataFrame:
    """Runs made on a piece of equipment while its own calibration had lapsed.

    Lapsed: the run started (UTC day) after the equipment's calibration due
    date as recorded with that run (`run_equipment`), i.e. the due date is the
    last valid day. Runs without a recorded due date are not listed (unknown).

    Parameters
    ----------
    equipment_serial : the equipment's serial (all kinds with this serial
        unless `kind` is given).
    kind : "rate_table", "centrifuge", "chamber", "daq"...

    Returns
    -------
    DataFrame with LAPSED_COLUMNS, oldest run first; days_overdue >= 1.
    """
    check_text(equipment_serial, "equipment serial", EQUIPMENT_SERIAL_LEN)
    day = _run_day(make_url(archive.url).get_backend_name())
    stmt = (
        select(Equipment.kind, Equipment.serial, Run.run_id, Device.serial, Run.started_at,
               Run.operator, RunEquipment.calibration_due)
        .join(RunEquipment, RunEquipment.equipment_id == Equipment.id)
        .join(Run, Run.id == RunEquipment.run_id)
        .join(Device, Device.id == Run.device_id)
        .where(
            Equipment.serial == equipment_serial,
            RunEquipment.calibration_due.is_not(None),
            day > RunEquipment.calibration_due,
        )
        .order_by(Run.started_at, Run.id)
    )  # fmt: skip
    if kind is not None:
        stmt = stmt.where(Equipment.kind == check_text(kind, "equipment kind", 100))
    with archive.engine().connect() as conn:
        rows = conn.execute(stmt).all()
    df = _frame(rows, LAPSED_COLUMNS[:-1])
    df["days_overdue"] = [
        (t.astimezone(UTC).date() - due).days
        for t, due in zip(df["started_at"], df["calibration_due"], strict=True)
    ]
    return df.astype({"days_overdue": "int64"})
