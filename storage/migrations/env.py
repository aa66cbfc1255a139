"""Alembic environment for the archive.

Normally run from `storage.db.Archive.upgrade`, which passes an open connection
(inside a transaction) in ``config.attributes["connection"]``. From the command
line (``alembic -c storage/alembic.ini ...``) the URL comes from
``-x url=...``, else env ``CALIB_ARCHIVE`` (a directory or a URL).
"""

from __future__ import annotations

from alembic import context
from sqlalchemy import Connection

from storage.db import resolve_archive
from storage.schema import Base

config = context.config
target_metadata = Base.metadata


def _url() -> str:
    url = context.get_x_argument(as_dictionary=True).get("url")
    return url or config.get_main_option("sqlalchemy.url") or resolve_archive(None).url


def _configure(connection: Connection) -> None:
    context.configure(
        connection=connection,
        target_metadata=target_metadata,
        # SQLite cannot ALTER most things: batch mode rebuilds the table instead.
        render_as_batch=connection.dialect.name == "sqlite",
        compare_type=True,
    )


def run_migrations_offline() -> None:
    url = _url()
    context.configure(
        url=url,
        target_metadata=target_metadata,
        literal_binds=True,
        render_as_batch=url.startswith("sqlite"),
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        _configure(connection)
        with context.begin_transaction():
            context.run_migrations()
        return
    archive = resolve_archive(_url())
    with archive.engine().begin() as connection:
        _configure(connection)
        with context.begin_transaction():
            context.run_migrations()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
