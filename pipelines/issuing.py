"""When a run's certificate is issued: right after the run is archived, or, in a batch, on a
thread of its own beside the solving of the next runs.

`process_run` calls `issue_certificate` once the revision is committed. Alone, the
certificate is issued then and there. Inside `issuing_beside()` (a batch in this process:
`pipelines.direct`, the Prefect flows' task threads) it is handed to one thread that
issues the batch's certificates in turn while the next runs are read and solved
(typesetting releases the interpreter), and leaving the block waits for every one of
them: a batch ends with its certificates issued, as before. Worker processes (the
process runner, Dask) issue theirs as each run ends, in parallel with the other workers.

A certificate that cannot be issued leaves its run archived (an issue writes its files
and its audit event together, or neither: `pipelines.reports.issue`); the run's outcome
says why in its message (`with_note`), whether it was issued alone or beside the batch
(`Certificates.reported`).
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor, wait
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any

from storage import write_failures
from storage.db import Archive

log = logging.getLogger(__name__)

ISSUE_ENV = "CALIB_ISSUE_CERTIFICATES"  # "0": no certificate at archive time


@dataclass
class Certificates:
    """The certificates queued in one batch (`issuing_beside`) on the batch's thread."""

    thread: ThreadPoolExecutor
    queued: list[tuple[str, Future]] = field(default_factory=list)  # (run id, its issue)

    def failures(self) -> dict[str, str]:
        """Run id -> why its certificate was not issued, once every queued one is done."""
        return {run_id: why for run_id, f in self.queued if (why := f.result()) is not None}

    def reported(self, outcomes: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """The batch's outcomes, each run whose certificate was not issued saying why in
        its message (waits for the queued certificates)."""
        failures = self.failures()
        return [
            {**o, "message": with_note(o["message"], o["run_id"], failures[o["run_id"]])}
            if o["run_id"] in failures
            else o
            for o in outcomes
        ]


# The batch's certificates, seen by the batch's task threads (Prefect copies the context
# into each task run).
_beside: ContextVar[Certificates | None] = ContextVar("calib_certificates", default=None)


def with_note(message: str | None, run_id: str, why: str) -> str:
    """An outcome's `message` with the note that the run's certificate was not issued."""
    note = f"certificate not issued: {why}; issue it with `calib report {run_id}`"
    return f"{message}; {note}" if message else note


def _issue_logged(archive: Archive, run_id: str) -> str | None:
    """Issue the run's certificate; a failure is logged with how to issue it later and
    returned (what went wrong), None when it was issued."""
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
        return problem
    return None


def issue_certificate(archive: Archive, run_id: str) -> str | None:
    """Issue the archived revision's certificate (HTML and PDF, `pipelines.reports.issue`).

    The run stays archived if this fails (a full disk, a read-only folder): the failure
    is logged with how to issue it later (`calib report RUN`). Environment
    ``CALIB_ISSUE_CERTIFICATES=0`` leaves the issue to `calib report` (bulk loads, test
    suites). Inside `issuing_beside` the issue is queued on the batch's certificate
    thread; else it is done before this returns.

    Returns
    -------
    Why the certificate was not issued; None when it was, was left to `calib report`, or
    was queued (the batch reports its failures: `Certificates.reported`).
    """
    if os.environ.get(ISSUE_ENV, "1").strip() == "0":
        return None
    batch = _beside.get()
    if batch is None:
        return _issue_logged(archive, run_id)
    batch.queued.append((run_id, batch.thread.submit(_issue_logged, archive, run_id)))
    return None


@contextlib.contextmanager
def issuing_beside() -> Iterator[Certificates]:
    """Within the block, certificates are issued on one thread beside the caller's next
    runs; leaving it waits until every one is issued (also when the block raises). The
    `Certificates` it gives report their failures once the block is left."""
    outer = _beside.get()
    if outer is not None:  # a batch inside a batch: the outer one's thread
        batch = Certificates(outer.thread)
        token = _beside.set(batch)
        try:
            yield batch
        finally:
            _beside.reset(token)
            outer.queued += batch.queued
            wait([issued for _, issued in batch.queued])  # its own, as the block promises
        return
    batch = Certificates(ThreadPoolExecutor(1, thread_name_prefix="calib-certificates"))
    token = _beside.set(batch)
    try:
        yield batch
    finally:
        _beside.reset(token)
        batch.thread.shutdown(wait=True)
