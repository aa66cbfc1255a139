"""Thermal models: temperature-compensation polynomials fitted per device.

Written out in full (not imported from storage.schema) so that this migration
keeps creating exactly this table while storage/schema.py moves on.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "thermal_models",
        sa.Column("id", sa.Integer(), nullable=False),
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
        sa.CheckConstraint("t_max > t_min", name=op.f("ck_thermal_models_t_range")),
        sa.ForeignKeyConstraint(
            ["device_id"], ["devices.id"], name=op.f("fk_thermal_models_device_id_devices")
        ),
        sa.ForeignKeyConstraint(
            ["superseded_by"],
            ["thermal_models.id"],
            name=op.f("fk_thermal_models_superseded_by_thermal_models"),
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_thermal_models")),
    )
    op.create_index(
        op.f("ix_thermal_models_device_id"), "thermal_models", ["device_id"], unique=False
    )


def downgrade() -> None:
    op.drop_index(op.f("ix_thermal_models_device_id"), table_name="thermal_models")
    op.drop_table("thermal_models")
