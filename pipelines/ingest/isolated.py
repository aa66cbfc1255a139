"""Reads that may crash the interpreter run in a separate process, so a damaged file fails its run.

scipy's MAT v5 reader dereferences a null pointer on a data element whose type
code is unknown (8 zeroed bytes in a valid file are enough: signal 11), and
HDF5 (MAT v7.3) is a large C library with a history of such crashes. Validating
every structure before the library sees it would mean re-implementing the
parsers; instead the read runs in a worker process, and a worker that dies is
reported as an :class:`IngestError` naming the file.

The workers are forked from multiprocessing's forkserver (a clean
single-threaded process, safe while the batch's threads run) and kept for
the next read: a call costs little more than the transfer of its result. The
MAT reader uses a worker as a probe: the worker reads the file and returns only
its errors, then the file is read again in the calling process (reading twice
costs less than returning a large file's arrays through the pipe). The first
read of a process starts the workers (with the reader's imports, once). A read
that kills its worker is tried once more in a fresh pool (two reads may share a
pool, and the crash of one breaks both); a file that
crashes a reader twice is the cause. As with every multiprocessing start
method but fork, a script that reads at the top level of its main module needs
the ``if __name__ == "__main__":`` guard.

Each worker ends with this process (`pipelines.runners.exit_with`), so none
outlives `calib`, whatever kills it.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.util
import os
import signal
import threading
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from pipelines.ingest.errors import IngestError
from pipelines.runners import exit_with

T = TypeVar("T")

WORKERS = 2  # reads of one process in parallel (a batch's threads share them)

_lock = threading.Lock()
_pool: ProcessPoolExecutor | None = None


def _current_pool() -> ProcessPoolExecutor:
    global _pool
    with _lock:
        if _pool is None:
            context = multiprocessing.get_context("forkserver")
            _pool = ProcessPoolExecutor(
                WORKERS, mp_context=context, initializer=exit_with, initargs=(os.getpid(),)
            )
            # A worker process of a batch leaves through multiprocessing's exit function,
            # which joins its children but skips the executors' own exit hook: the pool's
            # workers would wait for work forever, and the process for them. Priority above
            # the pool's queues' own finalizers (10), which would stop their feeding first.
            multiprocessing.util.Finalize(_pool, _pool.shutdown, exitpriority=100)
        return _pool


def _drop(broken: ProcessPoolExecutor) -> str:
    """Forget a broken pool (the next call starts a new one); return how its worker died."""
    global _pool
    codes = [p.exitcode for p in list(getattr(broken, "_processes", {}).values())]
    with _lock:
        if _pool is broken:
            _pool = None
    broken.shutdown(wait=False, cancel_futures=True)
    deaths = [c for c in codes if c is not None and c != 0]
    if deaths and deaths[0] < 0:
        try:
            return f"killed by signal {-deaths[0]} ({signal.Signals(-deaths[0]).name})"
        except ValueError:
            return f"killed by signal {-deaths[0]}"
    return f"exit code {deaths[0]}" if deaths else "died"


def run_isolated(fn: Callable[..., T], *args: Any, file: str, what: str) -> T:
    """``fn(*args)`` in a worker process; its result or the exception it raised.

    Parameters
    ----------
    fn, args : a module-level function and picklable arguments.
    file : the file being read (named in the error if the worker dies).
    what : the reader, for the message (e.g. "scipy's MAT v5 reader").

    Raises
    ------
    IngestError
        If the worker process dies twice on this call (a crash of the native
        reader on this file's bytes).
    """
    how = "died"
    for _ in range(2):
        pool = _current_pool()
        try:
            return pool.submit(fn, *args).result()
        except BrokenProcessPool:
            how = _drop(pool)
    raise IngestError(
        f"{what} crashed on this file (its process {how}); the file is damaged or not "
        "what its name says: check it, or export it again from the acquisition software",
        file=file,
    )
