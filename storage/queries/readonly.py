"""The archive read-only, for the archive browser (`calib serve`) and any reader.

`open_readonly` gives the archive read-only (`storage.db.Archive` with
``read_only=True``, the one read-only opener): SQLite with a ``mode=ro`` file URI
(and ``query_only``), PostgreSQL in read-only transactions as the read-only role
(storage.roles): a connecting role that may write switches to the reader role with
``SET ROLE``, and the start fails with the reason when it cannot. Every question of
storage.queries takes it like any Archive.
"""

from __future__ import annotations

from pathlib import Path

from sqlalchemy.engine import make_url

from storage.db import Archive
from storage.roles import READER


def open_readonly(archive: Archive, reader_role: str = READER) -> Archive:
    """The same archive, read-only (`Archive` with ``read_only=True``, `reader_role`);
    checks at once that it can be read.

    Raises
    ------
    FileNotFoundError : SQLite file missing (a read-only open never creates one).
    PermissionError : PostgreSQL role can write and cannot become `reader_role`.
    LookupError : no archive schema in the database.
    """
    ro = Archive(archive.url, archive.root, read_only=True, reader_role=reader_role)
    if ro.is_sqlite:
        db = make_url(ro.url).database
        path = Path(db).resolve() if db and db != ":memory:" else None
        if path is None or not path.is_file():
            raise FileNotFoundError(f"no archive database at {path or ro.url}")
    revision = ro.schema_revision()
    if revision is None:
        raise LookupError(f"{ro.display_url} holds no archive (no schema revision)")
    return ro
