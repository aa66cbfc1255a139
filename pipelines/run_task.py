"""The work of one batch task: one run through `process_run`, transient errors told apart.

This module imports no Prefect, so a worker process that only runs tasks' work
(`pipelines.runners.WorkerProcesses`) loads the pipeline and nothing else. The
flow (`pipelines.flows`) wraps `process_run_for_batch` in its Prefect task and
retries what raises `TransientError`.
"""

from __future__ import annotations

import errno
import time
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from pipelines.ingest import RunSource
from pipelines.process import process_run, run_outcome
from storage.archive import StaleCheckError
from storage.db import Archive
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
        if isinstance(e, TransientError | ConnectionError | TimeoutError | BrokenProcessPool
                      | StaleCheckError):  # fmt: skip
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

    archive = Archive(url=archive_url, root=Path(archive_root))
    try:
        return process_run(source, archive, reraise=transient)
    except Exception as exc:  # only what `transient` let through
        raise TransientError(f"{source.name}: {type(exc).__name__}: {exc}") from exc
    finally:
        archive.dispose()  # one engine per task: give its connections back now


def call_with_retries(
    call: Callable[[], dict[str, Any]], gave_up: Callable[[TransientError], dict[str, Any]]
) -> dict[str, Any]:
    """``call()`` in this process, retried as the batch flow retries its tasks.

    A `TransientError` is tried again after each of RETRY_DELAYS_S (RETRIES more
    attempts); after the last, the outcome is ``gave_up(error)``.
    """
    for delay in RETRY_DELAYS_S[:RETRIES]:
        try:
            return call()
        except TransientError:
            time.sleep(delay)
    try:
        return call()
    except TransientError as exc:
        return gave_up(exc)


def gave_up(source: str, serial: str, exc: BaseException, run_id: str = "") -> dict[str, Any]:
    """The failed outcome of a run whose attempts (1 + RETRIES) all met transient errors."""
    return run_outcome(source=source, serial=serial, status="failed", run_id=run_id,
                       error=f"gave up after {RETRIES + 1} attempts: {exc}")  # fmt: skip
