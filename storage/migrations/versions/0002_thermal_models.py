"""Thermal models: temperature-compensation polynomials fitted per device."""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

from storage.migrations.ddl import create_index, create_table, drop_index

revision = "0002"
down_revision = "0001"


def upgrade() -> None:
    create_table(
        "thermal_models",
        sa.Column("device_id", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("model_name", sa.String(length=100), nullable=False),
        sa.Column("model_version", sa.String(length=100), nullable=False),
        sa.Column("t_ref", sa.Float(), nullable=False),
        sa.Column("t_min", sa.Float(), nullable=False),
        sa.Column("t_max", sa.Float(), nullable=False),
        sa.Column("document", sa.JSON(), nullable=False),
        sa.Column("calibration_ids", sa.JSON(), nullable=False),
        sa.Column("superseded_by", sa.Integer(), nullable=True),
        checks={"t_range": "t_max > t_min"},
        references={"device_id": "devices", "superseded_by": "thermal_models"},
    )
    create_index("thermal_models", "device_id")


def downgrade() -> None:
    drop_index("thermal_models", "device_id")
    op.drop_table("thermal_models")
