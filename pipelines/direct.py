"""Small batches processed in this process, without Prefect: one run answered without
starting a Prefect server (docs/architecture.md, "Batches"; figures: benchmarks/README.md,
"latency.py").

Prefect orchestrates batches (`pipelines.flows.process_batch`); for one run or a handful
at the lab table, starting Prefect's temporary API server costs far more than the runs
themselves (about 14 s of CPU against 3 s a run). A batch runs here when `in_process` says
so. The outcomes and the archive are the same either way: the same discovery
(`discover`), the same `process_run` per run with the same retries of transient errors
(`pipelines.run_task`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

# Light to import (the CLI reads IN_PROCESS_MAX_RUNS for its --help): the pipeline
# loads inside the functions.
if TYPE_CHECKING:
    from pipelines.ingest import RunSource

# Up to this many runs, `calib process` answers without Prefect (unless --flow).
IN_PROCESS_MAX_RUNS = 4

ProgressCallback = Callable[[int, int, dict[str, Any]], None]


def discover(paths: list[str]) -> tuple[list[RunSource], list[dict[str, Any]]]:
    """The runs under `paths`, each once, in discovery order, and the failed outcomes of
    paths that could not be searched (a missing folder, an unreadable manifest)."""
    from pipelines.ingest import discover_runs
    from pipelines.ingest.errors import IngestError
    from pipelines.process import run_outcome

    failed: list[dict[str, Any]] = []
    sources: list[RunSource] = []
    for p in paths:
        try:
            sources.extend(discover_runs([Path(p)]))
        except (IngestError, OSError) as exc:
            failed.append(run_outcome(source=str(p), serial="", status="failed", error=str(exc)))
    return list(dict.fromkeys(sources)), failed  # overlapping paths name a run once


def prefect_api_configured() -> bool:
    """Is a Prefect API configured (environment or the active Prefect profile)?

    Read without importing Prefect (that alone takes about a second): ``PREFECT_API_URL``
    in the environment, else in the active profile of ``$PREFECT_HOME/profiles.toml``.
    """
    if os.environ.get("PREFECT_API_URL"):
        return True
    import tomllib  # here: the CLI imports this module for its --help

    home = Path(os.environ.get("PREFECT_HOME", Path.home() / ".prefect")).expanduser()
    try:
        doc = tomllib.loads((home / "profiles.toml").read_text("utf-8"))
    except (OSError, ValueError):
        return False
    active = os.environ.get("PREFECT_PROFILE") or doc.get("active", "ephemeral")
    profile = (doc.get("profiles") or {}).get(active) or {}
    return bool(profile.get("PREFECT_API_URL"))


def in_process(runs: int, runner: str, flow: bool) -> bool:
    """Whether a batch of `runs` runs runs in this process rather than as the Prefect flow:
    at most IN_PROCESS_MAX_RUNS, the ``local`` runner, ``--flow`` not given (`flow` False)
    and no Prefect API configured (a lab with a Prefect server sees every batch there)."""
    small = not flow and runner == "local" and runs <= IN_PROCESS_MAX_RUNS
    return small and not prefect_api_configured()


def process_in_process(
    sources: list[RunSource],
    archive: str | None,
    on_progress: ProgressCallback | None = None,
) -> list[dict[str, Any]]:
    """Process `sources` one after the other in this process; outcomes in their order
    (each run's certificate issued beside the next run, all of them by the return; one
    not issued is said in its run's message).

    A transient failure (a locked database, a vanished share) is retried as the batch flow
    retries it (RETRIES more attempts after RETRY_DELAYS_S); then the run is reported failed.
    """
    from pipelines.issuing import issuing_beside
    from pipelines.run_task import gave_up, process_run_for_batch, run_in_process
    from storage.db import resolve_archive

    arch = resolve_archive(archive)
    arch.upgrade()
    with issuing_beside() as certificates:  # each certificate beside the next run
        outcomes = run_in_process(
            sources,
            lambda source: process_run_for_batch(source, arch.url, str(arch.root)),
            lambda source, exc: gave_up(str(source.folder), source.serial or "", exc),
            on_progress,
        )
    return certificates.reported(outcomes)
