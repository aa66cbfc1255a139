"""The solve of a record streamed to its samples' Parquet: how it runs, kept out of the
science (`calib_core.streamed.Execution`).

`solve_streamed` reads the Parquet back for the static-bias solve's second pass, one
channel (column) after the other (`ChannelFeed`, decoded by a prefetching thread): a
channel's whole Allan phase in memory when half the limit holds it (`phase_rows`, in
`phase_workspace`, an anonymous mapping), else its last rows, the long lags from a phase
file (`FileHistory`); half of each channel's Allan sums on a helper thread. The C heap's
freed pages go back to the system before and after (`give_back_freed_memory`). Memory
stays bounded by `memory_limit` whatever the record's length; progress goes to stderr on
long records.
"""

from __future__ import annotations

import contextlib
import ctypes
import mmap
import os
import queue
import tempfile
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from calib_core import procedures
from calib_core.calibration import Calibration
from calib_core.streamed import Execution, TemperatureTrend
from pipelines.ingest.csv_layout import CHANNELS
from pipelines.ingest.csv_reader import float_values
from pipelines.ingest.data_format import PROGRESS_THRESHOLD_BYTES
from pipelines.ingest.streamed_pass import DEFAULT_MEMORY_LIMIT, Progress, Streamed


class FileHistory:
    """The Allan deviation's phase rows in temporary files, one per channel
    (`calib_core.streamed.History`): the long lags are read back with `os.pread`, so
    they take no resident memory."""

    def __init__(self, folder: Path | None = None):
        self.folder, self.fds, self.rows = folder, [], 0

    def append(self, rows: np.ndarray) -> None:
        """Add (C, n) phase rows at the end."""
        while len(self.fds) < rows.shape[0]:
            fd, name = tempfile.mkstemp(prefix="allan-phase-", dir=self.folder)
            os.unlink(name)  # gone with the descriptor, however the process ends
            self.fds.append(fd)
        for fd, col in zip(self.fds, rows, strict=True):
            os.pwrite(fd, np.ascontiguousarray(col, dtype=np.float64), 8 * self.rows)
        self.rows += rows.shape[1]

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows start..stop-1, (C, stop - start)."""
        out = np.empty((len(self.fds), stop - start))
        for fd, col in zip(self.fds, out, strict=True):
            if os.preadv(fd, [col], 8 * start) != col.nbytes:
                raise OSError("Allan phase file: short read")
        return out

    def close(self) -> None:
        for fd in self.fds:
            os.close(fd)
        self.fds = []


def samples_chunks(samples: Path, memory_limit: int) -> Iterator[tuple]:
    """The streamed samples back from their Parquet as (t, gyr, acc) chunks."""
    # pre_buffer off: with it, the batches' buffers of the whole file stay allocated
    # until the iteration ends (memory growing with the record).
    reader = pq.ParquetFile(samples, pre_buffer=False)
    batches = reader.iter_batches(batch_size=batch_rows(memory_limit), columns=[*CHANNELS, "t"])
    # decoded and laid out by the prefetching thread, beside the solve's arithmetic
    for t, both in prefetched(_arrays(b) for b in batches):
        yield t, both[:, :3], both[:, 3:]


def _arrays(batch: pa.RecordBatch) -> tuple[np.ndarray, np.ndarray]:
    """A batch of the samples as (t, [gyr | acc] (n, 6)), the six channels column by
    column in memory (the solve works channel by channel)."""
    both = np.empty((batch.num_rows, 6), order="F")
    for i in range(6):
        both[:, i] = float_values(batch.column(i))
    return float_values(batch.column(6)), both


def prefetched(items: Iterator[Any], depth: int = 2) -> Iterator[Any]:
    """`items`, the next `depth` produced by a thread while the caller works on one (the
    Parquet decoder releases the GIL: decoding overlaps the solve's arithmetic)."""
    done = object()
    slots: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                if stop.is_set():
                    return
                slots.put(item)
            slots.put(done)
        except BaseException as exc:  # noqa: BLE001 - raised again in the caller
            slots.put(exc)

    worker = threading.Thread(target=produce, name="calib-prefetch", daemon=True)
    worker.start()
    try:
        while (item := slots.get()) is not done:
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while worker.is_alive():  # let a producer blocked on a full queue finish
            with contextlib.suppress(queue.Empty):
                slots.get(timeout=0.1)


class ChannelFeed:
    """The streamed samples' channels of [gyr | acc] back from their Parquet one after the
    other, each column read and decoded alone, by one prefetching thread that runs ahead
    across the channels (the next channel's first batches are decoded while the solve
    finishes one); with `trend`, the time and temperature go to it with the first channel.

    `channel(c)` gives channel c's (n, 1) chunks; the channels are taken in order, each
    to its end. `close` stops the thread (a solve that failed part way).
    """

    def __init__(self, samples: Path, memory_limit: int, trend: TemperatureTrend | None = None):
        # a batch of one channel: as many bytes as one of six
        self.rows = len(CHANNELS) * batch_rows(memory_limit)
        self.samples, self.trend = samples, trend
        self.items = prefetched(self._batches())
        self.next = 0

    def _batches(self) -> Iterator[tuple[int, pa.RecordBatch | None]]:
        for c, name in enumerate(CHANNELS):
            timed = self.trend is not None and c == 0
            cols = [name, "t", "temp"] if timed else [name]
            reader = pq.ParquetFile(self.samples, pre_buffer=False)  # see samples_chunks
            for batch in reader.iter_batches(batch_size=self.rows, columns=cols):
                if timed:
                    self.trend.push(float_values(batch.column(1)), float_values(batch.column(2)))
                yield c, batch
            yield c, None  # the channel's end

    def channel(self, c: int) -> Iterator[np.ndarray]:
        if c != self.next:
            raise ValueError(f"channel feed: channel {c} asked for, {self.next} is next")
        self.next += 1
        for k, batch in self.items:
            if batch is None:
                return
            if k != c:  # cannot happen: the channels end in order
                raise RuntimeError(f"channel feed: a batch of channel {k} in channel {c}'s")
            yield float_values(batch.column(0)).reshape(-1, 1)

    def close(self) -> None:
        self.items.close()


class _SolveProgress:
    """The progress of the solve's passes on stderr (as the read's): the data file's
    bytes in proportion to the samples done of `passes` passes over the record."""

    def __init__(self, streamed: Streamed, passes: int):
        show = streamed.size > PROGRESS_THRESHOLD_BYTES
        self.bar = Progress("the record", streamed.size, show, verb="solving")
        self.size, self.passes = streamed.size, passes
        self.total, self.done = max(streamed.first.n, 1) * passes, 0

    def counted(self, chunks: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
        """`chunks` ((n, ...) arrays), counted as they are taken."""
        for chunk in chunks:
            yield chunk
            self.done += len(chunk)
            self.bar.update(self.size * self.done // self.total, self.done // self.passes)

    def end(self) -> None:
        self.bar.update(self.size, self.done // self.passes, final=True)


def batch_rows(memory_limit: int) -> int:
    """Rows per batch of the second pass: the batch and its copies (clip, fill, phase,
    second differences on each thread) several times over within a 16th of the limit."""
    return max(memory_limit // (16 * 16 * 6 * 8), 1024)


def grouped_phase_rows(memory_limit: int) -> int:
    """Rows of the Allan phase kept in memory when the six channels go through one pass
    (three to a `StreamedAllan`): their buffers (twice the rows, six channels of float64)
    within an eighth of the limit; longer lags read the phase file."""
    return max(memory_limit // (16 * 6 * 8), 1024)


def phase_rows(memory_limit: int, n: int) -> int:
    """Rows of one channel's Allan phase kept in memory (`StreamedAllan`'s memory_rows)
    when the channels are solved one after the other: the whole phase (n + 1 rows) when
    it takes at most half the limit, else a third of that (its buffer holds twice the
    rows kept and a batch); longer lags then read the phase file."""
    rows = memory_limit // (2 * 8)
    return n + 1 if n + 1 <= rows else max(rows // 3, 1024)


def phase_workspace(memory_limit: int, n: int) -> np.ndarray | None:
    """Room for one channel's whole Allan phase (n + 1 float64 values) when `phase_rows`
    holds it, else None. A large one is an anonymous mapping of its own: NumPy asks the
    kernel for transparent huge pages for large arrays, and when the page cache fills the
    memory (it does while a long record is read) each such fault stalls in compaction
    (about 1 s for 450 MB here, against 0.2 s in small pages). A small one comes from the
    C heap, which may hold memory the read freed."""
    if phase_rows(memory_limit, n) < n + 1:
        return None
    if (n + 1) * 8 < MAPPED_BYTES:
        return np.empty(n + 1)
    return np.frombuffer(mmap.mmap(-1, (n + 1) * 8), dtype=np.float64)


MAPPED_BYTES = 32 << 20  # glibc's malloc maps blocks this large itself


def give_back_freed_memory() -> None:
    """Return the C heap's free pages to the system (glibc's ``malloc_trim``): buffers a
    pass freed stay resident otherwise, under whatever the next pass maps (the Allan
    phase's workspace is a mapping of its own) in the process's peak. Nothing where the
    C library has no ``malloc_trim``."""
    trim = getattr(ctypes.CDLL(None), "malloc_trim", None)
    if trim is not None:
        trim(0)


def solve_streamed(
    streamed: Streamed,
    settings: dict[str, Any],
    *,
    label: str = "record",
    gravity: float,
    memory_limit: int = DEFAULT_MEMORY_LIMIT,
    trend: TemperatureTrend | None = None,
    chunks: Callable[[], Iterator[tuple]] | None = None,
    procedure: str = "static_bias",
) -> Calibration:
    """The solve of a streamed record (second pass over its Parquet samples) by its
    procedure's `stream_solver`.

    settings : the run's settings (the procedure leaves out its reading settings such as
        memory_limit_mb).
    procedure : the run's procedure (one that streams: `Procedure.stream_solver`).
    trend : fed with the samples' time and temperature on the way (the conditions').
    chunks : other (t, gyr, acc) chunks to solve (a fresh iterator per call; two passes:
        e.g. the samples corrected by an earlier calibration; t in s); None: the samples'.
    Returns the Calibration, the record's motion check among its checks.
    """
    own = chunks is None  # the samples themselves: the first pass's statistics hold
    histories: list[FileHistory] = []
    give_back_freed_memory()  # the read's buffers, before the phase takes its memory

    def new_history() -> FileHistory:
        histories.append(FileHistory(streamed.samples.parent))
        return histories[-1]

    progress = _SolveProgress(streamed, len(CHANNELS)) if own else None
    feed = by_channel = None
    if progress is not None:  # one column at a time
        needs_trend = trend is not None and trend.n_finite > 0
        feed = ChannelFeed(streamed.samples, memory_limit, trend if needs_trend else None)

        def by_channel(c: int) -> Iterator[np.ndarray]:
            return progress.counted(feed.channel(c))

    if chunks is None:
        chunks = lambda: samples_chunks(streamed.samples, memory_limit)  # noqa: E731
    n = streamed.first.n
    # the helper: motion windows, a sensor's channels or half of the Allan sums
    side = ThreadPoolExecutor(2, thread_name_prefix="calib-solve-side")
    try:
        execution = Execution(
            submit=side.submit if (os.cpu_count() or 1) > 1 else None,
            memory_rows=phase_rows(memory_limit, n) if own else grouped_phase_rows(memory_limit),
            new_history=new_history,
            workspace=phase_workspace(memory_limit, n) if own else None,
        )
        cal = procedures.get(procedure).stream_solver(
            chunks,
            settings,
            label=label,
            first=streamed.first if own else None,
            gravity=gravity,
            motion_label=label,
            channel_chunks=by_channel,
            execution=execution,
        )
    finally:
        if feed is not None:
            feed.close()
        side.shutdown()
        for history in histories:
            history.close()
        give_back_freed_memory()  # the solve's, before the archive's work
    if progress is not None:
        progress.end()
    return cal
