"""One pass over a data file in bounded memory: what every format's streamed route shares.

A format's reader yields chunks of samples; on the streamed route (`StreamedPass`) each
chunk goes to a `SampleSink`, which writes it as a row group of the samples' Parquet
(`storage.rawstore.samples_parquet_options`) and pushes it to the first-pass statistics
(`calib_core.solvers.static_bias.FirstPass`), while the file's bytes are hashed and copied
(the raw copy) as they are read (`HashingTee`, or the CSV reader's own block reader).
`pipelines.streamed_solve` solves the record from the Parquet. Memory stays bounded by
`memory_limit` whatever the record's length; progress (bytes, samples, rate, time left)
goes to stderr on long reads.

Each kind of background work has a worker of its own: the Parquet writes one, the first
pass's another. With one pool shared by both, a 12 MiB-limit bag's pass grew by 10.5-13
MiB instead of 6-8.6 (most likely each worker's allocator arena held both kinds of buffers).
"""

from __future__ import annotations

import hashlib
import os
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, TypedDict

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from calib_core.solvers.static_bias import FirstPass
from calib_core.streamed import Execution, MedianStep
from pipelines.ingest.cdr import NS
from pipelines.ingest.csv_layout import AXES
from pipelines.ingest.data_format import PROGRESS_THRESHOLD_BYTES
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import check_finite, impossible_reading
from pipelines.ingest.time_order import check_time_increases
from storage.rawstore import samples_parquet_options

DEFAULT_MEMORY_LIMIT = 10**9  # bytes: the `memory_limit_mb` setting's default
ROW_BYTES = 8 * 8  # t, 6 channels, temp as float64
SAMPLE_COLUMNS = ("t", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z", "temp")
SCHEMA = pa.schema([("segment", pa.string())] + [(c, pa.float64()) for c in SAMPLE_COLUMNS])
SKIP_BLOCK = 1 << 20  # bytes read at a time when a reader skips records
QUEUED = 4  # blocks waiting to be hashed and copied


def block_bytes(memory_limit: int) -> int:
    """Text per parsed block: a 32nd of the limit (the block, its parse, its arrays and
    the Parquet writer's buffers several times over), between 64 kB and 64 MB."""
    return int(min(max(memory_limit // 32, 64 << 10), 64 << 20))


@dataclass
class Streamed:
    """What one pass over a data file gave: its hash and size, the samples' Parquet,
    the first-pass statistics."""

    sha256: str
    size: int
    samples: Path
    first: FirstPass
    seconds: float
    temp_finite: int = 0  # samples with a finite temperature (0: no temperature)
    span: tuple[float, float] | None = None  # the data's first and last time, s (all rows)


class Progress:
    """Bytes, samples, rate and time left on one stderr line, at most once a second."""

    def __init__(self, name: str, size: int, show: bool, verb: str = "reading"):
        self.name, self.size, self.show, self.verb = name, size, show, verb
        self.started = self.last = time.monotonic()

    def update(self, done: int, samples: int, final: bool = False) -> None:
        now = time.monotonic()
        if not self.show or (now - self.last < 1.0 and not final):
            return
        self.last = now
        rate = done / max(now - self.started, 1e-9)
        left = (self.size - done) / rate if rate > 0 else float("nan")
        sys.stderr.write(
            f"\r{self.verb} {self.name}: {done / 1e6:,.0f} / {self.size / 1e6:,.0f} MB, "
            f"{samples:,} samples, {rate / 1e6:.0f} MB/s, {left:.0f} s left "
            + ("\n" if final else "")
        )
        sys.stderr.flush()


def windowed(
    chunk: dict[str, np.ndarray], window: tuple[float, float] | None
) -> dict[str, np.ndarray]:
    """The rows of a chunk (increasing t, s) with start <= t < end (`Recording.window`'s
    rule), as views; all of them when `window` is None."""
    if window is None:
        return chunk
    lo, hi = np.searchsorted(chunk["t"], window, side="left")
    return chunk if (lo, hi) == (0, len(chunk["t"])) else {k: v[lo:hi] for k, v in chunk.items()}


def parquet_table(chunk: dict[str, np.ndarray], label: str, schema: pa.Schema = SCHEMA) -> pa.Table:
    """A chunk (t (n,), acc and gyr (n, 3), temp (n,)) as the samples' Parquet rows."""
    n = len(chunk["t"])
    cols: dict[str, Any] = {"segment": labels(label, n)}
    cols["t"] = arrow_column(chunk["t"])
    for i, a in enumerate(AXES):
        cols[f"acc_{a}"] = arrow_column(chunk["acc"][:, i])
        cols[f"gyr_{a}"] = arrow_column(chunk["gyr"][:, i])
    cols["temp"] = arrow_column(chunk["temp"])
    return pa.table(cols, schema=schema)


def arrow_column(values: np.ndarray) -> pa.Array:
    """A float64 column as an Arrow array over the same memory when it is contiguous
    (NaN stays a value, as ``pa.array`` keeps it)."""
    values = np.ascontiguousarray(values, dtype=np.float64)
    return pa.Array.from_buffers(pa.float64(), len(values), [None, pa.py_buffer(values)])


def labels(label: str, n: int) -> pa.Array:
    """`label` n times as an Arrow string array, from one bytes repeat and its offsets."""
    b = label.encode()
    offsets = np.arange(n + 1, dtype=np.int64) * len(b)
    kind = pa.string() if offsets[-1] <= np.iinfo(np.int32).max else pa.large_string()
    if kind == pa.string():
        offsets = offsets.astype(np.int32)
    arr = pa.Array.from_buffers(kind, n, [None, pa.py_buffer(offsets), pa.py_buffer(b * n)])
    return arr if kind == pa.string() else arr.cast(pa.string())


class HashingTee:
    """A file read forward once: every byte is hashed and copied the first time it is read.

    A reader's forward skips of records (``seek(n, 1)``) read through, so skipped records
    are hashed too; reads ahead of that point (a summary or index read first) are not,
    their bytes are hashed when the pass reaches them. `drain` hashes the rest.

    Hashing and copying run on one worker thread, in order, while the reader decodes
    (both release the GIL on large buffers): small reads (record headers, unchunked
    messages) are gathered into blocks of `SKIP_BLOCK` first; at most `QUEUED` blocks
    wait (memory: a few chunks). `close` waits for them and raises what the worker raised.
    """

    def __init__(self, fh: BinaryIO, sha: Any, copy: BinaryIO | None):
        self.fh, self.sha, self.copy = fh, sha, copy
        self.at = 0  # the reader's position
        self.hashed = 0  # bytes handed to the worker: [0, hashed)
        self.small = bytearray()
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="calib-hash")
        self.queued: deque[Future] = deque()

    def read(self, n: int = -1) -> bytes:
        data = self.fh.read(n)
        start, self.at = self.at, self.at + len(data)
        if start <= self.hashed < self.at:
            self.take(data if start == self.hashed else data[self.hashed - start :])
        return data

    def take(self, data: bytes) -> None:
        self.hashed += len(data)
        if len(data) < SKIP_BLOCK // 16:
            self.small += data
            if len(self.small) < SKIP_BLOCK:
                return
            data, self.small = self.small, bytearray()
        elif self.small:
            self.submit(self.small)
            self.small = bytearray()
        self.submit(data)

    def submit(self, data: bytes | bytearray) -> None:
        while len(self.queued) >= QUEUED:
            self.queued.popleft().result()
        self.queued.append(self.pool.submit(self.write, data))

    def write(self, data: bytes | bytearray) -> None:
        self.sha.update(data)
        if self.copy is not None:
            self.copy.write(data)

    def close(self) -> None:
        """Hash and copy what is still queued (the worker's errors raised here)."""
        try:
            if self.small:
                self.submit(self.small)
                self.small = bytearray()
            while self.queued:
                self.queued.popleft().result()
        finally:
            self.pool.shutdown(cancel_futures=True)

    def tell(self) -> int:
        return self.at

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        if whence != os.SEEK_CUR or offset <= 0 or self.at != self.hashed:
            self.at = self.fh.seek(offset, whence)  # e.g. to the summary and back
            return self.at
        left = offset
        while left > 0:
            got = self.read(min(left, SKIP_BLOCK))
            if not got:
                break
            left -= len(got)
        return self.at

    def drain(self) -> None:
        """Hash and copy what the reader did not read (the bytes after the closing magic)."""
        self.at = self.fh.seek(self.hashed)
        while self.read(SKIP_BLOCK):
            pass


class SampleSink:
    """Chunks of samples to the samples' Parquet and the first-pass statistics.

    `write` takes a checked chunk in SI (t (n,) s, acc and gyr (n, 3), temp (n,)): the
    rows in `window` are written as a row group (encoded on the writer's worker while the
    next chunk is read; one waits at most) and pushed to `first`. `push` takes a log's
    decoded messages (``stamp`` ns, ``acc``, ``gyr``) and gathers them into batches of
    `rows`, each checked (time increasing, finite and possible values; messages numbered
    in the whole topic) and put on the in-memory readers' time base (Unix s from exact
    integer offsets to the first stamp) before `write`.
    """

    def __init__(
        self,
        name: str,
        writer: pq.ParquetWriter,
        label: str,
        rows: int = 1,
        window: tuple[float, float] | None = None,
        written: Callable[[int], None] = lambda n: None,
    ):
        self.name, self.writer, self.label, self.rows = name, writer, label, rows
        self.window = window  # (start, end) s: the rows written
        # the whole record's median step (its rate check) when a window keeps part of it
        self.steps = MedianStep() if window is not None else None
        self.written = written  # called with the samples read so far (progress)
        self.topic = "?"  # the streamed topic of a log (its errors name it)
        self.parts: list[dict[str, np.ndarray]] = []
        self.pending = 0
        self.done = 0  # samples read
        self.t0: np.int64 | None = None  # a log's first stamp, ns
        self.last: np.int64 | None = None
        self.span: tuple[float, float] | None = None  # first and last time, s (all rows)
        self.temp_finite = 0
        self.writes = ThreadPoolExecutor(1, thread_name_prefix="calib-parquet")
        self.helper = ThreadPoolExecutor(1, thread_name_prefix="calib-first")
        self.first = FirstPass.empty(execution=Execution(submit=self.helper.submit))
        self.writing: Future | None = None

    def push(self, part: dict[str, np.ndarray]) -> None:
        self.parts.append(part)
        self.pending += len(part["stamp"])
        if self.pending >= self.rows:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        parts, self.parts, self.pending = self.parts, [], 0
        stamp = np.concatenate([p["stamp"] for p in parts])
        where = f"topic {self.topic!r}"
        ahead = stamp if self.last is None else np.concatenate([[self.last], stamp])
        check_time_increases(
            ahead,
            file=self.name,
            sample="message",
            unit="ns",
            prefix=f"{where}: ",
            offset=self.done - (self.last is not None),
        )
        n = len(stamp)
        # [gyr | acc]: the first pass takes views of one array; column-major, so each
        # channel is contiguous for the statistics and the Parquet columns
        both = np.empty((n, 6), order="F")
        np.concatenate([p["gyr"] for p in parts], out=both[:, :3])
        np.concatenate([p["acc"] for p in parts], out=both[:, 3:])
        check_finite(self.name, where, "linear_acceleration", both[:, 3:], self.done)
        check_finite(self.name, where, "angular_velocity", both[:, :3], self.done)
        found = impossible_reading({"acc": both[:, 3:], "gyr": both[:, :3]})
        if found is not None:  # the in-memory route's check (run_loader: check_readings)
            name, i, text = found
            raise IngestError(f"{where}: message {self.done + i} (0-based): {text}", file=self.name)
        if self.t0 is None:
            self.t0 = stamp[0]
        self.last = stamp[-1]
        t = (stamp - self.t0) / NS + self.t0 / NS
        self.write({"t": t, "gyr": both[:, :3], "acc": both[:, 3:], "temp": np.full(n, np.nan)})

    def write(self, chunk: dict[str, np.ndarray]) -> None:
        """A checked chunk in SI: its rows in the window to the Parquet and `first`."""
        t = chunk["t"]
        self.span = (float(t[0]) if self.span is None else self.span[0], float(t[-1]))
        self.done += len(t)
        self.written(self.done)
        if self.steps is not None:
            self.steps.push(t)
        chunk = windowed(chunk, self.window)
        if len(chunk["t"]) == 0:
            return
        table = parquet_table(chunk, self.label, self.writer.schema)
        self.wait()
        self.writing = self.writes.submit(self.writer.write_table, table)
        self.first.push((chunk["t"], chunk["gyr"], chunk["acc"]))
        self.temp_finite += int(np.isfinite(chunk["temp"]).sum())

    def wait(self) -> None:
        """Until the chunk being written is (its errors raised here)."""
        if self.writing is not None:
            writing, self.writing = self.writing, None
            writing.result()

    def finish(self) -> None:
        """The last batch written, the first pass's work on it done."""
        self.flush()
        self.wait()
        self.first.close()

    def close(self) -> None:
        try:
            self.wait()
        finally:
            self.writes.shutdown(cancel_futures=True)
            self.helper.shutdown(cancel_futures=True)


class StreamOptions(TypedDict, total=False):
    """The options of every format's streamed reader (`streaming.STREAMERS`).

    copy_to : where the raw bytes are copied (None, the default: not copied).
    label : the segment label of every row (default ``"record"``).
    memory_limit : bytes (default `DEFAULT_MEMORY_LIMIT`): the block, batch and largest
        chunk a pass holds.
    progress : a progress line on stderr; None (default): for files above
        `PROGRESS_THRESHOLD_BYTES`.
    window : (start, end) s: the samples with start <= t < end only (`windowed`) go to the
        Parquet and the statistics; None (default): all.
    """

    copy_to: Path | None
    label: str
    memory_limit: int
    progress: bool | None
    window: tuple[float, float] | None


@dataclass
class StreamedPass:
    """An open pass: the data file `fh`, its hash `sha` and raw copy `copy`, the `sink`."""

    path: Path
    size: int
    fh: BinaryIO
    sha: Any
    copy: BinaryIO | None
    sink: SampleSink
    bar: Progress
    samples: Path
    started: float
    memory_limit: int
    tee: HashingTee | None = None  # the file read through it (hashed and copied)

    def result(self) -> Streamed:
        """What the pass gave, once the sink is finished."""
        self.bar.update(self.size, self.sink.done, final=True)
        sink, seconds = self.sink, time.perf_counter() - self.started
        return Streamed(
            self.sha.hexdigest(), self.size, self.samples, sink.first, seconds,
            sink.temp_finite, sink.span,
        )  # fmt: skip


@contextmanager
def streamed_pass(
    path: Path,
    samples: Path,
    *,
    copy_to: Path | None = None,
    label: str = "record",
    memory_limit: int = DEFAULT_MEMORY_LIMIT,
    progress: bool | None = None,
    window: tuple[float, float] | None = None,
    tee: bool = False,
) -> Iterator[StreamedPass]:
    """Open the data file, the samples' Parquet writer, the raw copy and the sink.

    The sink gathers `block_bytes(memory_limit) // ROW_BYTES` messages a batch. With
    `tee`, the file is read through a `HashingTee` (`SKIP_BLOCK` buffering), the progress
    line following its bytes; it is closed (all hashed and copied) before the sink. An
    OSError reading the file becomes the IngestError naming it.
    """
    started = time.perf_counter()
    path = Path(path)
    size = path.stat().st_size
    show = size > PROGRESS_THRESHOLD_BYTES if progress is None else progress
    bar = Progress(path.name, size, show)
    try:
        with ExitStack() as stack:
            fh = stack.enter_context(path.open("rb", buffering=SKIP_BLOCK if tee else -1))
            writer = stack.enter_context(
                pq.ParquetWriter(samples, SCHEMA, **samples_parquet_options(SCHEMA))
            )
            copy = stack.enter_context(copy_to.open("wb")) if copy_to is not None else None
            rows = block_bytes(memory_limit) // ROW_BYTES
            sink = SampleSink(str(path), writer, label, rows, window)
            stack.callback(sink.close)
            sha = hashlib.sha256()
            run = StreamedPass(
                path, size, fh, sha, copy, sink, bar, Path(samples), started, memory_limit
            )
            if tee:
                run.tee = HashingTee(fh, sha, copy)
                stack.callback(run.tee.close)
                sink.written = lambda n: bar.update(run.tee.hashed, n)
            yield run
    except OSError as exc:
        raise IngestError(f"cannot read file: {exc.strerror or exc}", file=path) from exc
