"""Shared fixtures: a throw-away PostgreSQL server, and archives on both back ends.

Also the two test tiers and the session's cleanup:

- tiers: `make test` runs everything; `make test-fast` (``-m "not slow and not postgres and
  not browser and not e2e"``) the tests a contributor runs before every commit. A test
  using the PostgreSQL server (fixture ``postgres_server``, directly or through another
  fixture) is marked ``postgres`` and one using the Prefect server (``prefect_harness``)
  ``e2e`` here, so a new test lands in its tier by what it uses; ``slow`` and ``browser``
  are set in the modules (``pytestmark``) or on the tests.
- cleanup: every temporary folder of the session (pytest's ``tmp_path``, ``tempfile``,
  the PostgreSQL data directory, Prefect's, multiprocessing's) lies in one session
  folder. SIGTERM and SIGHUP end the run like Ctrl-C (fixtures torn down: the server
  stops). A watchdog process (calib_testing.watchdog) removes the folder once the run's
  process has ended, whatever ended it (after its own exit handlers, which may still use
  the folder), and stops a server left running in it (a run killed outright).
  ``--basetemp DIR`` keeps pytest's folders in DIR instead.
"""

from __future__ import annotations

import contextlib
import os
import signal
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
# Typesetting a certificate at archive time costs seconds per run (docs/reports.md); the
# suite archives hundreds of runs. Tests that read issued certificates ask for them with
# the `issuing_certificates` fixture.
ISSUE_ENV = "CALIB_ISSUE_CERTIFICATES"
os.environ.setdefault(ISSUE_ENV, "0")

from calib_testing.pgserver import ServerUnavailableError, private_server  # noqa: E402
from calib_testing.watchdog import clean_up_after  # noqa: E402
from storage.db import Archive, default_archive_url  # noqa: E402
from storage.schema import TABLES  # noqa: E402

# --- tiers ------------------------------------------------------------------------

# fixture -> marker of every test that uses it (directly or through other fixtures)
MARK_BY_FIXTURE = {"postgres_server": "postgres", "prefect_harness": "e2e"}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        for fixture, marker in MARK_BY_FIXTURE.items():
            if fixture in getattr(item, "fixturenames", ()):
                item.add_marker(marker)


# --- the session's folder and its cleanup -------------------------------------------

_session: dict[str, object] = {}


def _end_like_ctrl_c(signum: int, frame: object) -> None:
    if os.getpid() != _session.get("pid"):  # a forked worker inherited the handler
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


def pytest_configure(config: pytest.Config) -> None:
    folder = Path(tempfile.mkdtemp(prefix="calib-tests-"))
    folder.chmod(0o755)  # the PostgreSQL server (user postgres) keeps its data in here
    _session.update(pid=os.getpid(), folder=folder, watchdog=clean_up_after(folder))
    tempfile.tempdir = str(folder)  # pytest's tmp_path base too (resolved on first use)
    os.environ["TMPDIR"] = str(folder)  # and every child process's
    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, _end_like_ctrl_c)


# --- PostgreSQL ---------------------------------------------------------------


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[str]:
    """Start a private PostgreSQL server (calib_testing.pgserver); yield its `postgres` db URL."""
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
    """One real, temporary Prefect server and database for the whole session (slow to start)."""
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=120):
        yield


# --- calib serve ---------------------------------------------------------------


@pytest.fixture(scope="session")
def serve_sample(tmp_path_factory: pytest.TempPathFactory):
    """The archive of tests/serve_sample.py (real pipeline, real SQLite file), built once."""
    import serve_sample as sample

    return sample.build(tmp_path_factory.mktemp("serve"))


@pytest.fixture(scope="module")
def archived_sample(tmp_path_factory: pytest.TempPathFactory) -> tuple[Archive, str]:
    """The MPU-6000 sample run (data_samples/mpu6000_MPU0001) processed into an archive of
    the module's own: (archive, run id)."""
    from calib_testing.archives import new_archive, processed_run

    arch = new_archive(tmp_path_factory.mktemp("sample"))
    sample = Path(__file__).resolve().parent.parent / "data_samples" / "mpu6000_MPU0001"
    return arch, processed_run(sample, arch)


@pytest.fixture(scope="module")
def client(serve_sample):
    """A web client of `calib serve` on the sample archive (read-only), for the module."""
    from fastapi.testclient import TestClient

    from pipelines.web.app import create_app
    from storage import queries

    ro = queries.open_readonly(serve_sample.archive)
    with TestClient(create_app(ro)) as c:
        yield c
    ro.dispose()


@pytest.fixture(scope="module")
def issuing_certificates() -> Iterator[None]:
    """Certificates issued when runs are archived, for the module that asks (module scope,
    so its archives built by module fixtures get them too)."""
    before = os.environ.get(ISSUE_ENV)
    os.environ[ISSUE_ENV] = "1"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(ISSUE_ENV, None)
        else:
            os.environ[ISSUE_ENV] = before
