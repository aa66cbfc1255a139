"""The connection a question of storage.queries runs on (storage.queries._common.reading):
on PostgreSQL in autocommit (no transaction held open by a question), handed back to the
pool transactional for the writers; on SQLite one read transaction."""

from __future__ import annotations

from pathlib import Path

from sqlalchemy import select, text
from test_archive import make_run

from storage import queries
from storage.archive import archive_run
from storage.db import Archive
from storage.queries._common import reading
from storage.schema import Device


def test_a_question_holds_no_transaction_and_writers_keep_theirs(
    empty_archive: Archive, tmp_path: Path
) -> None:
    archive = empty_archive
    archive.upgrade()
    run = make_run(tmp_path / "in", serial="0042")
    archive_run(archive, run)
    archive.dispose()  # one pooled connection from here on: the question's, then the writer's

    with reading(archive) as conn:
        dbapi = conn.connection.dbapi_connection
        assert conn.execute(select(Device.serial)).scalars().all() == ["0042"]
        if archive.is_sqlite:
            assert dbapi.in_transaction  # one snapshot for all statements of a question
        else:
            from psycopg.pq import TransactionStatus

            assert dbapi.info.transaction_status == TransactionStatus.IDLE  # no BEGIN sent
    assert not queries.latest_valid(archive, "0042").empty

    with archive.engine().connect() as conn:
        assert conn.connection.dbapi_connection is dbapi  # the question's connection, reused
        conn.execute(text("UPDATE devices SET manufacturer = 'changed'"))
        conn.rollback()  # undone only if the writer's connection is transactional again
    with reading(archive) as conn:
        assert conn.execute(select(Device.manufacturer)).scalar_one() != "changed"
