"""Shared fixtures: a throw-away PostgreSQL server, and archives on both back ends."""

from __future__ import annotations

import contextlib
import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")

from storage.db import Archive, default_archive_url  # noqa: E402
from storage.schema import TABLES

# --- PostgreSQL ---------------------------------------------------------------

PG_START_TIMEOUT_S = 30


def _pg_bindir() -> Path | None:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    return Path(initdb).parent if initdb else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[str]:
    """Start a private PostgreSQL server; yield the URL of its `postgres` database.

    initdb refuses to run as root, so as root the server runs as the `postgres`
    user (`runuser`), with its data directory in a fresh folder under /tmp.
    """
    bindir = _pg_bindir()
    if bindir is None:
        if os.environ.get("CI"):  # CI runs `make test`, which installs the server: never skip there
            pytest.fail("PostgreSQL server binaries not found although `make test` installs them")
        pytest.skip(
            "PostgreSQL server binaries (initdb, pg_ctl) not found: `make test` installs "
            "them (scripts/ensure_postgres.sh), or apt-get install postgresql"
        )
    as_root = os.geteuid() == 0
    prefix: list[str] = []
    if as_root:
        try:
            pw = pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root but there is no `postgres` user to run the server as")
        prefix = ["runuser", "-u", "postgres", "--"]
    base = Path(tempfile.mkdtemp(prefix="calib-pg-", dir="/tmp"))
    base.chmod(0o755)
    data = base / "data"
    data.mkdir()
    if as_root:
        for p in (base, data):
            os.chown(p, pw.pw_uid, pw.pw_gid)
    port = _free_port()

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [*prefix, *args], capture_output=True, text=True, timeout=PG_START_TIMEOUT_S
        )

    init = run(
        str(bindir / "initdb"),
        "-D",
        str(data),
        "-U",
        "postgres",
        "-A",
        "trust",
        "-E",
        "UTF8",
        "--no-sync",
    )
    if init.returncode:
        shutil.rmtree(base, ignore_errors=True)
        pytest.fail(f"initdb failed:\n{init.stderr}")
    opts = f"-p {port} -k {base} -c listen_addresses=127.0.0.1 -c fsync=off"
    start = run(
        str(bindir / "pg_ctl"),
        "-D",
        str(data),
        "-o",
        opts,
        "-l",
        str(base / "log"),
        "-w",
        "-t",
        str(PG_START_TIMEOUT_S),
        "start",
    )
    if start.returncode:
        log = (base / "log").read_text() if (base / "log").exists() else ""
        shutil.rmtree(base, ignore_errors=True)
        pytest.fail(f"PostgreSQL did not start:\n{start.stderr}\n{log}")
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:{port}/postgres"
    finally:
        run(str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop")
        shutil.rmtree(base, ignore_errors=True)


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
