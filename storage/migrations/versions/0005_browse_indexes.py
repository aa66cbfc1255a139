"""Indexes for the archive browser's fleet and equipment pages.

- ``calibrations(run_id, verdict, profile_name) WHERE superseded_by IS NULL``
  (PostgreSQL: INCLUDE id): the current revision of a run and its verdict from the
  index alone, one step per unit when a fleet's latest (valid) runs are picked;
- ``runs(device_id, started_at, id)`` replaces ``runs(device_id, started_at)``: a
  unit's latest run, the later archived of two with the same start, is the last
  entry (PostgreSQL sorted each unit's runs by id for it; SQLite keys every index by
  the row id already, so there it only renames the index);
- ``run_equipment(equipment_id, calibration_due)``: the latest due date recorded for
  each piece of equipment without reading its runs.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"

CURRENT = sa.text("superseded_by IS NULL")


def upgrade() -> None:
    op.create_index(
        "ix_calibrations_current",
        "calibrations",
        ["run_id", "verdict", "profile_name"],
        sqlite_where=CURRENT,
        postgresql_where=CURRENT,
        postgresql_include=["id"],
    )
    op.create_index("ix_runs_device_id_started_at_id", "runs", ["device_id", "started_at", "id"])
    op.drop_index("ix_runs_device_id_started_at", table_name="runs")
    op.create_index(
        "ix_run_equipment_equipment_id_calibration_due",
        "run_equipment",
        ["equipment_id", "calibration_due"],
    )


def downgrade() -> None:
    op.drop_index("ix_run_equipment_equipment_id_calibration_due", table_name="run_equipment")
    op.create_index("ix_runs_device_id_started_at", "runs", ["device_id", "started_at"])
    op.drop_index("ix_runs_device_id_started_at_id", table_name="runs")
    op.drop_index("ix_calibrations_current", table_name="calibrations")
