"""Seals and the audit chain: tables ``seals`` and ``audit_events``.

Every calibration already in the archive is sealed here, in id order, with one
"sealed" event each, in record format 1 (storage.seal; the files its revision wrote
were not recorded before, so those records list none). The sealing is frozen into
this file as storage.seal did it when the migration was written, over the tables
as they are at this revision: a later change of storage/seal.py or storage/schema.py
does not change what this migration writes. On PostgreSQL, triggers
guard what grants cannot: ``seals`` and ``audit_events`` refuse UPDATE and
DELETE for every role, and no row can be added to a sealed calibration (its
parameters, checks, steps) or to the run of one (raw files, equipment links).
"""

from __future__ import annotations

import hashlib
import json
from datetime import UTC, date, datetime
from typing import Any

import sqlalchemy as sa
from alembic import op

from storage.migrations.ddl import create_index, create_table, drop_index

revision = "0004"
down_revision = "0003"

_APPEND_ONLY = """
CREATE FUNCTION calib_append_only() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
  RAISE EXCEPTION 'calib archive: % on % refused: the table is append-only', TG_OP, TG_TABLE_NAME
    USING ERRCODE = 'insufficient_privilege';
END $$
"""
_SEALED_CAL = """
CREATE FUNCTION calib_sealed_calibration() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
  IF EXISTS (SELECT 1 FROM seals WHERE calibration_id = NEW.calibration_id) THEN
    RAISE EXCEPTION 'calib archive: calibration % is sealed: no row can be added to %',
      NEW.calibration_id, TG_TABLE_NAME USING ERRCODE = 'insufficient_privilege';
  END IF;
  RETURN NEW;
END $$
"""
_SEALED_RUN = """
CREATE FUNCTION calib_sealed_run() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
  IF EXISTS (SELECT 1 FROM seals JOIN calibrations ON calibrations.id = seals.calibration_id
             WHERE calibrations.run_id = NEW.run_id) THEN
    RAISE EXCEPTION 'calib archive: run % is sealed: no row can be added to %',
      NEW.run_id, TG_TABLE_NAME USING ERRCODE = 'insufficient_privilege';
  END IF;
  RETURN NEW;
END $$
"""
_GUARDS = [
    ("append_only", "BEFORE UPDATE OR DELETE", "seals", "calib_append_only"),
    ("append_only", "BEFORE UPDATE OR DELETE", "audit_events", "calib_append_only"),
    ("sealed", "BEFORE INSERT", "parameters", "calib_sealed_calibration"),
    ("sealed", "BEFORE INSERT", "check_results", "calib_sealed_calibration"),
    ("sealed", "BEFORE INSERT", "processing_steps", "calib_sealed_calibration"),
    ("sealed", "BEFORE INSERT", "raw_files", "calib_sealed_run"),
    ("sealed", "BEFORE INSERT", "run_equipment", "calib_sealed_run"),
]


def upgrade() -> None:
    create_table(
        "seals",
        sa.Column("calibration_id", sa.Integer(), nullable=False),
        sa.Column("digest", sa.String(length=64), nullable=False),
        sa.Column("record", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        references={"calibration_id": "calibrations"},
        unique=[("calibration_id",)],
    )
    create_table(
        "audit_events",
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("actor", sa.String(length=200), nullable=False),
        sa.Column("action", sa.String(length=50), nullable=False),
        sa.Column("run_id", sa.String(length=64), nullable=True),
        sa.Column("revision", sa.Integer(), nullable=True),
        sa.Column("reason", sa.Text(), nullable=True),
        sa.Column("detail", sa.JSON(), nullable=False),
        sa.Column("digest", sa.String(length=64), nullable=True),
        sa.Column("prev_hash", sa.String(length=64), nullable=False),
        sa.Column("hash", sa.String(length=64), nullable=False),
        key=sa.Column("seq", sa.Integer(), autoincrement=False, nullable=False),
        unique=[("prev_hash",), ("hash",)],
    )
    create_index("audit_events", "at")
    create_index("audit_events", "run_id")

    _seal_unsealed(op.get_bind(), who="migration 0004")
    if op.get_bind().dialect.name == "postgresql":
        for fn in (_APPEND_ONLY, _SEALED_CAL, _SEALED_RUN):
            op.execute(fn)
        for name, when, table, fn in _GUARDS:
            op.execute(
                f"CREATE TRIGGER {name} {when} ON {table} FOR EACH ROW EXECUTE FUNCTION {fn}()"
            )


def downgrade() -> None:
    if op.get_bind().dialect.name == "postgresql":
        for name, _, table, _ in _GUARDS:
            op.execute(f"DROP TRIGGER IF EXISTS {name} ON {table}")
        for fn in ("calib_append_only", "calib_sealed_calibration", "calib_sealed_run"):
            op.execute(f"DROP FUNCTION IF EXISTS {fn}()")
    drop_index("audit_events", "run_id")
    drop_index("audit_events", "at")
    op.drop_table("audit_events")
    op.drop_table("seals")


# --- the sealing of this revision, frozen (record format 1) ----------------------------


class _UTCDateTime(sa.types.TypeDecorator):
    """storage.schema.UTCDateTime as of this revision: stored UTC, read back UTC-aware."""

    impl = sa.DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is None:
            return None
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


_T, _I, _F, _J, _S = _UTCDateTime, sa.Integer, sa.Float, sa.JSON, sa.String
_TABLES = {
    "devices": {"id": _I, "serial": _S, "model": _S, "manufacturer": _S, "specification": _S},
    "equipment": {"id": _I, "kind": _S, "model": _S, "serial": _S, "accuracy_class": _S},
    "runs": {"id": _I, "device_id": _I, "run_id": _S, "started_at": _T, "operator": _S,
             "procedure": _S, "site": _J, "gravity": _F, "environment": _J,
             "manifest_text": _S, "raw_hash": _S, "tolerance_profile": _S, "run_dir": _S,
             "samples_path": _S, "samples_sha256": _S, "created_at": _T},
    "run_equipment": {"id": _I, "run_id": _I, "equipment_id": _I,
                      "calibration_due": sa.Date, "calibrated_on": sa.Date},
    "raw_files": {"id": _I, "run_id": _I, "name": _S, "sha256": _S, "size": sa.BigInteger,
                  "format": _S, "stored_path": _S},
    "calibrations": {"id": _I, "run_id": _I, "revision": _I, "settings_hash": _S,
                     "settings": _J, "software_version": _S, "source_revision": _S,
                     "created_at": _T, "document": _J, "verdict": _S, "profile_name": _S,
                     "profile_version": _S},
    "processing_steps": {"id": _I, "calibration_id": _I, "seq": _I, "name": _S,
                         "settings": _J, "statistics": _J, "software_version": _S,
                         "source_revision": _S},
    "parameters": {"id": _I, "calibration_id": _I, "name": _S, "value": _F, "std": _F,
                   "unit": _S, "temperature_c": _F},
    "check_results": {"id": _I, "calibration_id": _I, "name": _S, "value": _F, "limit": _F,
                      "passed": sa.Boolean, "detail": _S, "profile_name": _S,
                      "profile_version": _S},
    "seals": {"calibration_id": _I, "digest": _S, "record": _J, "created_at": _T},
    "audit_events": {"seq": _I, "at": _T, "actor": _S, "action": _S, "run_id": _S,
                     "revision": _I, "reason": _S, "detail": _J, "digest": _S,
                     "prev_hash": _S, "hash": _S},
}  # fmt: skip
_t = {
    name: sa.table(name, *(sa.column(c, k()) for c, k in cols.items()))
    for name, cols in _TABLES.items()
}
# The sealed fields of each table (storage.seal's _RUN, _CAL ... of this revision).
_RUN = ("run_id", "started_at", "operator", "procedure", "site", "gravity", "environment",
        "manifest_text", "raw_hash", "tolerance_profile", "run_dir", "samples_path",
        "samples_sha256", "created_at")  # fmt: skip
_CAL = (
    "revision",
    "settings_hash",
    "settings",
    "software_version",
    "source_revision",
    "created_at",
    "document",
    "verdict",
    "profile_name",
    "profile_version",
)
_DEVICE = ("serial", "model", "manufacturer", "specification")
_RAW = ("name", "sha256", "size", "format", "stored_path")
_EQUIPMENT = ("kind", "serial", "model", "accuracy_class", "calibration_due", "calibrated_on")
_CHILDREN = (  # a revision's child tables: (table, sealed fields, order within a revision)
    ("processing_steps", ("seq", "name", "settings", "statistics", "software_version",
                          "source_revision"), "seq"),
    ("parameters", ("name", "value", "std", "unit", "temperature_c"), "name"),
    ("check_results", ("name", "value", "limit", "passed", "detail", "profile_name",
                       "profile_version"), "name"),
)  # fmt: skip
_EVENT = (
    "seq",
    "at",
    "actor",
    "action",
    "run_id",
    "revision",
    "reason",
    "detail",
    "digest",
    "prev_hash",
)
_GENESIS = "0" * 64
_PG_CHAIN_LOCK = 0x63616C6963  # the chain's advisory lock (storage.seal)


def _canonical(value: Any) -> bytes:
    def iso(v: Any) -> str:
        if isinstance(v, date | datetime):
            return v.isoformat()
        raise TypeError(f"{type(v).__name__} is not part of a record")

    return json.dumps(
        value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, default=iso
    ).encode()


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _labelled(rows: list[tuple[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """Rows keyed by label; a repeated label gets ``#2``, ``#3``... in row order."""
    out: dict[str, dict[str, Any]] = {}
    for label, row in rows:
        key, n = label, 1
        while key in out:
            n += 1
            key = f"{label}#{n}"
        out[key] = row
    return out


def _record(conn: sa.Connection, cal_id: int) -> dict[str, Any]:
    """The format 1 record of one calibration revision (no files: none were recorded)."""
    c, r, d = _t["calibrations"], _t["runs"], _t["devices"]
    head = (
        conn.execute(
            sa.select(
                r.c.id.label("run_pk"),
                *(r.c[n].label("r_" + n) for n in _RUN),
                *(c.c[n].label("c_" + n) for n in _CAL),
                *(d.c[n].label("d_" + n) for n in _DEVICE),
            )
            .join(r, r.c.id == c.c.run_id)
            .join(d, d.c.id == r.c.device_id)
            .where(c.c.id == cal_id)
        )
        .mappings()
        .one()
    )
    run_pk = head["run_pk"]
    rec: dict[str, Any] = {
        "runs": {n: head["r_" + n] for n in _RUN},
        "calibrations": {n: head["c_" + n] for n in _CAL},
        "devices": {n: head["d_" + n] for n in _DEVICE},
        "files": {},
    }
    re_, eq = _t["run_equipment"], _t["equipment"]
    equipment = conn.execute(
        sa.select(
            eq.c.kind,
            eq.c.serial,
            eq.c.model,
            eq.c.accuracy_class,
            re_.c.calibration_due,
            re_.c.calibrated_on,
        )
        .join(eq, eq.c.id == re_.c.equipment_id)
        .where(re_.c.run_id == run_pk)
        .order_by(eq.c.kind, eq.c.serial)
    ).all()
    rec["run_equipment"] = _labelled(
        [(f"{e.kind}:{e.serial}", dict(zip(_EQUIPMENT, e, strict=True))) for e in equipment]
    )
    raw = _t["raw_files"]
    rows = conn.execute(
        sa.select(*(raw.c[n] for n in _RAW)).where(raw.c.run_id == run_pk).order_by(raw.c.name)
    ).all()
    rec["raw_files"] = _labelled([(m.name, dict(zip(_RAW, m, strict=True))) for m in rows])
    for table, names, order in _CHILDREN:
        t = _t[table]
        rows = conn.execute(
            sa.select(*(t.c[n] for n in names))
            .where(t.c.calibration_id == cal_id)
            .order_by(t.c[order], t.c.id)
        ).all()
        children = [dict(zip(names, m, strict=True)) for m in rows]
        rec[table] = _labelled(
            [
                (f"{row['seq']}:{row['name']}" if table == "processing_steps" else row["name"], row)
                for row in children
            ]
        )
    return rec


def _append_event(conn: sa.Connection, who: str, rec: dict[str, Any], digest: str) -> None:
    """One "sealed" event chained to the newest one (storage.seal.append_event)."""
    if conn.dialect.name == "postgresql":
        conn.execute(sa.text("SELECT pg_advisory_xact_lock(:k)"), {"k": _PG_CHAIN_LOCK})
    a = _t["audit_events"]
    last = conn.execute(sa.select(a.c.seq, a.c.hash).order_by(a.c.seq.desc()).limit(1)).first()
    seq, prev = (0, _GENESIS) if last is None else (last.seq, last.hash)
    event = {
        "seq": seq + 1,
        "at": datetime.now(UTC),
        "actor": who,
        "action": "sealed",
        "run_id": rec["runs"]["run_id"],
        "revision": rec["calibrations"]["revision"],
        "reason": "sealed when the archive was upgraded",
        "detail": {},
        "digest": digest,
        "prev_hash": prev,
    }
    conn.execute(
        sa.insert(a), {**event, "hash": _sha256(_canonical({k: event[k] for k in _EVENT}))}
    )


def _seal_unsealed(conn: sa.Connection, who: str) -> int:
    """Seal every calibration without a seal, in id order; return how many."""
    c = _t["calibrations"]
    ids = conn.execute(sa.select(c.c.id).order_by(c.c.id)).scalars().all()
    for cal_id in ids:  # a new table: none of them is sealed yet
        rec = _record(conn, cal_id)
        data = _canonical(rec)
        digest = _sha256(data)
        conn.execute(
            sa.insert(_t["seals"]),
            {
                "calibration_id": cal_id,
                "digest": digest,
                "record": json.loads(data),
                "created_at": datetime.now(UTC),
            },
        )
        _append_event(conn, who, rec, digest)
    return len(ids)
