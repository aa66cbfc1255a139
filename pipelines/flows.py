"""Prefect flows: a batch of lab runs, one task per run.

Tasks wrap the plain functions of `pipelines.process`; their results are small
JSON-able dicts (ids and summaries), never arrays.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from prefect import flow, get_run_logger, task

from pipelines.ingest import discover_runs
from pipelines.ingest.errors import IngestError
from pipelines.process import process_run, run_outcome
from storage.db import Archive, resolve_archive


@task(
    name="process-run",
    retries=2,
    retry_delay_seconds=1,
    retry_condition_fn=lambda task, run, state: _is_transient(state),
)
def process_run_task(source, archive_url: str, archive_root: str) -> dict[str, Any]:
    return process_run(source, Archive(url=archive_url, root=Path(archive_root)))


def _is_transient(state) -> bool:
    """Retry only errors that may go away: a locked database, a vanished network share."""
    try:
        state.result()
    except Exception as exc:  # noqa: BLE001 - classifying the failure
        text = str(exc).lower()
        return "database is locked" in text or isinstance(exc, ConnectionError | TimeoutError)
    return False


@flow(name="process-batch", log_prints=True)
def process_batch(paths: list[str], archive: str | None = None) -> list[dict[str, Any]]:
    """Process every run found under `paths` into the archive; a failing run is reported, not fatal.

    Parameters
    ----------
    paths : run folders, MPU-6000 folders, or folders holding such folders.
    archive : archive directory or SQLAlchemy URL (default: $CALIB_ARCHIVE or ./calib-archive).

    Returns
    -------
    One outcome dict per run, as in the `calib process --json` document.
    """
    logger = get_run_logger()
    arch = resolve_archive(archive)
    arch.upgrade()
    outcomes: list[dict[str, Any]] = []
    sources = []
    for p in paths:
        try:
            sources.extend(discover_runs([Path(p)]))
        except (IngestError, OSError) as exc:
            outcomes.append(run_outcome(source=str(p), serial="", status="failed", error=str(exc)))
    logger.info("%d run(s) found under %d path(s)", len(sources), len(paths))
    futures = [process_run_task.submit(s, arch.url, str(arch.root)) for s in sources]
    for source, fut in zip(sources, futures, strict=True):
        try:
            outcomes.append(fut.result())
        except Exception as exc:  # noqa: BLE001 - retries exhausted: report, go on
            outcomes.append(
                run_outcome(
                    source=str(source.folder),
                    serial=source.serial or "",
                    status="failed",
                    error=f"{type(exc).__name__}: {exc}",
                )
            )
    return outcomes
