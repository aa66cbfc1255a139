"""Each unit's latest run and latest valid calibration: the derived table ``unit_latest``.

A fleet page asks, for each of thousands of units, which run is its latest and which
calibration its latest valid one; walking every unit's runs for that on each request
cost more than the rest of the page. The answer changes only when one of the unit's
runs is archived or revised, so it is kept in a table (storage.schema.UnitLatest):

- `refresh` rewrites one unit's row from its runs, in the transaction that archives or
  revises a run of it (storage.archive), so a reader never sees it stale;
- `rebuild` derives every row (migration 0006, bulk loads);
- `differences` compares the table with its derivation (`calib verify` reports each
  unit whose row disagrees: never a silently wrong fleet).

The picks are those of storage.queries.fleet and latest_valid: latest by run start, the
later archived (larger id) among equal starts; of two current revisions of one run (a
broken archive, which verify reports too) the later one.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import Connection, ScalarSelect, Select, delete, insert, select
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert

from storage.queries._common import PASS
from storage.schema import CalibrationRow, Device, Run, UnitLatest

COLUMNS = (
    "device_id", "run_id", "calibration_id", "verdict", "profile_name", "valid_calibration_id",
)  # fmt: skip


def _latest_run() -> ScalarSelect:
    return (select(Run.id).where(Run.device_id == Device.id)
            .order_by(Run.started_at.desc(), Run.id.desc()).limit(1)
            .correlate(Device).scalar_subquery())  # fmt: skip


def _derived(device_id: int | None = None) -> Select:
    """The rows (COLUMNS) of every unit with a run (or of unit `device_id`), derived from
    runs and calibrations (a backward step on the runs index per pick)."""
    latest = _latest_run()
    current = (select(CalibrationRow.id)
               .where(CalibrationRow.run_id == latest, CalibrationRow.superseded_by.is_(None))
               .order_by(CalibrationRow.id.desc()).limit(1)
               .correlate(Device).scalar_subquery())  # fmt: skip
    valid = (
        select(CalibrationRow.id)
        .join(Run, Run.id == CalibrationRow.run_id)
        .where(Run.device_id == Device.id, CalibrationRow.superseded_by.is_(None),
               CalibrationRow.verdict == PASS)
        .order_by(Run.started_at.desc(), Run.id.desc(), CalibrationRow.id.desc())
        .limit(1).correlate(Device).scalar_subquery()
    )  # fmt: skip
    picks = select(Device.id.label("device_id"), latest.label("run_id"),
                   current.label("calibration_id"), valid.label("valid_calibration_id"))
    if device_id is not None:
        picks = picks.where(Device.id == device_id)
    picks = picks.subquery("picks")
    return (select(picks.c.device_id, picks.c.run_id, picks.c.calibration_id,
                   CalibrationRow.verdict, CalibrationRow.profile_name,
                   picks.c.valid_calibration_id)
            .select_from(picks)
            .outerjoin(CalibrationRow, CalibrationRow.id == picks.c.calibration_id)
            .where(picks.c.run_id.is_not(None)))  # fmt: skip


def refresh(conn: Connection, device_id: int) -> None:
    """Rewrite the row of unit `device_id` from its runs (call in the writing transaction,
    after the run's calibration rows and supersession are written).

    On PostgreSQL the unit's row is locked first and derived by a later statement, so a
    concurrent writer of another run of the unit, committed while this one waited, is
    seen (READ COMMITTED: each statement sees what was committed before it began). A new
    unit has no row to lock; its concurrent writers meet at the unique serial instead.
    """
    lock = select(UnitLatest.device_id).where(UnitLatest.device_id == device_id)
    conn.execute(lock.with_for_update())  # (no-op on SQLite, whose writers take turns)
    row = conn.execute(_derived(device_id)).one_or_none()
    if row is None:  # no runs (not reached by storage.archive, which adds one first)
        conn.execute(delete(UnitLatest).where(UnitLatest.device_id == device_id))
        return
    values = dict(row._mapping)
    dialect_insert = pg_insert if conn.dialect.name == "postgresql" else sqlite_insert
    stmt = dialect_insert(UnitLatest).values(**values)
    conn.execute(stmt.on_conflict_do_update(
        index_elements=[UnitLatest.device_id],
        set_={c: stmt.excluded[c] for c in COLUMNS[1:]},
    ))  # fmt: skip


def rebuild(conn: Connection) -> int:
    """Derive every unit's row afresh (replacing the table's content); return the rows."""
    conn.execute(delete(UnitLatest))
    conn.execute(insert(UnitLatest).from_select(list(COLUMNS), _derived()))
    return len(conn.execute(select(UnitLatest.device_id)).all())


def differences(conn: Connection) -> list[dict[str, Any]]:
    """Units whose row disagrees with its derivation (missing, extra or different ids).

    Dicts: serial, stored and derived (``{column: value}`` of COLUMNS but device_id,
    None when there is no row), run_ids (the run ids, as the archive
    names runs, of the latest runs either side names).
    """
    stored = {r[0]: tuple(r[1:]) for r in conn.execute(select(*(UnitLatest.__table__.c[c]
                                                                 for c in COLUMNS)))}  # fmt: skip
    derived = {r[0]: tuple(r[1:]) for r in conn.execute(_derived())}
    bad = sorted(d for d in stored.keys() | derived.keys() if stored.get(d) != derived.get(d))
    if not bad:
        return []
    serials = dict(conn.execute(select(Device.id, Device.serial).where(Device.id.in_(bad))).all())
    pks = {v[0] for d in bad for v in (stored.get(d), derived.get(d)) if v is not None}
    names = dict(conn.execute(select(Run.id, Run.run_id).where(Run.id.in_(pks))).all())
    out = []
    for d in bad:
        s, e = stored.get(d), derived.get(d)
        out.append({
            "serial": serials.get(d, f"(device id {d}, not in devices)"),
            "stored": None if s is None else dict(zip(COLUMNS[1:], s, strict=True)),
            "derived": None if e is None else dict(zip(COLUMNS[1:], e, strict=True)),
            "run_ids": sorted({names[v[0]] for v in (s, e) if v is not None and v[0] in names}),
        })  # fmt: skip
    return out
