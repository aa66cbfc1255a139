"""Seals and the audit chain (issue 20): tables ``seals`` and ``audit_events``.

Every calibration already in the archive is sealed here, in id order, with one
"sealed" event each (storage.seal.seal_unsealed; the files its revision wrote
were not recorded before, so those records list none). On PostgreSQL, triggers
guard what grants cannot: ``seals`` and ``audit_events`` refuse UPDATE and
DELETE for every role, and no row can be added to a sealed calibration (its
parameters, checks, steps) or to the run of one (raw files, equipment links).
"""

from __future__ import annotations

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

    from storage.seal import seal_unsealed  # the sealing code of this version of calib

    seal_unsealed(op.get_bind(), who="migration 0004")
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
