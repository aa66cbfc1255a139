"""The device description of each run: ``runs.model``,
``runs.manufacturer``, ``runs.specification``.

Before, only the unit's row in ``devices`` held a description, the one its serial
was first archived under; a later run that named another model kept none of its
own. Runs archived before this revision get their device row's description, which
is also what their seals hold (storage.seal puts the run's description in a
record's ``devices``), so every seal still verifies.

SQLite adds a NOT NULL column only with a default and cannot drop that default
without rebuilding ``runs`` (which four tables reference): there the columns keep
the default ``''``; the archive always writes them. PostgreSQL drops it.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006_run_device"
down_revision = "0005"

_COLUMNS = (
    ("model", sa.String(length=200), False),
    ("manufacturer", sa.String(length=200), False),
    ("specification", sa.Text(), True),
)


def upgrade() -> None:
    for name, type_, nullable in _COLUMNS:
        op.add_column(
            "runs",
            sa.Column(name, type_, nullable=nullable, server_default=None if nullable else ""),
        )
    op.execute(
        "UPDATE runs SET "
        + ", ".join(
            f"{name} = (SELECT devices.{name} FROM devices WHERE devices.id = runs.device_id)"
            for name, _, _ in _COLUMNS
        )
    )
    if op.get_bind().dialect.name == "postgresql":
        for name, _, nullable in _COLUMNS:
            if not nullable:
                op.alter_column("runs", name, server_default=None)


def downgrade() -> None:
    for name, _, _ in reversed(_COLUMNS):
        op.drop_column("runs", name)
