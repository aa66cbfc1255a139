"""Queries of the archive about equipment: every piece with its due dates, one piece's
due-date history, the runs made while it was past its due date (a frame, or a page of
the archive browser), the state of a due date.
"""

from __future__ import annotations

from datetime import UTC, date, datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import Select, func, select
from sqlalchemy.engine import make_url

from storage.db import Archive
from storage.queries._common import (
    EQUIPMENT_SERIAL_LEN,
    _frame,
    _run_day,
    check_text,
    reading,
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
    columns = (Equipment.kind, Equipment.serial, *_LAPSED_RUN)
    stmt = _lapsed(archive, equipment_serial, kind, *columns)
    with reading(archive) as conn:
        rows = conn.execute(stmt).all()
    df = _frame(rows, LAPSED_COLUMNS[:-1])
    df["days_overdue"] = [
        (t.astimezone(UTC).date() - due).days
        for t, due in zip(df["started_at"], df["calibration_due"], strict=True)
    ]
    return df.astype({"days_overdue": "int64"})


# What a lapsed run is shown with: the run, its unit, start, operator and the due date.
_LAPSED_RUN = (
    Run.run_id,
    Device.serial,
    Run.started_at,
    Run.operator,
    RunEquipment.calibration_due,
)


def _lapsed(archive: Archive, equipment_serial: str, kind: str | None, *columns: Any) -> Select:
    """SELECT `columns` of the runs made on the equipment while its calibration had lapsed
    (the run's UTC start day after the due date recorded with that run), oldest first."""
    day = _run_day(make_url(archive.url).get_backend_name())
    due = RunEquipment.calibration_due
    return (
        runs_with_equipment(equipment_serial, kind, *columns)
        .where(due.is_not(None), day > due)
        .order_by(Run.started_at, Run.id)
    )


def runs_with_equipment(equipment_serial: str, kind: str | None, *columns: Any) -> Select:
    """SELECT `columns` of every run whose equipment snapshot (`run_equipment`) names
    `equipment_serial` (of `kind`; None: any kind), from Run, Device (the unit),
    RunEquipment and Equipment joined. Raises ValueError naming a malformed serial or kind."""
    check_text(equipment_serial, "equipment serial", EQUIPMENT_SERIAL_LEN)
    stmt = (
        select(*columns)
        .select_from(Run)
        .join(Device, Device.id == Run.device_id)
        .join(RunEquipment, RunEquipment.run_id == Run.id)
        .join(Equipment, Equipment.id == RunEquipment.equipment_id)
        .where(Equipment.serial == equipment_serial)
    )
    if kind is not None:
        stmt = stmt.where(Equipment.kind == check_text(kind, "equipment kind", 100))
    return stmt


def equipment_list(archive: Archive) -> list[dict[str, Any]]:
    """Every piece of equipment: kind, serial, model, accuracy_class, the latest due date
    recorded with any of its runs (``calibration_due``) and the run count.

    Both per piece from ix_run_equipment_equipment_id_calibration_due alone (its last
    entry; its entries counted), not by grouping the run_equipment rows."""
    due = (
        select(func.max(RunEquipment.calibration_due))
        .where(RunEquipment.equipment_id == Equipment.id)
        .scalar_subquery()
    )
    runs = (
        select(func.count())
        .select_from(RunEquipment)
        .where(RunEquipment.equipment_id == Equipment.id)
        .scalar_subquery()
    )
    stmt = select(
        Equipment.kind,
        Equipment.serial,
        Equipment.model,
        Equipment.accuracy_class,
        due.label("calibration_due"),
        runs.label("runs"),
    ).order_by(Equipment.kind, Equipment.serial)
    with reading(archive) as conn:
        return [dict(r._mapping) for r in conn.execute(stmt).all()]


def equipment_item(archive: Archive, kind: str, serial: str) -> dict[str, Any]:
    """One piece of equipment with its due-date history: the distinct (calibrated_on,
    calibration_due) pairs recorded with its runs, each with its run count and span."""
    check_text(kind, "equipment kind", 100)
    check_text(serial, "equipment serial")
    head = select(
        Equipment.id, Equipment.kind, Equipment.serial, Equipment.model, Equipment.accuracy_class
    ).where(Equipment.kind == kind, Equipment.serial == serial)
    with reading(archive) as conn:
        row = conn.execute(head).one_or_none()
        if row is None:
            raise LookupError(f"no equipment {kind} {serial!r} in the archive")
        periods = conn.execute(
            select(
                RunEquipment.calibrated_on,
                RunEquipment.calibration_due,
                func.count().label("runs"),
                func.min(Run.started_at).label("first_run"),
                func.max(Run.started_at).label("last_run"),
            )
            .join(Run, Run.id == RunEquipment.run_id)
            .where(RunEquipment.equipment_id == row.id)
            .group_by(RunEquipment.calibrated_on, RunEquipment.calibration_due)
            .order_by(func.min(Run.started_at))
        ).all()
    item = dict(row._mapping)
    del item["id"]
    item["periods"] = [dict(p._mapping) for p in periods]
    return item


def lapsed_page(
    archive: Archive, kind: str, serial: str, limit: int = 500
) -> tuple[list[dict[str, Any]], int]:
    """Runs made on one piece of equipment while its calibration had lapsed: the first
    `limit` (oldest first) and how many there are, as storage.queries.lapsed_runs decides
    (the run's UTC start day after the due date recorded with that run).

    Dicts: run_id, serial, started_at, operator, calibration_due, days_overdue.
    """
    check_text(kind, "equipment kind", 100)
    total = func.count().over().label("total")
    stmt = _lapsed(archive, serial, kind, *_LAPSED_RUN, total).limit(limit)
    with reading(archive) as conn:  # counted in the same pass (before the LIMIT)
        rows = conn.execute(stmt).all()
    total = rows[0].total if rows else 0
    out = [dict(r._mapping) for r in rows]
    for r in out:
        del r["total"]
        r["days_overdue"] = (r["started_at"].astimezone(UTC).date() - r["calibration_due"]).days
    return out, total


def today_utc() -> date:
    return datetime.now(UTC).date()


def due_state(due: date | None, today: date | None = None) -> str:
    """ "lapsed", "due soon" (within 30 days), "valid" or "unknown" for a due date."""
    if due is None:
        return "unknown"
    days = (due - (today or today_utc())).days
    return "lapsed" if days < 0 else "due soon" if days <= 30 else "valid"
