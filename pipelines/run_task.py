"""The work of one batch task: one run through `process_run`, transient errors told apart.

This module imports no Prefect, so a worker process that only runs tasks' work
(`pipelines.runners.WorkerProcesses`) loads the pipeline and nothing else. The
flow (`pipelines.flows`) wraps `process_run_for_batch` in its Prefect task and
retries what raises `TransientError`.
"""

from __future__ import annotations

import errno
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from sqlalchemy.engine import make_url

from pipelines.ingest import RunSource
from pipelines.process import process_run, run_outcome
from storage.archive import StaleCheckError
from storage.db import Archive, sqlite_read_only
from storage.write_failures import exception_chain

# OS errors of a network file system or connection that is briefly away; ENOENT
# is not among them (a missing file is a bad run; a vanished run folder is
# recognised separately, because the folder was there when the batch began).
RETRIES = 2  # attempts after the first
RETRY_DELAYS_S = [1.0, 4.0]  # s before the 1st and 2nd retry: a lock or a share outage passes

TRANSIENT_ERRNOS = frozenset(
    {
        errno.ESTALE,
        errno.EIO,
        errno.EAGAIN,
        errno.EBUSY,
        errno.ENOTCONN,
        errno.ETIMEDOUT,
        errno.ECONNRESET,
        errno.ECONNREFUSED,
        errno.ECONNABORTED,
        errno.EHOSTDOWN,
        errno.EHOSTUNREACH,
        errno.ENETDOWN,
        errno.ENETUNREACH,
    }
)
# Database errors that a later attempt can get past (SQLite and PostgreSQL wording).
TRANSIENT_DB_TEXT = (
    "database is locked",
    "database table is locked",
    "could not connect",
    "connection refused",
    "server closed the connection",
    "terminating connection",
    "connection is closed",
    "deadlock detected",
    "could not serialize access",
    "too many clients",
)


# Archives (engines) kept open in this process between a batch's runs, newest last.
MAX_OPEN_ARCHIVES = 4
_open_archives: OrderedDict[tuple[Any, ...], Archive] = OrderedDict()
_open_lock = threading.Lock()


def _forget_open_archives() -> None:
    # A forked child must not use its parent's pooled connections: drop them, unclosed.
    for archive in _open_archives.values():
        if archive._engine is not None:
            archive._engine.dispose(close=False)
    _open_archives.clear()


os.register_at_fork(after_in_child=_forget_open_archives)


def batch_archive(archive_url: str, archive_root: str) -> Archive:
    """The archive at `archive_url` / `archive_root`, one open engine per process.

    A batch's runs in one worker process share it: a new engine per run paid,
    every run, for a connection with its set-up and for compiling every SQL
    statement again (SQLAlchemy's statement cache belongs to the engine),
    a cost per run that benchmarks/batch.py shows. The key holds what a fresh
    `Archive` would decide anew: for SQLite the database file's identity (a file
    deleted and made again is not reached through an old connection) and whether
    it can be written. At most MAX_OPEN_ARCHIVES stay open; thread-safe; a
    forked child starts with none.
    """
    url = make_url(archive_url)
    identity = None
    if url.get_backend_name() == "sqlite" and url.database and url.database != ":memory:":
        try:
            st = os.stat(url.database)
            identity = (st.st_dev, st.st_ino)
        except OSError:
            identity = None
    key = (archive_url, archive_root, identity, sqlite_read_only(archive_url))
    with _open_lock:
        archive = _open_archives.get(key)
        if archive is None:
            archive = _open_archives[key] = Archive(url=archive_url, root=Path(archive_root))
        _open_archives.move_to_end(key)
        while len(_open_archives) > MAX_OPEN_ARCHIVES:
            _open_archives.popitem(last=False)[1].dispose()
    return archive


class TransientError(RuntimeError):
    """A run failed for a reason that may go away; the batch flow retries it."""


def is_transient(exc: BaseException) -> bool:
    """Whether an error may go away on retry: a locked or unreachable database, a flaky share.

    Looks through the exception's causes (and SQLAlchemy's wrapped driver
    error), so an ``IngestError`` raised from an ``ESTALE`` counts as transient.
    A worker process that died under a run (``BrokenProcessPool``) counts too:
    the run is tried again in a new one, and a run that kills its worker every
    time fails once its retries are spent. So does a run whose passed
    ``device:description`` check another run of its unit made stale
    (`storage.archive.StaleCheckError`): the retry checks it again.
    """
    from sqlalchemy.exc import DBAPIError

    for e in exception_chain(exc):
        if isinstance(
            e, TransientError | ConnectionError | TimeoutError | BrokenProcessPool | StaleCheckError
        ):
            return True
        if isinstance(e, OSError) and e.errno in TRANSIENT_ERRNOS:
            return True
        if isinstance(e, DBAPIError) and e.connection_invalidated:
            return True
        is_db_error = isinstance(e, DBAPIError) or type(e).__name__ == "OperationalError"
        if is_db_error and any(s in str(e).lower() for s in TRANSIENT_DB_TEXT):
            return True
    return False


def process_run_for_batch(source: RunSource, archive_url: str, archive_root: str) -> dict[str, Any]:
    """One run of a batch through `process_run`, in whichever process the task's work runs.

    Returns the run's outcome dict (a failing run is reported in it); raises
    ``TransientError`` for a failure worth another attempt. Arguments and
    result are small and picklable, so the call can be shipped to a worker.
    """

    def transient(exc: BaseException) -> bool:
        # The folder was found when the batch began: if it is gone now, its share went away.
        return is_transient(exc) or not source.folder.is_dir()

    archive = batch_archive(archive_url, archive_root)
    try:
        return process_run(source, archive, reraise=transient)
    except Exception as exc:  # only what `transient` let through
        archive.dispose()  # the retry connects afresh
        raise TransientError(f"{source.name}: {type(exc).__name__}: {exc}") from exc


def run_in_process(
    items: list[Any],
    call: Callable[[Any], dict[str, Any]],
    gave_up: Callable[[Any, TransientError], dict[str, Any]],
    on_progress: Callable[[int, int, dict[str, Any]], None] | None = None,
    done: list[dict[str, Any]] | None = None,
) -> list[dict[str, Any]]:
    """``call(item)`` for each item in this process, one after the other, retried as the
    batch flow retries its tasks; the outcomes of `done` (settled before), then theirs.

    A `TransientError` is tried again after each of RETRY_DELAYS_S (RETRIES more
    attempts); after the last, the outcome is ``gave_up(item, error)``. `on_progress`
    gets (outcomes so far, total, the last outcome) after each, `done` first.
    """
    outcomes: list[dict[str, Any]] = []
    total = len(done or []) + len(items)
    for item in done or []:
        outcomes.append(item)
        if on_progress is not None:
            on_progress(len(outcomes), total, item)
    for item in items:
        for delay in [*RETRY_DELAYS_S[:RETRIES], None]:
            try:
                outcome = call(item)
                break
            except TransientError as exc:
                if delay is None:
                    outcome = gave_up(item, exc)
                else:
                    time.sleep(delay)
        outcomes.append(outcome)
        if on_progress is not None:
            on_progress(len(outcomes), total, outcome)
    return outcomes


def gave_up(source: str, serial: str, exc: BaseException, run_id: str = "") -> dict[str, Any]:
    """The failed outcome of a run whose attempts (1 + RETRIES) all met transient errors."""
    return run_outcome(
        source=source,
        serial=serial,
        status="failed",
        run_id=run_id,
        error=f"gave up after {RETRIES + 1} attempts: {exc}",
    )
