"""Validation records: a revision compared with independent implementations (``validations``).

`calib validate` keeps each comparison (per peer and parameter: ours, theirs, the
difference, u_c, E_n) with the calibration revision it compared, sealed by the digest of
its "validated" audit event (storage.validation).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

from storage.migrations.ddl import create_index, create_table, drop_index

revision = "0009_validations"
down_revision = "0008_seal_texts"


def upgrade() -> None:
    create_table(
        "validations",
        sa.Column("calibration_id", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("software_version", sa.String(length=100), nullable=False),
        sa.Column("document", sa.JSON(), nullable=False),
        sa.Column("digest", sa.String(length=64), nullable=False),
        references={"calibration_id": "calibrations"},
    )
    create_index("validations", "calibration_id")


def downgrade() -> None:
    drop_index("validations", "calibration_id")
    op.drop_table("validations")
