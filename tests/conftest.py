"""Shared fixtures: a throw-away PostgreSQL server, and archives on both back ends."""

from __future__ import annotations

import contextlib
import os
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")

from storage.db import Archive, default_archive_url  # noqa: E402
from storage.pgserver import ServerUnavailableError, private_server  # noqa: E402
from storage.schema import TABLES  # noqa: E402

# --- PostgreSQL ---------------------------------------------------------------


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[str]:
    """Start a private PostgreSQL server (storage.pgserver); yield the URL of its `postgres` db."""
    try:
        with private_server() as url:
            yield url
    except ServerUnavailableError as exc:
        if os.environ.get("CI"):  # CI runs `make test`, which installs the server: never skip there
            pytest.fail(f"{exc} although `make test` installs the server")
        pytest.skip(str(exc))
    except RuntimeError as exc:  # initdb or the start failed: the message holds the log
        pytest.fail(str(exc))


def _admin_db(url: str, sql: str) -> None:
    """Run one statement outside a transaction (CREATE DATABASE needs that)."""
    import psycopg

    dsn = url.replace("postgresql+psycopg://", "postgresql://")
    with psycopg.connect(dsn, autocommit=True) as conn:
        conn.execute(sql)


@contextlib.contextmanager
def _fresh_pg_database(server_url: str) -> Iterator[str]:
    name = "t_" + uuid.uuid4().hex[:12]
    _admin_db(server_url, f'CREATE DATABASE "{name}"')
    try:
        yield server_url.rsplit("/", 1)[0] + "/" + name
    finally:
        _admin_db(server_url, f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture
def postgres_url(postgres_server: str) -> Iterator[str]:
    """URL of an empty database of its own on the session's PostgreSQL server."""
    with _fresh_pg_database(postgres_server) as url:
        yield url


# --- archives -----------------------------------------------------------------


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def empty_archive(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Archive]:
    """An archive with no schema yet, on each back end; files under tmp_path/store."""
    root = tmp_path / "store"
    if request.param == "sqlite":
        archive = Archive(default_archive_url(root), root)
        yield archive
        archive.dispose()
        return
    with _fresh_pg_database(request.getfixturevalue("postgres_server")) as url:
        archive = Archive(url, root)
        yield archive
        archive.dispose()


@pytest.fixture(scope="session")
def _pg_schema_database(postgres_server: str) -> Iterator[str]:
    """One PostgreSQL database with the current schema, emptied before each test using it."""
    with _fresh_pg_database(postgres_server) as url:
        archive = Archive(url, Path(tempfile.gettempdir()))
        archive.upgrade()
        archive.dispose()
        yield url


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def archive(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Archive]:
    """An empty archive with the current schema, on each back end; files under tmp_path/store.

    PostgreSQL reuses one migrated database (TRUNCATE between tests): creating
    and migrating a database per test would cost more than the tests.
    """
    root = tmp_path / "store"
    if request.param == "sqlite":
        archive = Archive(default_archive_url(root), root)
        archive.upgrade()
    else:
        url = request.getfixturevalue("_pg_schema_database")
        tables = ", ".join(f'"{t}"' for t in TABLES)
        _admin_db(url, f"TRUNCATE {tables} RESTART IDENTITY CASCADE")
        archive = Archive(url, root)
    yield archive
    archive.dispose()


# --- Prefect -------------------------------------------------------------------


@pytest.fixture(scope="session")
def prefect_harness() -> Iterator[None]:
    """One real, temporary Prefect server and database for the whole session (~8 s to start)."""
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=120):
        yield


# --- calib serve ---------------------------------------------------------------


@pytest.fixture(scope="session")
def serve_sample(tmp_path_factory: pytest.TempPathFactory):
    """The archive of tests/serve_sample.py (real pipeline, real SQLite file), built once."""
    import serve_sample as sample

    return sample.build(tmp_path_factory.mktemp("serve"))
