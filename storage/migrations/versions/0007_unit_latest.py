"""Each unit's latest run and latest valid calibration, kept (issue 23): ``unit_latest``.

The fleet page picked, on every request, each unit's latest run and latest valid
calibration by walking the unit's runs (6k units of a model: ~50 ms of a 100k-run
archive's fleet page on SQLite). The derived table holds the picks per unit and the
verdict and profile of the latest run (storage.unit_latest): storage.archive rewrites a
unit's row in the transaction that archives or revises one of its runs, `calib verify`
compares the table with its derivation. ``unit_latest_values`` holds, per unit, the
parameters of that valid calibration (one per name: of temperature-dependent values the
one nearest 20 deg C), keyed by model, name and serial: a fleet's values of one
parameter are one range of the key. Every existing unit's rows are derived here.
"""

from __future__ import annotations

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
    from storage.unit_latest import rebuild  # the derivation of this version of calib

    rebuild(op.get_bind())


def downgrade() -> None:
    drop_index("unit_latest_values", "device_id")
    op.drop_table("unit_latest_values")
    op.drop_table("unit_latest")
