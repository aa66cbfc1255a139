"""Each unit's latest run and latest valid calibration: the derived tables ``unit_latest``
and ``unit_latest_values``.

A fleet page asks, for each of thousands of units, which run is its latest and which
calibration its latest valid one, and that calibration's value of one parameter;
walking every unit's runs and parameter rows for that on each request cost more than
the rest of the page. The answers change only when one of the unit's runs is archived
or revised, so they are kept (storage.schema.UnitLatest, UnitLatestValue: per unit its
picks, and the valid calibration's parameters one per name, of temperature-dependent
values the one nearest REFERENCE_C, keyed by model, name and serial):

- `refresh` rewrites one unit's rows from its runs, in the transaction that archives or
  revises a run of it (storage.archive), so a reader never sees them stale;
- `rebuild` derives every row (migration 0007, bulk loads);
- `differences` and `value_differences` compare the tables with their derivation
  (`calib verify` reports each unit whose rows disagree: never a silently wrong fleet).

The picks follow the one rule of storage.current (as storage.queries.fleet and
latest_valid): latest by run start, the later archived (larger id) among equal starts;
of two current revisions of one run (a broken archive, which verify reports too) the
later one.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from functools import cache
from typing import Any

from sqlalchemy import Connection, ScalarSelect, Select, bindparam, delete, insert, select
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert

from storage.current import CURRENT, LATEST_RUN_FIRST, latest_valid_pick
from storage.schema import CalibrationRow, Device, ParameterRow, Run, UnitLatest, UnitLatestValue

COLUMNS = (
    "device_id", "run_id", "calibration_id", "verdict", "profile_name", "valid_calibration_id",
)  # fmt: skip
VALUE_COLUMNS = ("model", "name", "serial", "device_id", "calibration_id", "value", "temperature_c")
VALUES_TABLE = UnitLatestValue.__tablename__
REFERENCE_C = 20.0  # of temperature-dependent values, the one nearest this (deg C)
_CHUNK = 10_000  # rows per INSERT of a rebuild
# The unit_latest_values rows a reader takes: those of the unit's latest valid calibration
# (a unit's rows are upserted, never deleted, so a name the earlier calibration had and
# the new one lacks keeps a row of the earlier one).
LIVE = (UnitLatest.device_id == UnitLatestValue.device_id) & (
    UnitLatest.valid_calibration_id == UnitLatestValue.calibration_id
)


def _latest_run() -> ScalarSelect:
    return (
        select(Run.id)
        .where(Run.device_id == Device.id)
        .order_by(*LATEST_RUN_FIRST)
        .limit(1)
        .correlate(Device)
        .scalar_subquery()
    )


# One unit's queries take its id as the parameter ``device_id``; they are built once per
# process: `refresh` runs in every archiving transaction, where building its statements
# anew cost most of its time.
_ONE_UNIT = bindparam("device_id")
_LOCK = select(UnitLatest.device_id).where(UnitLatest.device_id == _ONE_UNIT).with_for_update()


@cache
def _derived(one_unit: bool = False) -> Select:
    """The rows (COLUMNS) of every unit with a run (or of the unit ``device_id``), derived
    from runs and calibrations (a backward step on the runs index per pick)."""
    latest = _latest_run()
    current = (
        select(CalibrationRow.id)
        .where(CalibrationRow.run_id == latest, CURRENT)
        .order_by(CalibrationRow.id.desc())
        .limit(1)
        .correlate(Device)
        .scalar_subquery()
    )
    valid = latest_valid_pick(Run.device_id == Device.id).correlate(Device).scalar_subquery()
    picks = select(
        Device.id.label("device_id"),
        latest.label("run_id"),
        current.label("calibration_id"),
        valid.label("valid_calibration_id"),
    )
    if one_unit:
        picks = picks.where(Device.id == _ONE_UNIT)
    picks = picks.subquery("picks")
    return (
        select(
            picks.c.device_id,
            picks.c.run_id,
            picks.c.calibration_id,
            CalibrationRow.verdict,
            CalibrationRow.profile_name,
            picks.c.valid_calibration_id,
        )
        .select_from(picks)
        .outerjoin(CalibrationRow, CalibrationRow.id == picks.c.calibration_id)
        .where(picks.c.run_id.is_not(None))
    )


def refresh(conn: Connection, device_id: int) -> None:
    """Rewrite the row of unit `device_id` from its runs (call in the writing transaction,
    after the run's calibration rows and supersession are written).

    On PostgreSQL the unit's row is locked first and derived by a later statement, so a
    concurrent writer of another run of the unit, committed while this one waited, is
    seen (READ COMMITTED: each statement sees what was committed before it began). A new
    unit has no row to lock; its concurrent writers meet at the unique serial instead.
    """
    one = {"device_id": device_id}
    conn.execute(_LOCK, one)  # (no-op on SQLite, whose writers take turns)
    row = conn.execute(_derived(one_unit=True), one).one_or_none()
    if row is None:  # no runs (not reached by storage.archive, which adds one first)
        conn.execute(delete(UnitLatest).where(UnitLatest.device_id == device_id))
        return
    put_unit, put_values = _upserts(conn.dialect.name)
    conn.execute(put_unit, dict(row._mapping))
    rows = _derived_values(conn, device_id)
    if rows:  # upserted: rows of names the new calibration lacks stay, not read (no DELETE)
        conn.execute(put_values, [dict(zip(VALUE_COLUMNS, r, strict=True)) for r in rows])


@cache
def _upserts(dialect: str) -> tuple[Any, Any]:
    """The upserts of a unit's row and of its value rows, in `dialect`'s words."""
    dialect_insert = pg_insert if dialect == "postgresql" else sqlite_insert
    unit = dialect_insert(UnitLatest)
    unit = unit.on_conflict_do_update(
        index_elements=[UnitLatest.device_id], set_={c: unit.excluded[c] for c in COLUMNS[1:]}
    )
    values = dialect_insert(UnitLatestValue)
    values = values.on_conflict_do_update(
        index_elements=[UnitLatestValue.model, UnitLatestValue.name, UnitLatestValue.serial],
        set_={c: values.excluded[c] for c in VALUE_COLUMNS[3:]},
    )
    return unit, values


def rebuild(conn: Connection) -> int:
    """Derive every unit's rows afresh (replacing both tables' content); return the
    number of units."""
    conn.execute(delete(UnitLatestValue))
    conn.execute(delete(UnitLatest))
    conn.execute(insert(UnitLatest).from_select(list(COLUMNS), _derived()))
    rows = iter(_derived_values(conn))
    while chunk := list(itertools.islice(rows, _CHUNK)):
        conn.execute(
            insert(UnitLatestValue), [dict(zip(VALUE_COLUMNS, r, strict=True)) for r in chunk]
        )
    return len(conn.execute(select(UnitLatest.device_id)).all())


def nearest(rows: Iterable[tuple[str, float, float | None]]) -> dict[str, tuple[float, Any]]:
    """Per parameter name, the (value, temperature_c) of `rows` (name, value,
    temperature_c) nearest REFERENCE_C: a value without a temperature (None or NaN)
    counts as at it; of two as near the lower temperature, then the earlier row."""
    best: dict[str, tuple[tuple[float, float], float, Any]] = {}
    for name, value, t in rows:
        key = (0.0, 0.0) if t is None or t != t else (abs(t - REFERENCE_C), t)  # t != t: NaN
        old = best.get(name)
        if old is None or key < old[0]:
            best[name] = (key, value, t)
    return {n: (v, t) for n, (_, v, t) in best.items()}


def _derived_values(conn: Connection, device_id: int | None = None) -> list[tuple]:
    """The unit_latest_values rows (VALUE_COLUMNS) of every unit (or of `device_id`):
    the parameters of its latest valid calibration as derived from the runs, one per
    name (`nearest`), by device then name."""
    one_unit = device_id is not None
    found = conn.execute(_values_query(one_unit), {"device_id": device_id} if one_unit else {})
    out = []
    for dev, group in itertools.groupby(found, key=lambda r: r[2]):
        rows = list(group)
        model, serial, _, cal = rows[0][:4]
        for name, (value, t) in sorted(nearest((r[4], r[5], r[6]) for r in rows).items()):
            out.append((model, name, serial, dev, cal, value, t))
    return out


@cache
def _values_query(one_unit: bool) -> Select:
    """The parameter rows of each unit's latest valid calibration (`_derived_values`)."""
    picks = _derived(one_unit).subquery("derived")
    return (
        select(
            Device.model,
            Device.serial,
            Device.id,
            picks.c.valid_calibration_id,
            ParameterRow.name,
            ParameterRow.value,
            ParameterRow.temperature_c,
        )
        .join(picks, picks.c.device_id == Device.id)
        .join(ParameterRow, ParameterRow.calibration_id == picks.c.valid_calibration_id)
        .order_by(Device.id, ParameterRow.id)
    )


def differences(conn: Connection) -> list[dict[str, Any]]:
    """Units whose row disagrees with its derivation (missing, extra or different ids).

    Dicts: serial, stored and derived (``{column: value}`` of COLUMNS but device_id,
    None when there is no row), run_ids (the run ids, as the archive
    names runs, of the latest runs either side names).
    """
    stored = {
        r[0]: tuple(r[1:])
        for r in conn.execute(select(*(UnitLatest.__table__.c[c] for c in COLUMNS)))
    }
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
        out.append(
            {
                "serial": serials.get(d, f"(device id {d}, not in devices)"),
                "stored": None if s is None else dict(zip(COLUMNS[1:], s, strict=True)),
                "derived": None if e is None else dict(zip(COLUMNS[1:], e, strict=True)),
                "run_ids": sorted({names[v[0]] for v in (s, e) if v is not None and v[0] in names}),
            }
        )
    return out


def value_differences(conn: Connection) -> list[dict[str, Any]]:
    """Units whose unit_latest_values rows, as a fleet reads them (`LIVE`), disagree
    with their derivation (a row missing, extra or different). Dicts: serial, names
    (the parameters that differ), stored and derived (of the first such name:
    ``{column: value}``, None if absent).
    """

    def key(r: tuple) -> tuple[tuple[int, str], tuple]:
        t = r[6]
        return (r[3], r[1]), (r[0], r[2], r[4], r[5], "NaN" if t is not None and t != t else t)

    cols = [UnitLatestValue.__table__.c[c] for c in VALUE_COLUMNS]
    stored = dict(key(tuple(r)) for r in conn.execute(select(*cols).join(UnitLatest, LIVE)))
    derived = dict(key(r) for r in _derived_values(conn))
    bad = sorted(k for k in stored.keys() | derived.keys() if stored.get(k) != derived.get(k))
    shown = ("model", "serial", "calibration_id", "value", "temperature_c")
    out = []
    for _, group in itertools.groupby(bad, key=lambda k: k[0]):
        names = list(group)
        first = names[0]
        s, e = stored.get(first), derived.get(first)
        out.append(
            {
                "serial": (s or e)[1],
                "names": [n for _, n in names],
                "stored": None if s is None else dict(zip(shown, s, strict=True)),
                "derived": None if e is None else dict(zip(shown, e, strict=True)),
            }
        )
    return out
