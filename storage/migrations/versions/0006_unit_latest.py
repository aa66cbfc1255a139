"""Each unit's latest run and latest valid calibration, kept (issue 23): ``unit_latest``.

The fleet page picked, on every request, each unit's latest run and latest valid
calibration by walking the unit's runs (6k units of a model: ~50 ms of a 100k-run
archive's fleet page on SQLite). The derived table holds the picks per unit and the
verdict and profile of the latest run (storage.unit_latest): storage.archive rewrites a
unit's row in the transaction that archives or revises one of its runs, `calib verify`
compares the table with its derivation. Every existing unit's row is derived here.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

from storage.migrations.ddl import create_table

revision = "0006"
down_revision = "0005"


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
    from storage.unit_latest import rebuild  # the derivation of this version of calib

    rebuild(op.get_bind())


def downgrade() -> None:
    op.drop_table("unit_latest")
