"""Each unit's latest run and latest valid calibration, kept: ``unit_latest``.

The fleet page picked, on every request, each unit's latest run and latest valid
calibration by walking the unit's runs, which cost more than the rest of a large
archive's fleet page. The derived table holds the picks per unit and the
verdict and profile of the latest run (storage.unit_latest): storage.archive rewrites a
unit's row in the transaction that archives or revises one of its runs, `calib verify`
compares the table with its derivation. ``unit_latest_values`` holds, per unit, the
parameters of that valid calibration (one per name: of temperature-dependent values the
one nearest 20 deg C), keyed by model, name and serial: a fleet's values of one
parameter are one range of the key. Every existing unit's rows are derived here, by
the derivation of storage.unit_latest as it was when the migration was written, frozen
into this file over the tables of this revision.
"""

from __future__ import annotations

import itertools
from typing import Any

import sqlalchemy as sa
from alembic import op

from storage.migrations.ddl import create_index, create_table, drop_index

revision = "0007"
down_revision = "0006_run_device"


def upgrade() -> None:
    create_table(
        "unit_latest",
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("calibration_id", sa.Integer(), nullable=True),
        sa.Column("verdict", sa.String(length=20), nullable=True),
        sa.Column("profile_name", sa.String(length=200), nullable=True),
        sa.Column("valid_calibration_id", sa.Integer(), nullable=True),
        key=sa.Column("device_id", sa.Integer(), autoincrement=False, nullable=False),
    )
    op.create_table(
        "unit_latest_values",
        sa.Column("model", sa.String(length=200), nullable=False),
        sa.Column("name", sa.String(length=100), nullable=False),
        sa.Column("serial", sa.String(length=64), nullable=False),
        sa.Column("device_id", sa.Integer(), nullable=False),
        sa.Column("calibration_id", sa.Integer(), nullable=False),
        sa.Column("value", sa.Float(), nullable=False),
        sa.Column("temperature_c", sa.Float(), nullable=True),
        sa.PrimaryKeyConstraint("model", "name", "serial", name=op.f("pk_unit_latest_values")),
        sqlite_with_rowid=False,
    )
    create_index("unit_latest_values", "device_id")
    _rebuild(op.get_bind())


def downgrade() -> None:
    drop_index("unit_latest_values", "device_id")
    op.drop_table("unit_latest_values")
    op.drop_table("unit_latest")


# --- the derivation of this revision, frozen (storage.unit_latest.rebuild) --------------

_I, _S, _F, _T = sa.Integer, sa.String, sa.Float, sa.DateTime
_TABLES = {
    "devices": {"id": _I, "serial": _S, "model": _S},
    "runs": {"id": _I, "device_id": _I, "started_at": _T},
    "calibrations": {"id": _I, "run_id": _I, "superseded_by": _I, "verdict": _S,
                     "profile_name": _S},
    "parameters": {"id": _I, "calibration_id": _I, "name": _S, "value": _F,
                   "temperature_c": _F},
    "unit_latest": {"device_id": _I, "run_id": _I, "calibration_id": _I, "verdict": _S,
                    "profile_name": _S, "valid_calibration_id": _I},
    "unit_latest_values": {"model": _S, "name": _S, "serial": _S, "device_id": _I,
                           "calibration_id": _I, "value": _F, "temperature_c": _F},
}  # fmt: skip
_t = {
    name: sa.table(name, *(sa.column(c, k()) for c, k in cols.items()))
    for name, cols in _TABLES.items()
}
_PASS = "pass"
_REFERENCE_C = 20.0  # of temperature-dependent values, the one nearest this (deg C)
_CHUNK = 10_000  # rows per INSERT


def _derived() -> sa.Select:
    """Each unit's latest run (by start, then id), its current calibration, its latest
    valid (passing, current) calibration, and the latest's verdict and profile."""
    d, r, c = _t["devices"], _t["runs"], _t["calibrations"]
    latest = (
        sa.select(r.c.id)
        .where(r.c.device_id == d.c.id)
        .order_by(r.c.started_at.desc(), r.c.id.desc())
        .limit(1)
        .correlate(d)
        .scalar_subquery()
    )
    current = (
        sa.select(c.c.id)
        .where(c.c.run_id == latest, c.c.superseded_by.is_(None))
        .order_by(c.c.id.desc())
        .limit(1)
        .correlate(d)
        .scalar_subquery()
    )
    valid = (
        sa.select(c.c.id)
        .join(r, r.c.id == c.c.run_id)
        .where(r.c.device_id == d.c.id, c.c.superseded_by.is_(None), c.c.verdict == _PASS)
        .order_by(r.c.started_at.desc(), r.c.id.desc(), c.c.id.desc())
        .limit(1)
        .correlate(d)
        .scalar_subquery()
    )
    picks = sa.select(
        d.c.id.label("device_id"),
        latest.label("run_id"),
        current.label("calibration_id"),
        valid.label("valid_calibration_id"),
    ).subquery("picks")
    return (
        sa.select(
            picks.c.device_id,
            picks.c.run_id,
            picks.c.calibration_id,
            c.c.verdict,
            c.c.profile_name,
            picks.c.valid_calibration_id,
        )
        .select_from(picks)
        .outerjoin(c, c.c.id == picks.c.calibration_id)
        .where(picks.c.run_id.is_not(None))
    )


def _nearest(rows: list[tuple[str, float, float | None]]) -> dict[str, tuple[float, Any]]:
    """Per name, the (value, temperature_c) nearest _REFERENCE_C (no temperature: at it;
    of two as near the lower temperature, then the earlier row)."""
    best: dict[str, tuple[tuple[float, float], float, Any]] = {}
    for name, value, t in rows:
        key = (0.0, 0.0) if t is None or t != t else (abs(t - _REFERENCE_C), t)  # t != t: NaN
        old = best.get(name)
        if old is None or key < old[0]:
            best[name] = (key, value, t)
    return {n: (v, t) for n, (_, v, t) in best.items()}


def _rebuild(conn: sa.Connection) -> None:
    """Derive every unit's rows of both tables."""
    d, p = _t["devices"], _t["parameters"]
    columns = list(_TABLES["unit_latest"])
    conn.execute(sa.insert(_t["unit_latest"]).from_select(columns, _derived()))
    picks = _derived().subquery("derived")
    found = conn.execute(
        sa.select(
            d.c.model,
            d.c.serial,
            d.c.id,
            picks.c.valid_calibration_id,
            p.c.name,
            p.c.value,
            p.c.temperature_c,
        )
        .join(picks, picks.c.device_id == d.c.id)
        .join(p, p.c.calibration_id == picks.c.valid_calibration_id)
        .order_by(d.c.id, p.c.id)
    )
    out = []
    for dev, group in itertools.groupby(found, key=lambda r: r[2]):
        rows = list(group)
        model, serial, _, cal = rows[0][:4]
        for name, (value, t) in sorted(_nearest([(r[4], r[5], r[6]) for r in rows]).items()):
            out.append(
                {
                    "model": model,
                    "name": name,
                    "serial": serial,
                    "device_id": dev,
                    "calibration_id": cal,
                    "value": value,
                    "temperature_c": t,
                }
            )
    for i in range(0, len(out), _CHUNK):
        conn.execute(sa.insert(_t["unit_latest_values"]), out[i : i + _CHUNK])
