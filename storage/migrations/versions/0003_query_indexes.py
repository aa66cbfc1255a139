"""Indexes for the archive's queries.

- ``runs(device_id, started_at)``: a unit's runs in time order (latest valid
  calibration as of a date, parameter history);
- ``parameters(calibration_id, name)``: one parameter of one calibration
  (history, lineage, fleet); it replaces ``parameters(calibration_id)``, whose
  lookups it serves as well, so that bulk loads maintain one index less;
- ``devices(model)``: units and fleet of one model.
"""

from __future__ import annotations

from alembic import op

revision = "0003"
down_revision = "0002"


def upgrade() -> None:
    op.create_index("ix_runs_device_id_started_at", "runs", ["device_id", "started_at"])
    op.create_index("ix_parameters_calibration_id_name", "parameters", ["calibration_id", "name"])
    op.drop_index("ix_parameters_calibration_id", table_name="parameters")
    op.create_index("ix_devices_model", "devices", ["model"])


def downgrade() -> None:
    op.drop_index("ix_devices_model", table_name="devices")
    op.create_index("ix_parameters_calibration_id", "parameters", ["calibration_id"])
    op.drop_index("ix_parameters_calibration_id_name", table_name="parameters")
    op.drop_index("ix_runs_device_id_started_at", table_name="runs")
