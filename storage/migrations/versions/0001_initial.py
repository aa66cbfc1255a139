"""Initial archive schema: devices, equipment, runs, raw files, calibrations with
revisions, processing steps, parameters (long table), check results.

Written out in full (not imported from storage.schema) so that this migration
keeps creating exactly this schema while storage/schema.py moves on.

Revision ID: 0001
Revises:
Create Date: 2026-11-22
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "devices",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("serial", sa.String(length=64), nullable=False),
        sa.Column("model", sa.String(length=200), nullable=False),
        sa.Column("manufacturer", sa.String(length=200), nullable=False),
        sa.Column("specification", sa.Text(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_devices")),
        sa.UniqueConstraint("serial", name=op.f("uq_devices_serial")),
    )
    op.create_table(
        "equipment",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=100), nullable=False),
        sa.Column("model", sa.String(length=200), nullable=True),
        sa.Column("serial", sa.String(length=200), nullable=False),
        sa.Column("accuracy_class", sa.String(length=100), nullable=True),
        sa.Column("calibration_due", sa.Date(), nullable=True),
        sa.Column("calibrated_on", sa.Date(), nullable=True),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_equipment")),
        sa.UniqueConstraint("kind", "serial", name=op.f("uq_equipment_kind_serial")),
    )
    op.create_table(
        "runs",
        sa.Column("id", sa.Integer(), nullable=False),
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
        sa.ForeignKeyConstraint(
            ["device_id"], ["devices.id"], name=op.f("fk_runs_device_id_devices")
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_runs")),
        sa.UniqueConstraint("raw_hash", name=op.f("uq_runs_raw_hash")),
        sa.UniqueConstraint("run_id", name=op.f("uq_runs_run_id")),
    )
    op.create_index(op.f("ix_runs_device_id"), "runs", ["device_id"], unique=False)
    op.create_index(op.f("ix_runs_started_at"), "runs", ["started_at"], unique=False)

    op.create_table(
        "calibrations",
        sa.Column("id", sa.Integer(), nullable=False),
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
        sa.CheckConstraint("revision >= 1", name=op.f("ck_calibrations_revision")),
        sa.ForeignKeyConstraint(["run_id"], ["runs.id"], name=op.f("fk_calibrations_run_id_runs")),
        sa.ForeignKeyConstraint(
            ["superseded_by"],
            ["calibrations.id"],
            name=op.f("fk_calibrations_superseded_by_calibrations"),
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_calibrations")),
        sa.UniqueConstraint("run_id", "revision", name=op.f("uq_calibrations_run_id_revision")),
        sa.UniqueConstraint(
            "run_id",
            "settings_hash",
            "software_version",
            name=op.f("uq_calibrations_run_id_settings_hash_software_version"),
        ),
    )
    op.create_table(
        "raw_files",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=500), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("size", sa.BigInteger(), nullable=False),
        sa.Column("format", sa.String(length=50), nullable=False),
        sa.Column("stored_path", sa.String(length=500), nullable=False),
        sa.CheckConstraint("size >= 0", name=op.f("ck_raw_files_size")),
        sa.ForeignKeyConstraint(["run_id"], ["runs.id"], name=op.f("fk_raw_files_run_id_runs")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_raw_files")),
        sa.UniqueConstraint("run_id", "name", name=op.f("uq_raw_files_run_id_name")),
    )
    op.create_index(op.f("ix_raw_files_sha256"), "raw_files", ["sha256"], unique=False)

    op.create_table(
        "run_equipment",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("equipment_id", sa.Integer(), nullable=False),
        sa.Column("calibration_due", sa.Date(), nullable=True),
        sa.Column("calibrated_on", sa.Date(), nullable=True),
        sa.ForeignKeyConstraint(
            ["equipment_id"], ["equipment.id"], name=op.f("fk_run_equipment_equipment_id_equipment")
        ),
        sa.ForeignKeyConstraint(["run_id"], ["runs.id"], name=op.f("fk_run_equipment_run_id_runs")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_run_equipment")),
        sa.UniqueConstraint(
            "run_id", "equipment_id", name=op.f("uq_run_equipment_run_id_equipment_id")
        ),
    )
    op.create_index(
        op.f("ix_run_equipment_equipment_id"), "run_equipment", ["equipment_id"], unique=False
    )
    op.create_index(op.f("ix_run_equipment_run_id"), "run_equipment", ["run_id"], unique=False)

    op.create_table(
        "check_results",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("calibration_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("value", sa.Float(), nullable=True),
        sa.Column("limit", sa.Float(), nullable=True),
        sa.Column("passed", sa.Boolean(), nullable=False),
        sa.Column("detail", sa.Text(), nullable=False),
        sa.Column("profile_name", sa.String(length=200), nullable=True),
        sa.Column("profile_version", sa.String(length=100), nullable=True),
        sa.ForeignKeyConstraint(
            ["calibration_id"],
            ["calibrations.id"],
            name=op.f("fk_check_results_calibration_id_calibrations"),
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_check_results")),
    )
    op.create_index(
        op.f("ix_check_results_calibration_id"), "check_results", ["calibration_id"], unique=False
    )

    op.create_table(
        "parameters",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("calibration_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=100), nullable=False),
        sa.Column("value", sa.Float(), nullable=False),
        sa.Column("std", sa.Float(), nullable=True),
        sa.Column("unit", sa.String(length=50), nullable=False),
        sa.Column("temperature_c", sa.Float(), nullable=True),
        sa.CheckConstraint("std IS NULL OR std >= 0", name=op.f("ck_parameters_std_nonnegative")),
        sa.ForeignKeyConstraint(
            ["calibration_id"],
            ["calibrations.id"],
            name=op.f("fk_parameters_calibration_id_calibrations"),
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_parameters")),
    )
    op.create_index(
        op.f("ix_parameters_calibration_id"), "parameters", ["calibration_id"], unique=False
    )
    op.create_index(op.f("ix_parameters_name"), "parameters", ["name"], unique=False)

    op.create_table(
        "processing_steps",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("calibration_id", sa.Integer(), nullable=False),
        sa.Column("seq", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("settings", sa.JSON(), nullable=False),
        sa.Column("statistics", sa.JSON(), nullable=False),
        sa.Column("software_version", sa.String(length=100), nullable=False),
        sa.Column("source_revision", sa.String(length=100), nullable=True),
        sa.ForeignKeyConstraint(
            ["calibration_id"],
            ["calibrations.id"],
            name=op.f("fk_processing_steps_calibration_id_calibrations"),
        ),
        sa.ForeignKeyConstraint(
            ["run_id"], ["runs.id"], name=op.f("fk_processing_steps_run_id_runs")
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_processing_steps")),
        sa.UniqueConstraint(
            "calibration_id", "seq", name=op.f("uq_processing_steps_calibration_id_seq")
        ),
    )
    op.create_index(
        op.f("ix_processing_steps_run_id"), "processing_steps", ["run_id"], unique=False
    )


def downgrade() -> None:
    op.drop_index(op.f("ix_processing_steps_run_id"), table_name="processing_steps")

    op.drop_table("processing_steps")
    op.drop_index(op.f("ix_parameters_name"), table_name="parameters")
    op.drop_index(op.f("ix_parameters_calibration_id"), table_name="parameters")

    op.drop_table("parameters")
    op.drop_index(op.f("ix_check_results_calibration_id"), table_name="check_results")

    op.drop_table("check_results")
    op.drop_index(op.f("ix_run_equipment_run_id"), table_name="run_equipment")
    op.drop_index(op.f("ix_run_equipment_equipment_id"), table_name="run_equipment")

    op.drop_table("run_equipment")
    op.drop_index(op.f("ix_raw_files_sha256"), table_name="raw_files")

    op.drop_table("raw_files")
    op.drop_table("calibrations")
    op.drop_index(op.f("ix_runs_started_at"), table_name="runs")
    op.drop_index(op.f("ix_runs_device_id"), table_name="runs")

    op.drop_table("runs")
    op.drop_table("equipment")
    op.drop_table("devices")
