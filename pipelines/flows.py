"""Prefect flows: a batch of lab runs, one task per run.

Tasks wrap the plain functions of `pipelines.process`; their inputs are run
folders and the archive's URL and root, their results small JSON-able dicts
(ids and summaries): arrays never pass through Prefect's result store, so the
same flow runs on threads, local processes or a Dask cluster
(`pipelines.runners`).

Errors that may go away (a locked database, a dropped database connection, a
network share that vanished for a moment) are retried; any other failure of a
run is reported in its outcome and the batch goes on.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from contextvars import ContextVar
from typing import Any

from prefect import flow, get_run_logger, task
from prefect.artifacts import (
    create_progress_artifact,
    create_table_artifact,
    update_progress_artifact,
)
from prefect.cache_policies import NO_CACHE
from prefect.futures import as_completed

from pipelines.direct import discover
from pipelines.ingest import RunSource
from pipelines.issuing import issuing_beside
from pipelines.rejudge import as_archived_now
from pipelines.run_task import (
    RETRIES,
    RETRY_DELAYS_S,
    TransientError,
    gave_up,
    is_transient,
    process_run_for_batch,
)
from pipelines.runners import WorkerProcesses, check_runner, default_workers, make_task_runner
from pipelines.temporary_api import guard_temporary_api
from storage.db import resolve_archive

__all__ = [
    "RETRIES",
    "TransientError",
    "is_transient",
    "process_batch",
    "recompute_batch",
    "report_progress",
    "reprocess_batch",
]

PROGRESS_EVERY_S = 2.0  # s between updates of the progress artifact in Prefect's UI
# Task-run events the temporary API server records per transaction, and the longest wait
# (whole seconds: Prefect rounds it down) before it records fewer (local_batch_settings).
RECORDER_BATCH_SIZE = 100
RECORDER_FLUSH_S = 1

# Callback(done, total, outcome) called as each run of a batch finishes (the CLI's progress bar).
ProgressCallback = Callable[[int, int, dict[str, Any]], None]
_progress: ContextVar[ProgressCallback | None] = ContextVar("calib_batch_progress", default=None)
# The worker processes of a batch run with the process runner (seen by its tasks' threads).
_batch_workers: ContextVar[WorkerProcesses | None] = ContextVar("calib_batch_workers", default=None)


# Both ContextVars are read through module-level functions: a flow or task shipped to
# another process (Dask) is pickled, and a ContextVar cannot be.
def _progress_callback() -> ProgressCallback | None:
    return _progress.get()


def _worker_processes() -> WorkerProcesses | None:
    return _batch_workers.get()


@contextlib.contextmanager
def _work_in_processes(runner: str, workers: int | None) -> Iterator[None]:
    """With the process runner, the batch's tasks hand their runs to worker processes."""
    if runner != "process":
        yield
        return
    pool = WorkerProcesses(workers or default_workers(), preload=("pipelines.run_task",))
    token = _batch_workers.set(pool)
    try:
        yield
    finally:
        _batch_workers.reset(token)
        pool.close()


@contextlib.contextmanager
def report_progress(callback: ProgressCallback) -> Iterator[None]:
    """Call ``callback(done, total, outcome)`` as each run of batches started inside finishes."""
    token = _progress.set(callback)
    try:
        yield
    finally:
        _progress.reset(token)


@contextlib.contextmanager
def local_batch_settings() -> Iterator[None]:
    """Settings for running batches from this process on Prefect's temporary local API.

    Used around the first Prefect call of the process, so that the temporary
    server Prefect starts then (no PREFECT_API_URL configured) gets them too:

    - Flow-run heartbeats let a Prefect server mark runs whose process died as
      crashed. The temporary API ends with this process, so nothing reads them,
      while Prefect's heartbeat thread holds up the end of every flow by up to a
      second (it sleeps in 1 s steps and is joined at exit): turned off.
    - The server's task-run recorder, which turns the task-run events the flow
      sends into the task runs the UI shows, writes each event in its own
      transaction by default: most of the server's CPU per task run went to the
      recorder, on the cores the batch's runs need. With the events written in
      batches (`RECORDER_BATCH_SIZE`, at least every `RECORDER_FLUSH_S`) it
      spends a fraction of that; task states reach the UI up to a second later.
    - Two of the server's services that read every event, for features a server
      that ends with this process cannot serve, are off: the event persister
      (the event feed of the UI; the task runs themselves are the recorder's) and
      the reactive triggers of automations (with the actions they would start):
      the server's CPU per task run falls with them (benchmarks/batch.py).

    The temporary server is also made to end with this process, whatever ends it
    (`pipelines.temporary_api`). With a configured API nothing changes
    (docs/deployment.md says how to set the recorder's batching on a lasting server).
    """
    from prefect.settings import (
        PREFECT_API_URL,
        PREFECT_FLOWS_HEARTBEAT_FREQUENCY,
        PREFECT_SERVER_SERVICES_EVENT_PERSISTER_ENABLED,
        PREFECT_SERVER_SERVICES_TASK_RUN_RECORDER_BATCH_SIZE,
        PREFECT_SERVER_SERVICES_TASK_RUN_RECORDER_FLUSH_INTERVAL,
        PREFECT_SERVER_SERVICES_TRIGGERS_ENABLED,
        temporary_settings,
    )

    if PREFECT_API_URL.value():
        yield
        return
    guard_temporary_api()
    with temporary_settings(
        {
            PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None,
            PREFECT_SERVER_SERVICES_TASK_RUN_RECORDER_BATCH_SIZE: RECORDER_BATCH_SIZE,
            PREFECT_SERVER_SERVICES_TASK_RUN_RECORDER_FLUSH_INTERVAL: RECORDER_FLUSH_S,
            PREFECT_SERVER_SERVICES_EVENT_PERSISTER_ENABLED: False,
            PREFECT_SERVER_SERVICES_TRIGGERS_ENABLED: False,
        }
    ):
        yield


def stop_temporary_api() -> None:
    """Stop the temporary local API server(s) this process started, if any.

    Prefect stops them in an exit hook; a process that leaves with ``os._exit``
    (an interrupted `calib process`) skips the hook and must do it here, or the
    server outlives it.
    """
    from prefect.server.api.server import SubprocessASGIServer

    # Prefect keeps its temporary servers in this class attribute (no public list).
    for server in list(getattr(SubprocessASGIServer, "_instances", {}).values()):
        with contextlib.suppress(Exception):
            server.stop()


@contextlib.contextmanager
def _api_for_workers(runner: str) -> Iterator[None]:
    """Let worker processes report to this process's Prefect API.

    Without a configured PREFECT_API_URL, Prefect runs a temporary local server
    in this process; a worker process would start one of its own (many seconds
    each). Naming this one's URL in the settings the task runner ships to its
    workers makes them all use it. With a configured API nothing changes.
    """
    from prefect.client.orchestration import get_client
    from prefect.settings import PREFECT_API_URL, temporary_settings

    if runner != "dask" or PREFECT_API_URL.value():  # other runners' tasks stay here
        yield
        return
    with get_client(sync_client=True) as client:
        url = str(client.api_url)
    with temporary_settings({PREFECT_API_URL: url}):
        yield


def _retry_transient(task, task_run, state) -> bool:  # noqa: ANN001 - Prefect's hook signature
    try:
        state.result()
    except Exception as exc:  # noqa: BLE001 - only what may go away is worth another attempt
        return is_transient(exc)
    return False


def _batch_task(name: str, run_name: str) -> Callable[[Callable[..., Any]], Any]:
    """Prefect's task decorator for one run of a batch: what `is_transient` accepts is
    retried (RETRIES more attempts after RETRY_DELAYS_S); nothing cached or persisted: the
    archive already makes a run idempotent (by content hash), and hashing inputs and task
    source for a cache key would cost every run."""
    return task(
        name=name,
        task_run_name=run_name,
        retries=RETRIES,
        retry_delay_seconds=RETRY_DELAYS_S,
        retry_condition_fn=_retry_transient,
        cache_policy=NO_CACHE,
        persist_result=False,
    )


@_batch_task("process-run", "process {source.name}")
def process_run_task(source: RunSource, archive_url: str, archive_root: str) -> dict[str, Any]:
    """One run through `process_run`; what `is_transient` accepts is retried.

    With the process runner the work runs in one of the batch's worker processes
    while this task (state, retries, logs) stays in a thread of the flow; a
    worker that died under it raises ``BrokenProcessPool``.
    """
    return _in_worker(process_run_for_batch, source, archive_url, archive_root)


def _in_worker(fn: Callable[..., dict[str, Any]], *args: Any) -> dict[str, Any]:
    """``fn(*args)`` in a worker process of the batch (process runner), else right here."""
    pool = _worker_processes()
    return fn(*args) if pool is None else pool.run(fn, *args)


@flow(name="process-batch", log_prints=True)
def process_batch(
    paths: list[str],
    archive: str | None = None,
    runner: str = "local",
    workers: int | None = None,
    scheduler: str | None = None,
) -> list[dict[str, Any]]:
    """Process every run found under `paths` into the archive; a failing run is reported, not fatal.

    Parameters
    ----------
    paths : run folders, MPU-6000 folders, or folders holding such folders.
    archive : archive directory or SQLAlchemy URL (default: $CALIB_ARCHIVE or ./calib-archive).
        Every worker must reach it: with a Dask cluster, a PostgreSQL URL and a
        file store root ($CALIB_FILESTORE) on a path every worker sees.
    runner : ``"local"`` (threads), ``"process"`` (local processes, for
        CPU-bound solving) or ``"dask"`` (see `pipelines.runners`).
    workers : parallel runs (default: the usable cores); not with `scheduler`.
    scheduler : address of an existing Dask scheduler, with ``runner="dask"``.

    Returns
    -------
    One outcome dict per run, as in the `calib process --json` document:
    discovery failures first, then the runs in discovery order.
    """
    check_runner(runner, workers, scheduler)
    logger = get_run_logger()
    sources, outcomes = discover(paths)
    logger.info(
        "%d run(s) found under %d path(s); runner %s%s",
        len(sources),
        len(paths),
        runner,
        f" at {scheduler}" if scheduler else "",
    )
    with _batch_runner(runner, workers, scheduler, has_runs=bool(sources)) as (
        task_runner,
        certificates,
    ):
        arch = resolve_archive(archive)
        arch.upgrade()  # once, before any worker archives
        parameters = [
            {"source": s, "archive_url": arch.url, "archive_root": str(arch.root)} for s in sources
        ]
        outcomes += _run_tasks(
            task_runner,
            process_run_task,
            parameters,
            lambda i, exc: gave_up(str(sources[i].folder), sources[i].serial or "", exc),
        )
        if sources:  # runs judged again by later tasks (pipelines.rejudge) say so
            outcomes = as_archived_now(arch, outcomes)
    outcomes = certificates.reported(outcomes)  # those not issued beside the runs say so
    _summary_artifact(outcomes)
    return outcomes


@contextlib.contextmanager
def _batch_runner(
    runner: str, workers: int | None, scheduler: str | None, *, has_runs: bool
) -> Iterator[Any]:
    """The batch's started task runner, with the process runner's worker processes (started
    first, so that they start while the flow gets ready; only for a batch that `has_runs`)
    and the certificates issued beside the runs (`pipelines.issuing`, given with the runner).
    On leaving, it waits for the tasks, then for the certificates."""
    with contextlib.ExitStack() as stack:
        if has_runs:
            stack.enter_context(_work_in_processes(runner, workers))
        certificates = stack.enter_context(issuing_beside())
        stack.enter_context(_api_for_workers(runner))
        yield stack.enter_context(make_task_runner(runner, workers, scheduler)), certificates


def _run_tasks(
    task_runner: Any,
    task_: Any,
    parameters: list[dict[str, Any]],
    gave_up: Callable[[int, Exception], dict[str, Any]],
    *,
    done_before: int = 0,
) -> list[dict[str, Any]]:
    """Submit `task_` once per parameter dict; the outcomes in that order.

    Progress goes to the flow run's progress artifact and to the callback of
    `report_progress` as each task ends; `done_before` runs of the batch (counted
    in the total) were settled before any task. A task whose retries are spent
    gets the outcome ``gave_up(index, exception)``.
    """
    total = done_before + len(parameters)
    progress_id = create_progress_artifact(
        progress=100.0 * done_before / max(total, 1),
        key="batch-progress",
        description=f"Runs of {total} processed (%)",
    )
    callback = _progress_callback()
    futures = [task_runner.submit(task_, p) for p in parameters]
    index = {id(f): i for i, f in enumerate(futures)}
    results: dict[int, dict[str, Any]] = {}
    shown = time.monotonic()
    for fut in as_completed(futures):
        i = index[id(fut)]
        try:
            results[i] = fut.result()
        except Exception as exc:  # noqa: BLE001 - retries exhausted: report, go on
            results[i] = gave_up(i, exc)
        done = done_before + len(results)
        # Every call is an API request: at most one per PROGRESS_EVERY_S, and the last.
        if done == total or time.monotonic() - shown >= PROGRESS_EVERY_S:
            update_progress_artifact(progress_id, 100.0 * done / total)
            shown = time.monotonic()
        if callback is not None:
            callback(done, total, results[i])
    return [results[i] for i in range(len(parameters))]


def _summary_artifact(outcomes: list[dict[str, Any]]) -> None:
    """One table row per run in the flow run's Artifacts tab."""
    create_table_artifact(
        key="batch-outcomes",
        table=[
            {
                "run_id": o["run_id"],
                "serial": o["serial"],
                "status": o["status"],
                "verdict": o["verdict"],
                "error": o["error"],
                "source": o["source"],
            }
            for o in outcomes
        ],
        description=f"{sum(o['status'] == 'failed' for o in outcomes)} of {len(outcomes)} failed",
    )


@_batch_task("reprocess-run", "reprocess {run_id}")
def reprocess_run_task(
    run_id: str, archive_url: str, archive_root: str, reason: str
) -> dict[str, Any]:
    """One archived run through `reprocess_run_for_batch` (in a worker process with the
    process runner, as `process_run_task`); what `is_transient` accepts is retried."""
    from pipelines.reprocess import reprocess_run_for_batch

    return _in_worker(reprocess_run_for_batch, run_id, archive_url, archive_root, reason)


@flow(name="reprocess-batch", log_prints=True)
def reprocess_batch(
    reason: str,
    selection: dict[str, Any] | None = None,
    archive: str | None = None,
    runner: str = "local",
    workers: int | None = None,
    scheduler: str | None = None,
) -> list[dict[str, Any]]:
    """Process every selected archived run again from its raw bytes, as a new revision.

    Parameters
    ----------
    reason : why (kept with every new revision); non-empty.
    selection : filters of `storage.queries.select_runs` (serial, model, since, until,
        software_version, profile); None or {}: every run of the archive.
    archive, runner, workers, scheduler : as `process_batch`.

    Returns
    -------
    One outcome per selected run (`calib process --json` entries; status "revised",
    "duplicate" or "failed"): first the runs already reprocessed by this software
    with these settings (`pipelines.reprocess.plan_reprocess`, so running it again
    after an interruption goes on), then the others, oldest first.
    """
    from pipelines.reprocess import check_reason, plan_reprocess

    check_runner(runner, workers, scheduler)
    check_reason(reason)
    logger = get_run_logger()
    arch = resolve_archive(archive)
    arch.upgrade()
    todo, skipped = plan_reprocess(arch, selection or {})
    logger.info(
        "%d run(s) selected, %d already reprocessed with this software and settings; runner %s",
        len(todo) + len(skipped),
        len(skipped),
        runner,
    )
    callback = _progress_callback()
    for n, outcome in enumerate(skipped, 1):
        if callback is not None:
            callback(n, len(skipped) + len(todo), outcome)
    with _batch_runner(runner, workers, scheduler, has_runs=bool(todo)) as (
        task_runner,
        certificates,
    ):
        parameters = [
            {"run_id": r, "archive_url": arch.url, "archive_root": str(arch.root), "reason": reason}
            for r in todo
        ]
        outcomes = skipped + _run_tasks(
            task_runner,
            reprocess_run_task,
            parameters,
            lambda i, exc: gave_up(f"archive:{todo[i]}", "", exc, todo[i]),
            done_before=len(skipped),
        )
    outcomes = certificates.reported(outcomes)
    _summary_artifact(outcomes)
    return outcomes


@_batch_task("recompute-run", "recompute {run_id}")
def recompute_run_task(run_id: str, archive_url: str, archive_root: str) -> dict[str, Any]:
    """Every revision of one archived run solved again and compared (`pipelines.recompute`;
    in a worker process with the process runner, as `process_run_task`)."""
    from pipelines.recompute import recompute_run_for_batch

    return _in_worker(recompute_run_for_batch, run_id, archive_url, archive_root)


@flow(name="recompute-batch", log_prints=True)
def recompute_batch(
    run_ids: list[str],
    archive: str | None = None,
    runner: str = "local",
    workers: int | None = None,
    scheduler: str | None = None,
) -> list[dict[str, Any]]:
    """Solve every revision of `run_ids` again from its raw bytes and compare it with its
    sealed rows (`calib verify --recompute`); nothing is written to the archive.

    Parameters
    ----------
    run_ids : full run ids (`pipelines.recompute.plan_recompute`).
    archive, runner, workers, scheduler : as `process_batch`.

    Returns
    -------
    One outcome per run, in the order of `run_ids` (`pipelines.recompute.recompute_run`).
    """
    from pipelines.recompute import failed_outcome

    check_runner(runner, workers, scheduler)
    arch = resolve_archive(archive)
    get_run_logger().info("%d run(s) to recompute; runner %s", len(run_ids), runner)
    with _batch_runner(runner, workers, scheduler, has_runs=bool(run_ids)) as (task_runner, _):
        parameters = [
            {"run_id": r, "archive_url": arch.url, "archive_root": str(arch.root)} for r in run_ids
        ]
        return _run_tasks(
            task_runner,
            recompute_run_task,
            parameters,
            lambda i, exc: failed_outcome(run_ids[i], exc),
        )


@flow(name="thermal_campaign")
def thermal_campaign(
    paths: list[str],
    archive: str | None = None,
    serial: str | None = None,
    settings: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Process a campaign's run folders (process_batch), then fit and archive the thermal model
    (`pipelines.thermal_campaign.thermal_fit`)."""
    from pipelines.thermal_campaign import thermal_fit

    outcomes = process_batch(paths, archive)
    ok = [o for o in outcomes if o["status"] in ("ok", "duplicate")]
    serials = sorted({o["serial"] for o in ok})
    if serial is None:
        if len(serials) != 1:
            raise ValueError(f"the campaign holds runs of {serials}; name the serial")
        serial = serials[0]
    arch = resolve_archive(archive)
    arch.upgrade()
    run_ids = [o["run_id"] for o in ok if o["serial"] == serial]
    return {"runs": outcomes, "thermal": thermal_fit(arch, serial, run_ids, settings)}
