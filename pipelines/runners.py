"""Where a batch's tasks run: threads, local processes, or a Dask cluster.

The batch flow (`pipelines.flows.process_batch`) submits one task per run to
the task runner chosen here. Nothing is scheduled by this project itself: the
pools are Prefect's, the cluster is Dask's.

- ``"local"``: Prefect's ``ThreadPoolTaskRunner``. Cheapest start; the
  numerical parts release the GIL only partly, so CPU-bound solving of many
  runs gains little beyond one core.
- ``"process"``: the tasks run in Prefect's ``ThreadPoolTaskRunner`` as with
  ``"local"``, and each task hands its run to a pool of worker processes
  (:class:`WorkerProcesses`), so solving really uses every core. Prefect keeps
  the tasks (states, retries, logs) in the flow's process, where a task costs
  little of Prefect's time; its own ``ProcessPoolTaskRunner`` re-creates the
  flow's context in the worker for every task, which made a batch markedly
  slower than a plain process pool. Task inputs must
  pickle (``RunSource`` is a frozen dataclass; archive URL and root are strings).
- ``"dask"``: prefect-dask's ``DaskTaskRunner`` on an existing scheduler
  (``tcp://host:8786``) when `scheduler` is given, else on a temporary local
  Dask cluster of `workers` single-threaded worker processes.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import select
import threading
import time
import weakref
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

T = TypeVar("T")

RUNNERS = ("local", "process", "dask")

# One thread per worker process for the numerical libraries: the parallelism of
# a batch is its worker processes, and nested BLAS / OpenMP / Arrow thread pools
# only fight them for the cores (a run took more CPU time with the default pools, for
# a slower wall time, even in a single worker).
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}


@contextlib.contextmanager
def single_threaded_children() -> Iterator[None]:
    """Worker processes started inside inherit SINGLE_THREAD_ENV (unless already set).

    The variables are read when numpy and pyarrow load, which in a new process
    (spawned, or a forkserver importing its preload) happens before any
    initializer could run, so they must be in the environment it inherits.
    This process's own libraries are loaded already and keep their pools; the
    variables are restored on exit.
    """
    added = {k: v for k, v in SINGLE_THREAD_ENV.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)


def exit_with(owner_pid: int) -> None:
    """End this process when process `owner_pid` ends, however it ends (a worker's initializer).

    A worker forked from the forkserver holds pipes that keep it, the forkserver
    and the resource tracker alive after the process that started them is gone
    (killed by signal 9, or crashed), waiting for work that never comes. A
    daemon thread waits on a pidfd of the owner (Linux >= 5.3; elsewhere it
    polls every second) and exits this process when the owner has ended.
    """
    threading.Thread(target=_wait_and_exit, args=(owner_pid,), daemon=True).start()


def _wait_and_exit(owner_pid: int) -> None:
    try:
        fd = os.pidfd_open(owner_pid)
    except (AttributeError, OSError):  # no pidfd: poll
        fd = None
    if fd is not None:
        select.select([fd], [], [])  # readable once the owner has ended
    else:
        while True:
            try:
                os.kill(owner_pid, 0)
            except ProcessLookupError:
                break
            except PermissionError:
                pass
            time.sleep(1.0)
    os._exit(1)


# Every WorkerProcesses not yet garbage: kill_all_workers stops them when a batch is interrupted.
_LIVE_POOLS: weakref.WeakSet[WorkerProcesses] = weakref.WeakSet()


def forkserver_context(preload: tuple[str, ...] = ()) -> multiprocessing.context.BaseContext:
    """The multiprocessing context of `WorkerProcesses`: a forkserver that imports `preload`.

    Start its first pool inside :func:`single_threaded_children`: the forkserver
    keeps the environment it started with and hands it to every worker.
    """
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(preload))
    return context


class WorkerProcesses:
    """A pool of worker processes that runs the CPU-bound work of a batch's tasks.

    Workers are forked from a forkserver: a clean single-threaded process that
    imports the `preload` modules once (forking the flow's own process, with
    Prefect's threads running, would be unsafe). So the pipeline's imports cost
    one core once per `calib` process instead of every worker on every
    core, and a later batch (or a replaced pool) starts its workers at once.
    The forkserver and so every worker run with single-threaded numerical
    libraries (:func:`single_threaded_children`). Workers are started at once,
    so their start overlaps with the flow's own.

    A worker that dies (killed, out of memory, a crash in a native library)
    breaks the whole pool in ``concurrent.futures``: the pool is then replaced
    by a fresh one and every call that was in it raises ``BrokenProcessPool``,
    which the batch counts as transient (`pipelines.run_task.is_transient`)
    and retries.

    Parameters
    ----------
    workers : number of worker processes (>= 1).
    preload : modules the forkserver imports before it forks workers; only
        honoured by the first pool of a process (the forkserver lives on).
    """

    def __init__(self, workers: int, preload: tuple[str, ...] = ()) -> None:
        self._workers = workers
        self._lock = threading.Lock()
        self._context = forkserver_context(preload)
        self._pool: ProcessPoolExecutor | None = None
        self._killed = False  # by `kill`: a broken pool is not replaced any more
        # The first start (the forkserver's imports) goes on in the background while
        # the caller gets on with its own start; the first `run` waits for it.
        self._started: Future[None] = Future()
        threading.Thread(target=self._first_start, name="calib-workers-start", daemon=True).start()
        _LIVE_POOLS.add(self)

    def _first_start(self) -> None:
        try:
            pool = self._start()
        except BaseException as exc:  # handed to the first `run`
            self._started.set_exception(exc)
            return
        with self._lock:
            self._pool = pool
        self._started.set_result(None)

    def _start(self) -> ProcessPoolExecutor:
        with single_threaded_children():
            pool = ProcessPoolExecutor(
                self._workers,
                mp_context=self._context,
                initializer=exit_with,
                initargs=(os.getpid(),),
            )
            # concurrent.futures starts a worker per call until it has them all:
            # one call each starts them now, inside the single-threaded environment.
            for _ in range(self._workers):
                pool.submit(int)
        return pool

    def _current(self) -> ProcessPoolExecutor:
        self._started.result()
        with self._lock:
            assert self._pool is not None
            return self._pool

    def run(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(*args)`` in a worker process; waits for and returns its result.

        Raises what `fn` raised, or ``BrokenProcessPool`` if the worker died
        (the pool is replaced first, so the next call finds live workers).
        """
        for _ in range(2):
            pool = self._current()
            try:
                future = pool.submit(fn, *args)
            except BrokenProcessPool:  # broken by another call before this one got in
                self._replace(pool)
                continue
            try:
                return future.result()
            except BrokenProcessPool:
                self._replace(pool)
                raise
        raise BrokenProcessPool("worker processes die as soon as they start")

    def _replace(self, broken: ProcessPoolExecutor) -> None:
        with self._lock:
            if self._pool is broken and not self._killed:  # the first caller to see it
                self._pool = self._start()
        broken.shutdown(wait=False, cancel_futures=True)

    def kill(self) -> None:
        """Stop the workers now, runs in progress and all (a batch interrupted by its user).

        A worker forked from the forkserver holds pipes that keep it, the forkserver
        and the resource tracker alive after this process is gone, so they are
        stopped here. A run cut short is not archived (the archive is whole-or-nothing).
        """
        with self._lock:
            self._killed = True
            pool = self._pool
        if pool is None:
            return
        # concurrent.futures has no public way to reach its processes before Python 3.14.
        for process in list(getattr(pool, "_processes", {}).values()):
            process.kill()

    def close(self) -> None:
        """Stop the workers once the calls under way are done."""
        try:
            pool = self._current()
        except Exception:  # noqa: BLE001 - never started: nothing to stop
            return
        pool.shutdown(wait=True)


def kill_all_workers() -> None:
    """`WorkerProcesses.kill` every pool of this process (before exiting on an interrupt)."""
    for pool in list(_LIVE_POOLS):
        pool.kill()


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
    if runner in ("local", "process"):
        from prefect.task_runners import ThreadPoolTaskRunner

        threads = workers or default_workers()
        if runner == "process":
            # The work goes on to WorkerProcesses. One task more than workers keeps a run
            # waiting at the pool, so no worker idles while a task thread spends its few ms
            # in Prefect between runs.
            threads += 1
        return ThreadPoolTaskRunner(max_workers=threads)
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
