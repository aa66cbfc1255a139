"""The stored JSON texts of a format 2 seal in a column of their own: ``seals.texts``.

Verify reads every seal's ``record -> 'files'`` and ``-> 'format'``; PostgreSQL's
``json`` type (and SQLite) parse the whole value for that. With the texts inside
the record that was tens of kB a seal, a large part of the seal pass on PostgreSQL
(storage.seal). Nullable: format 1 seals have no texts.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008_seal_texts"
down_revision = "0007"


def upgrade() -> None:
    op.add_column("seals", sa.Column("texts", sa.JSON(), nullable=True))


def downgrade() -> None:
    op.drop_column("seals", "texts")
