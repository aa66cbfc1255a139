"""Initial archive schema: devices, equipment, runs, raw files, calibrations with
revisions, processing steps, parameters (long table), check results."""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

from storage.migrations.ddl import create_index, create_table, drop_index

revision = "0001"
down_revision = None


def upgrade() -> None:
    create_table(
        "devices",
        sa.Column("serial", sa.String(length=64), nullable=False),
        sa.Column("model", sa.String(length=200), nullable=False),
        sa.Column("manufacturer", sa.String(length=200), nullable=False),
        sa.Column("specification", sa.Text(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        unique=[("serial",)],
    )
    create_table(
        "equipment",
        sa.Column("kind", sa.String(length=100), nullable=False),
        sa.Column("model", sa.String(length=200), nullable=True),
        sa.Column("serial", sa.String(length=200), nullable=False),
        sa.Column("accuracy_class", sa.String(length=100), nullable=True),
        sa.Column("calibration_due", sa.Date(), nullable=True),
        sa.Column("calibrated_on", sa.Date(), nullable=True),
        unique=[("kind", "serial")],
    )
    create_table(
        "runs",
        sa.Column("run_id", sa.String(length=64), nullable=False),
        sa.Column("device_id", sa.Integer(), nullable=False),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("operator", sa.String(length=200), nullable=True),
        sa.Column("procedure", sa.String(length=100), nullable=False),
        sa.Column("site", sa.JSON(), nullable=False),
        sa.Column("gravity", sa.Float(), nullable=False),
        sa.Column("environment", sa.JSON(), nullable=False),
        sa.Column("manifest_text", sa.Text(), nullable=True),
        sa.Column("raw_hash", sa.String(length=64), nullable=False),
        sa.Column("tolerance_profile", sa.String(length=200), nullable=True),
        sa.Column("run_dir", sa.String(length=500), nullable=False),
        sa.Column("samples_path", sa.String(length=500), nullable=True),
        sa.Column("samples_sha256", sa.String(length=64), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        references={"device_id": "devices"},
        unique=[("raw_hash",), ("run_id",)],
    )
    create_index("runs", "device_id")
    create_index("runs", "started_at")
    create_table(
        "calibrations",
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("revision", sa.Integer(), nullable=False),
        sa.Column("settings_hash", sa.String(length=64), nullable=False),
        sa.Column("settings", sa.JSON(), nullable=False),
        sa.Column("software_version", sa.String(length=100), nullable=False),
        sa.Column("source_revision", sa.String(length=100), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("superseded_by", sa.Integer(), nullable=True),
        sa.Column("document", sa.JSON(), nullable=False),
        sa.Column("verdict", sa.String(length=20), nullable=False),
        sa.Column("profile_name", sa.String(length=200), nullable=True),
        sa.Column("profile_version", sa.String(length=100), nullable=True),
        checks={"revision": "revision >= 1"},
        references={"run_id": "runs", "superseded_by": "calibrations"},
        unique=[("run_id", "revision"), ("run_id", "settings_hash", "software_version")],
    )
    create_table(
        "raw_files",
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=500), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("size", sa.BigInteger(), nullable=False),
        sa.Column("format", sa.String(length=50), nullable=False),
        sa.Column("stored_path", sa.String(length=500), nullable=False),
        checks={"size": "size >= 0"},
        references={"run_id": "runs"},
        unique=[("run_id", "name")],
    )
    create_index("raw_files", "sha256")
    create_table(
        "run_equipment",
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("equipment_id", sa.Integer(), nullable=False),
        sa.Column("calibration_due", sa.Date(), nullable=True),
        sa.Column("calibrated_on", sa.Date(), nullable=True),
        references={"equipment_id": "equipment", "run_id": "runs"},
        unique=[("run_id", "equipment_id")],
    )
    create_index("run_equipment", "equipment_id")
    create_index("run_equipment", "run_id")
    create_table(
        "check_results",
        sa.Column("calibration_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("value", sa.Float(), nullable=True),
        sa.Column("limit", sa.Float(), nullable=True),
        sa.Column("passed", sa.Boolean(), nullable=False),
        sa.Column("detail", sa.Text(), nullable=False),
        sa.Column("profile_name", sa.String(length=200), nullable=True),
        sa.Column("profile_version", sa.String(length=100), nullable=True),
        references={"calibration_id": "calibrations"},
    )
    create_index("check_results", "calibration_id")
    create_table(
        "parameters",
        sa.Column("calibration_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=100), nullable=False),
        sa.Column("value", sa.Float(), nullable=False),
        sa.Column("std", sa.Float(), nullable=True),
        sa.Column("unit", sa.String(length=50), nullable=False),
        sa.Column("temperature_c", sa.Float(), nullable=True),
        checks={"std_nonnegative": "std IS NULL OR std >= 0"},
        references={"calibration_id": "calibrations"},
    )
    create_index("parameters", "calibration_id")
    create_index("parameters", "name")
    create_table(
        "processing_steps",
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("calibration_id", sa.Integer(), nullable=False),
        sa.Column("seq", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("settings", sa.JSON(), nullable=False),
        sa.Column("statistics", sa.JSON(), nullable=False),
        sa.Column("software_version", sa.String(length=100), nullable=False),
        sa.Column("source_revision", sa.String(length=100), nullable=True),
        references={"calibration_id": "calibrations", "run_id": "runs"},
        unique=[("calibration_id", "seq")],
    )
    create_index("processing_steps", "run_id")


def downgrade() -> None:
    drop_index("processing_steps", "run_id")
    op.drop_table("processing_steps")
    drop_index("parameters", "name")
    drop_index("parameters", "calibration_id")
    op.drop_table("parameters")
    drop_index("check_results", "calibration_id")
    op.drop_table("check_results")
    drop_index("run_equipment", "run_id")
    drop_index("run_equipment", "equipment_id")
    op.drop_table("run_equipment")
    drop_index("raw_files", "sha256")
    op.drop_table("raw_files")
    op.drop_table("calibrations")
    drop_index("runs", "started_at")
    drop_index("runs", "device_id")
    op.drop_table("runs")
    op.drop_table("equipment")
    op.drop_table("devices")
