"""Table and index builders for the migrations in versions/, frozen with them.

A migration keeps creating exactly the schema of its day, so it never imports
storage.schema (which moves on): it writes its tables out column by column. What
every table has in common is built here: the integer key ``id`` and the names of
constraints and indexes as ``storage.schema.NAMING`` makes them (``pk_<table>``,
``fk_<table>_<column>_<referred table>``, ``uq_<table>_<columns>``,
``ck_<table>_<name>``, ``ix_<table>_<columns>``). Like a migration, a builder is
never changed once a migration uses it; a later schema gets a new migration.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import sqlalchemy as sa
from alembic import op


def create_table(
    name: str,
    *columns: sa.Column,
    key: sa.Column | None = None,
    checks: Mapping[str, str] | None = None,
    references: Mapping[str, str] | None = None,
    unique: Sequence[tuple[str, ...]] = (),
) -> None:
    """Create table `name`: its primary key column, `columns`, then its named constraints.

    Parameters
    ----------
    name : the table.
    columns : the columns after the key, in order.
    key : the primary key column; default an integer ``id``.
    checks : constraint name (without ``ck_<table>_``) -> SQL condition.
    references : column -> referred table (its ``id``), a foreign key each.
    unique : column sets, a unique constraint each.

    The constraints come in the order Alembic's autogenerate wrote them (checks,
    foreign keys, primary key, unique), so SQLite stores the same CREATE TABLE text.
    """
    key = sa.Column("id", sa.Integer(), nullable=False) if key is None else key
    op.create_table(
        name,
        key,
        *columns,
        *(
            sa.CheckConstraint(sql, name=op.f(f"ck_{name}_{ck}"))
            for ck, sql in (checks or {}).items()
        ),
        *(
            sa.ForeignKeyConstraint([col], [f"{table}.id"], name=op.f(f"fk_{name}_{col}_{table}"))
            for col, table in (references or {}).items()
        ),
        sa.PrimaryKeyConstraint(key.name, name=op.f(f"pk_{name}")),
        *(sa.UniqueConstraint(*cols, name=op.f(f"uq_{name}_{'_'.join(cols)}")) for cols in unique),
    )


def create_index(table: str, *columns: str) -> None:
    """A (non-unique) index ``ix_<table>_<columns>`` on `columns` of `table`."""
    op.create_index(op.f(f"ix_{table}_{'_'.join(columns)}"), table, list(columns), unique=False)


def drop_index(table: str, *columns: str) -> None:
    """Drop the index that ``create_index(table, *columns)`` created."""
    op.drop_index(op.f(f"ix_{table}_{'_'.join(columns)}"), table_name=table)
