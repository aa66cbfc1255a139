"""When a run's certificate is issued: right after the run is archived, or, in a batch, on a
thread of its own beside the solving of the next runs.

`process_run` calls `issue_certificate` once the revision is committed. Alone, the
certificate is issued then and there. Inside `issuing_beside()` (a batch in this process:
`pipelines.direct`, the Prefect flows' task threads) it is handed to one thread that
issues the batch's certificates in turn while the next runs are read and solved
(typesetting releases the interpreter), and leaving the block waits for every one of
them: a batch ends with its certificates issued, as before. Worker processes (the
process runner, Dask) issue theirs as each run ends, in parallel with the other workers.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextvars import ContextVar

from storage import write_failures
from storage.db import Archive

log = logging.getLogger(__name__)

ISSUE_ENV = "CALIB_ISSUE_CERTIFICATES"  # "0": no certificate at archive time

# The batch's certificate thread, seen by the batch's task threads (Prefect copies the
# context into each task run).
_beside: ContextVar[ThreadPoolExecutor | None] = ContextVar("calib_certificates", default=None)


def _issue_logged(archive: Archive, run_id: str) -> None:
    """Issue the run's certificate; a failure is logged with how to issue it later."""
    from pipelines.reports.issue import issue

    try:
        issue(archive, run_id)
    except Exception as exc:  # noqa: BLE001 - the archived run stands; said, not hidden
        problem = write_failures.describe(exc, archive.url) or f"{type(exc).__name__}: {exc}"
        log.warning(
            "run %s is archived but its certificate was not issued: %s; issue it "
            "with `calib report %s`",
            run_id,
            problem,
            run_id,
        )


def issue_certificate(archive: Archive, run_id: str) -> Future | None:
    """Issue the archived revision's certificate (HTML and PDF, `pipelines.reports.issue`).

    The run stays archived if this fails (a full disk, a read-only folder): the failure
    is logged with how to issue it later (`calib report RUN`). Environment
    ``CALIB_ISSUE_CERTIFICATES=0`` leaves the issue to `calib report` (bulk loads, test
    suites). Inside `issuing_beside` the issue is queued on the batch's certificate
    thread (its future returned); else it is done before this returns (None).
    """
    if os.environ.get(ISSUE_ENV, "1").strip() == "0":
        return None
    thread = _beside.get()
    if thread is None:
        _issue_logged(archive, run_id)
        return None
    return thread.submit(_issue_logged, archive, run_id)


@contextlib.contextmanager
def issuing_beside() -> Iterator[None]:
    """Within the block, certificates are issued on one thread beside the caller's next
    runs; leaving it waits until every one is issued (also when the block raises)."""
    if _beside.get() is not None:  # a batch inside a batch: the outer one's thread
        yield
        return
    thread = ThreadPoolExecutor(1, thread_name_prefix="calib-certificates")
    token = _beside.set(thread)
    try:
        yield
    finally:
        _beside.reset(token)
        thread.shutdown(wait=True)
