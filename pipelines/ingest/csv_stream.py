"""A long static record from delimited text in bounded memory, and its static-bias solve.

`stream_csv` reads the file once, block by block: each block's bytes are hashed and
copied (the raw copy), its complete lines parsed by pyarrow into SI samples (the
column plan and units of `csv_reader`), written as a row group of the samples'
Parquet (`storage.rawstore.samples_parquet_options`) and added to the first-pass
statistics (`calib_core.solvers.static_bias.FirstPass`; the record's motion
windows among them, on a worker thread beside the reading).
`pipelines.streamed_solve` solves it from the Parquet. Memory stays bounded by
`memory_limit` whatever the record's length; progress (bytes, samples, rate, time left)
goes to stderr on long reads.
"""

from __future__ import annotations

import hashlib
import sys
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

from calib_core.solvers.static_bias import FirstPass
from calib_core.streamed import Execution
from pipelines.ingest.csv_layout import AXES, header_units, layout_of
from pipelines.ingest.csv_reader import (
    PROGRESS_THRESHOLD_BYTES,
    float_values,
    iso_seconds,
    seconds,
    sensor_si,
    temperature_celsius,
)
from pipelines.ingest.data_format import FormatSpec
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import impossible_reading
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
    window: tuple[float, float] | None = None,
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
    window : (start, end) s: the samples with start <= t < end only (`windowed`) go to
        the Parquet and the statistics; None: all.
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
    sha = hashlib.sha256()
    rows, t0, last_t, done, temp_finite = 0, 0.0, None, 0, 0
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
        # Each block's Parquet is written on a thread while the next block is parsed; the
        # first pass's work after the first block on another.
        parquet = _Background("calib-parquet")
        first = FirstPass.empty(execution=Execution(submit=parquet.pool.submit))
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
                t0 = float(chunk["t"][0]) if last_t is None else t0
                last_t = float(chunk["t"][-1])
                rows += len(chunk["t"])
                bar.update(done, rows)
                chunk = windowed(chunk, window)
                if len(chunk["t"]) == 0:
                    continue
                parquet.run(writer.write_table, parquet_table(chunk, label, schema))
                first.push((chunk["t"], chunk["gyr"], chunk["acc"]))
                if "temp" in layout.roles:
                    temp_finite += int(np.isfinite(chunk["temp"]).sum())
            first.close()  # the last chunk's motion windows (computed beside the reading)
        finally:
            parquet.close()
    bar.update(done, rows, final=True)
    if rows == 0:
        raise IngestError("no data rows", file=path)
    seconds_ = time.perf_counter() - started
    span = (t0, last_t)
    return Streamed(sha.hexdigest(), size, Path(samples), first, seconds_, temp_finite, span)


def windowed(
    chunk: dict[str, np.ndarray], window: tuple[float, float] | None
) -> dict[str, np.ndarray]:
    """The rows of a chunk (increasing t, s) with start <= t < end (`Recording.window`'s
    rule), as views; all of them when `window` is None."""
    if window is None:
        return chunk
    lo, hi = np.searchsorted(chunk["t"], window, side="left")
    return chunk if (lo, hi) == (0, len(chunk["t"])) else {k: v[lo:hi] for k, v in chunk.items()}


class _Background:
    """One call at a time on a worker thread: `run` waits for the previous call (raising
    its error) before it starts the next; `close` waits for the last."""

    def __init__(self, name: str):
        self.pool = ThreadPoolExecutor(2, thread_name_prefix=name)  # one for others' calls
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
            v = iso_seconds(col.combine_chunks())
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
    gyr = sensor_si(both[:, :3], "gyr", fmt)
    acc = sensor_si(both[:, 3:], "acc", fmt)
    found = impossible_reading({"acc": acc, "gyr": gyr})
    if found is not None:  # the in-memory route's check (run_loader: check_readings)
        name, i, text = found
        raise IngestError(text, file=path, line=layout.line_of_row(rows + i), field=name)
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
    temp = temperature_celsius(layout, values.get("temp"))
    return {"t": t, "acc": acc, "gyr": gyr, "temp": np.full(n, np.nan) if temp is None else temp}


def _copy_values(column: pa.ChunkedArray, out: np.ndarray) -> None:
    """A float64 column's values into out (n,), chunk by chunk (nulls as NaN)."""
    start = 0
    for chunk in column.chunks:
        out[start : start + len(chunk)] = float_values(chunk)
        start += len(chunk)


def parquet_table(chunk: dict[str, np.ndarray], label: str, schema: pa.Schema) -> pa.Table:
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
