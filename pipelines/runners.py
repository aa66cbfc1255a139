"""Where a batch's tasks run: threads, local processes, or a Dask cluster.

The batch flow (`pipelines.flows.process_batch`) submits one task per run to
the task runner chosen here. Nothing is scheduled by this project itself: the
pools are Prefect's, the cluster is Dask's.

- ``"local"``: Prefect's ``ThreadPoolTaskRunner``. Cheapest start; the
  numerical parts release the GIL only partly, so CPU-bound solving of many
  runs gains little beyond one core.
- ``"process"``: Prefect's ``ProcessPoolTaskRunner``, one Python process per
  worker, so solving really uses every core. Task inputs must pickle
  (``RunSource`` is a frozen dataclass; archive URL and root are strings).
  Start the pool inside :func:`single_threaded_children`.
- ``"dask"``: prefect-dask's ``DaskTaskRunner`` on an existing scheduler
  (``tcp://host:8786``) when `scheduler` is given, else on a temporary local
  Dask cluster of `workers` single-threaded worker processes.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import Any

RUNNERS = ("local", "process", "dask")

# One thread per worker process for the numerical libraries: the parallelism of
# a batch is its worker processes, and nested BLAS / OpenMP / Arrow thread pools
# only fight them for the cores (measured: a run took 1.7x the CPU time with
# the default pools, for a slower wall time, even in a single worker).
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}


@contextlib.contextmanager
def single_threaded_children() -> Iterator[None]:
    """Worker processes started inside inherit SINGLE_THREAD_ENV (unless already set).

    The variables are read when numpy and pyarrow load, which in a spawned
    worker happens before any initializer could run, so they must be in the
    environment the worker inherits. This process's own libraries are loaded
    already and keep their pools; the variables are restored on exit.
    """
    added = {k: v for k, v in SINGLE_THREAD_ENV.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)


def default_workers() -> int:
    """Worker count when none is given: the cores this process may use (>= 1)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def check_runner(runner: str, workers: int | None, scheduler: str | None) -> None:
    """Raise ValueError naming the option and what was expected if the choice is inconsistent."""
    if runner not in RUNNERS:
        raise ValueError(f"--runner {runner!r}: expected one of {', '.join(RUNNERS)}")
    if workers is not None and (
        isinstance(workers, bool) or int(workers) != workers or workers < 1
    ):
        raise ValueError(f"--workers {workers!r}: expected a whole number >= 1")
    if scheduler is not None:
        if runner != "dask":
            raise ValueError(f"--scheduler is only used with --runner dask, not {runner!r}")
        if "://" not in scheduler:
            raise ValueError(
                f"--scheduler {scheduler!r}: expected a Dask scheduler address such as "
                "tcp://10.0.0.5:8786"
            )
        if workers is not None:
            raise ValueError(
                "--workers cannot be combined with --scheduler: an existing Dask cluster "
                "has the workers it was started with"
            )


def make_task_runner(
    runner: str = "local", workers: int | None = None, scheduler: str | None = None
):
    """A Prefect task runner for a batch.

    Parameters
    ----------
    runner : ``"local"`` (threads), ``"process"`` (local processes) or ``"dask"``.
    workers : parallel tasks (threads or processes); default: the usable cores.
        Not allowed with `scheduler` (the cluster decides).
    scheduler : address of an existing Dask scheduler (``tcp://host:port``);
        only with ``runner="dask"``.

    Returns
    -------
    A not yet started ``prefect.task_runners.TaskRunner``; use it as a context
    manager (``with make_task_runner(...) as tr: tr.submit(task, parameters)``).

    Raises
    ------
    ValueError for an unknown runner or inconsistent options.
    """
    check_runner(runner, workers, scheduler)
    if runner == "local":
        from prefect.task_runners import ThreadPoolTaskRunner

        return ThreadPoolTaskRunner(max_workers=workers or default_workers())
    if runner == "process":
        from prefect.task_runners import ProcessPoolTaskRunner

        return ProcessPoolTaskRunner(max_workers=workers or default_workers())
    from prefect_dask import DaskTaskRunner

    if scheduler is not None:
        return DaskTaskRunner(address=scheduler)
    # One thread per worker process: the solvers are CPU-bound and hold the GIL.
    cluster: dict[str, Any] = {
        "n_workers": workers or default_workers(),
        "threads_per_worker": 1,
        "processes": True,
        "dashboard_address": ":0",
        "env": SINGLE_THREAD_ENV,
    }
    return DaskTaskRunner(cluster_kwargs=cluster)
