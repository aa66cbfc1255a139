"""A long static record from delimited text in bounded memory, and its static-bias solve.

`stream_csv` reads the file once, block by block: each block's bytes are hashed and
copied (the raw copy), its complete lines parsed by pyarrow into SI samples (the
column plan and units of `csv_reader`), written as a row group of the samples'
Parquet (`storage.rawstore.samples_parquet_options`) and added to the first-pass
statistics (`calib_core.solvers.static_bias_stream.FirstPass`). `solve_streamed` then
reads the Parquet back for the static-bias solve's second pass, one channel (column)
after the other (`ChannelFeed`): a channel's whole Allan phase in memory when half the
limit holds it (`phase_rows`, `phase_workspace`), else its last rows, the long lags from
a phase file (`FileHistory`). Memory stays bounded by `memory_limit` whatever the
record's length; progress (bytes, samples, rate, time left) goes to stderr on long reads.
The record's motion check (`calib_core.preprocess.motion`'s `StreamedMotion`: the
windows' statistics as the chunks pass) is computed by the first pass, on a worker thread
beside the reading; the solve's pass computes it only when the first chunk's rate did not
give the record's window width (`FirstPass.settled_motion`).
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import mmap
import os
import queue
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from calib_core import procedures
from calib_core.calibration import Calibration
from calib_core.solvers.static_bias_stream import FirstPass
from calib_core.streamed import TemperatureTrend
from pipelines.ingest.csv_layout import AXES, header_units, layout_of
from pipelines.ingest.csv_reader import (
    PROGRESS_THRESHOLD_BYTES,
    _celsius,
    _float_values,
    _iso_seconds,
    _to_si,
    seconds,
)
from pipelines.ingest.data_format import FormatSpec
from pipelines.ingest.errors import IngestError
from storage.rawstore import samples_parquet_options

DEFAULT_MEMORY_LIMIT = 10**9  # bytes: the `memory_limit_mb` setting's default
ROW_BYTES = 8 * 8  # t, 6 channels, temp as float64
SAMPLE_COLUMNS = ("t", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z", "temp")
CHANNELS = (*(f"gyr_{a}" for a in AXES), *(f"acc_{a}" for a in AXES))  # [gyr | acc]


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


def _blocks(fh: BinaryIO, size: int, copy: BinaryIO | None, sha: Any) -> Iterator[memoryview]:
    """The file's bytes in blocks cut after a line end; every byte hashed and copied once.

    Read into two buffers in turn: a thread hashes and copies one buffer's new bytes
    while the caller parses the block before it is handed out (hashing overlaps
    parsing); a buffer is read into again only once its bytes are hashed and copied.
    Each block is a view, valid until the next one is asked for (the parser copies what
    it keeps); the unfinished last line moves to the front of the other buffer. All is
    hashed and copied when the iteration ends.
    """
    bufs = [bytearray(2 * size), bytearray(2 * size)]
    jobs: list[Future | None] = [None, None]
    io = ThreadPoolExecutor(max_workers=1, thread_name_prefix="calib-hash")

    def consume(view: memoryview) -> None:
        sha.update(view)
        if copy is not None:
            copy.write(view)

    cur, carry = 0, 0
    prev = memoryview(bufs[0])[:0]
    try:
        while True:
            if jobs[cur] is not None:
                jobs[cur].result()  # its last bytes are hashed: it may be filled again
            if len(bufs[cur]) - carry < size:  # a line longer than a block: grow
                bufs[cur] = bytearray(carry + 2 * size)
            view = memoryview(bufs[cur])
            view[:carry] = prev[len(prev) - carry :] if carry else b""
            got = fh.readinto(view[carry : carry + size])
            if not got:
                if carry:
                    yield view[:carry]
                return
            jobs[cur] = io.submit(consume, view[carry : carry + got])
            end = carry + got
            cut = bufs[cur].rfind(b"\n", 0, end) + 1
            prev, carry = view[:end], end - cut
            if cut:
                yield view[:cut]
                cur = 1 - cur
            # else: no line end yet; read on into the same buffer after the carry
            else:
                jobs[cur].result()
                prev = memoryview(bytes(view[:end]))
    finally:
        io.shutdown(wait=True)
        for job in jobs:
            if job is not None:
                job.result()  # raise a failed write (a full disk)


def stream_csv(
    path: Path,
    fmt: FormatSpec,
    samples: Path,
    *,
    copy_to: Path | None = None,
    label: str = "record",
    memory_limit: int = DEFAULT_MEMORY_LIMIT,
    progress: bool | None = None,
) -> Streamed:
    """One pass over a delimited text file: hash, raw copy, samples' Parquet, statistics.

    Parameters
    ----------
    path : the data file (delimited text with a time column or a sample rate; one record).
    fmt : the manifest's format section (as `csv_reader.read_csv`).
    samples : the Parquet file to write (columns segment, t, acc_*, gyr_*, temp; SI).
    copy_to : where the raw bytes are copied (None: not copied).
    label : the segment label of every row.
    memory_limit : bytes; sets the block size.
    progress : a progress line on stderr; None: for files above PROGRESS_THRESHOLD_BYTES.

    Raises
    ------
    IngestError naming the file and the line where time stops increasing or a value is
    not a finite number.
    """
    started = time.perf_counter()
    path = Path(path)
    layout = layout_of(path, fmt, sections=False)
    if layout.delimiter == "whitespace" or "section" in layout.roles:
        raise IngestError("the streamed route reads delimited text of one record only", file=path)
    fmt = header_units(layout, fmt)
    iso = layout.roles.get("time") if fmt.time_unit == "iso" else None
    columns = list(dict.fromkeys(layout.roles.values()))
    types = {c: (pa.string() if c == iso else pa.float64()) for c in columns}
    read = pacsv.ReadOptions(column_names=layout.names, encoding="utf8")
    parse = pacsv.ParseOptions(delimiter=layout.delimiter)
    convert = pacsv.ConvertOptions(
        include_columns=columns, column_types=types, decimal_point=layout.decimal
    )
    size = path.stat().st_size
    show = size > PROGRESS_THRESHOLD_BYTES if progress is None else progress
    bar = Progress(path.name, size, show)
    sha, first = hashlib.sha256(), FirstPass.empty()
    rows, last_t, done, temp_finite = 0, None, 0, 0
    schema = pa.schema([("segment", pa.string())] + [(c, pa.float64()) for c in SAMPLE_COLUMNS])
    with (
        path.open("rb") as fh,
        pq.ParquetWriter(samples, schema, **samples_parquet_options(schema)) as writer,
        copy_to.open("wb") if copy_to is not None else nullcontext() as copy,
    ):
        head = b"".join(fh.readline() for _ in range(layout.data_start - 1))
        sha.update(head)
        if copy is not None:
            copy.write(head)
        done = len(head)
        # Each block's Parquet is written on a thread while the next block is parsed.
        parquet = _Background("calib-parquet")
        try:
            for text in _blocks(fh, block_bytes(memory_limit), copy, sha):
                done += len(text)
                try:
                    table = pacsv.read_csv(pa.py_buffer(text), read, parse, convert)
                except pa.ArrowInvalid as exc:
                    raise IngestError(f"cannot parse the file: {exc}", file=path) from None
                if table.num_rows == 0:  # blank lines only
                    continue
                chunk = _chunk(table, layout, fmt, iso, rows, path, last_t)
                last_t = float(chunk["t"][-1])
                parquet.run(writer.write_table, _table(chunk, label, schema))
                first.push((chunk["t"], chunk["gyr"], chunk["acc"]))
                if "temp" in layout.roles:
                    temp_finite += int(np.isfinite(chunk["temp"]).sum())
                rows += len(chunk["t"])
                bar.update(done, rows)
            first.close()  # the last chunk's motion windows (computed beside the reading)
        finally:
            parquet.close()
    bar.update(done, rows, final=True)
    if rows == 0:
        raise IngestError("no data rows", file=path)
    seconds_ = time.perf_counter() - started
    return Streamed(sha.hexdigest(), size, Path(samples), first, seconds_, temp_finite)


class _Background:
    """One call at a time on a worker thread: `run` waits for the previous call (raising
    its error) before it starts the next; `close` waits for the last."""

    def __init__(self, name: str):
        self.pool = ThreadPoolExecutor(1, thread_name_prefix=name)
        self.running: Future | None = None

    def run(self, fn: Callable, *args: Any) -> None:
        self.wait()
        self.running = self.pool.submit(fn, *args)

    def wait(self) -> None:
        if self.running is not None:
            running, self.running = self.running, None
            running.result()

    def close(self) -> None:
        try:
            self.wait()
        finally:
            self.pool.shutdown(cancel_futures=True)


def _chunk(
    table: pa.Table, layout, fmt: FormatSpec, iso, rows: int, path: Path, last_t: float | None
) -> dict[str, np.ndarray]:
    """One block's samples in SI: t (n,), acc and gyr (n, 3), temp (n,) (NaN if none)."""
    n = table.num_rows
    # [gyr | acc]: the first pass takes it without a copy; column by column in memory, so
    # each column is filled, reduced and handed to Arrow without a strided copy. The
    # parser's chunks are copied straight into it (one copy, no combined Arrow column).
    both = np.empty((n, 6), order="F")
    values: dict[str, np.ndarray] = {}
    for role, name in layout.roles.items():
        col = table.column(name)
        if name == iso:
            v = _iso_seconds(col.combine_chunks())
        else:
            v = both[:, CHANNELS.index(role)] if role in CHANNELS else np.empty(n)
            _copy_values(col, v)
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise IngestError(
                "expected a finite number",
                file=path,
                line=layout.line_of_row(rows + int(bad[0])),
                field=layout.fields[name],
            )
        values[role] = v
    gyr = _to_si(both[:, :3], "gyr", fmt)
    acc = _to_si(both[:, 3:], "acc", fmt)
    if "time" in values:
        t = values["time"]
        if fmt.time_unit == "samples":
            t = t / fmt.sample_rate_hz
        elif fmt.time_unit != "iso":
            t = seconds(t, fmt.time_unit)
    else:
        t = (rows + np.arange(n)) / fmt.sample_rate_hz
    steps = np.diff(t, prepend=-np.inf if last_t is None else last_t)
    if (steps <= 0).any():
        row = rows + int(np.flatnonzero(steps <= 0)[0])
        field = layout.fields.get(layout.roles.get("time", ""), "time")
        raise IngestError(
            "time must increase", file=path, line=layout.line_of_row(row), field=field
        )
    temp = _celsius(layout, values.get("temp"))
    return {"t": t, "acc": acc, "gyr": gyr, "temp": np.full(n, np.nan) if temp is None else temp}


def _copy_values(column: pa.ChunkedArray, out: np.ndarray) -> None:
    """A float64 column's values into out (n,), chunk by chunk (nulls as NaN)."""
    start = 0
    for chunk in column.chunks:
        out[start : start + len(chunk)] = _float_values(chunk)
        start += len(chunk)


def _table(chunk: dict[str, np.ndarray], label: str, schema: pa.Schema) -> pa.Table:
    n = len(chunk["t"])
    cols: dict[str, Any] = {"segment": _labels(label, n)}
    cols["t"] = _column(chunk["t"])
    for i, a in enumerate(AXES):
        cols[f"acc_{a}"] = _column(chunk["acc"][:, i])
        cols[f"gyr_{a}"] = _column(chunk["gyr"][:, i])
    cols["temp"] = _column(chunk["temp"])
    return pa.table(cols, schema=schema)


def _column(values: np.ndarray) -> pa.Array:
    """A float64 column as an Arrow array over the same memory when it is contiguous
    (NaN stays a value, as ``pa.array`` keeps it)."""
    values = np.ascontiguousarray(values, dtype=np.float64)
    return pa.Array.from_buffers(pa.float64(), len(values), [None, pa.py_buffer(values)])


def _labels(label: str, n: int) -> pa.Array:
    """`label` n times as an Arrow string array, from one bytes repeat and its offsets."""
    b = label.encode()
    offsets = np.arange(n + 1, dtype=np.int64) * len(b)
    kind = pa.string() if offsets[-1] <= np.iinfo(np.int32).max else pa.large_string()
    if kind == pa.string():
        offsets = offsets.astype(np.int32)
    arr = pa.Array.from_buffers(kind, n, [None, pa.py_buffer(offsets), pa.py_buffer(b * n)])
    return arr if kind == pa.string() else arr.cast(pa.string())


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
        both[:, i] = _float_values(batch.column(i))
    return _float_values(batch.column(6)), both


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
                    self.trend.push(_float_values(batch.column(1)), _float_values(batch.column(2)))
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
            yield _float_values(batch.column(0)).reshape(-1, 1)

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
    # motion windows, and half of the Allan sums: a thread of its own (no nesting)
    side = ThreadPoolExecutor(1, thread_name_prefix="calib-solve-side")
    try:
        cal = procedures.get(procedure).stream_solver(
            chunks,
            settings,
            label=label,
            first=streamed.first if own else None,
            gravity=gravity,
            new_history=new_history,
            memory_rows=phase_rows(memory_limit, streamed.first.n)
            if own
            else grouped_phase_rows(memory_limit),
            parallel=(os.cpu_count() or 1) > 1,
            motion_label=label,
            submit=side.submit,
            channel_chunks=by_channel,
            workspace=phase_workspace(memory_limit, streamed.first.n) if own else None,
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
