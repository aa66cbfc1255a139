"""A long ROS 2 IMU record from MCAP in bounded memory (the streamed route of `csv_stream`).

`stream_mcap` is `pipelines.ingest.mcap_reader`'s reader run over the file once, its
bytes passing through a tee that hashes and copies them (the raw copy) as they are read.
Nothing is re-implemented: the record walk, chunk decompression, CRC and truncation
checks, topic selection (`McapReader._role` / `_pick`), the vectorised CDR decoding of
``sensor_msgs/msg/Imu`` (`pipelines.ingest.cdr`: its layout is fixed once the frame_id's
length is known, so numpy gathers decode every message of a chunk at once, where
mcap-ros2-support builds one Python object per message, minutes for an hour at 1 kHz)
and the stamp choice (header stamp or log time) are the in-memory reader's.
Only where a chunk's decoded IMU messages go differs: instead of the whole topic's
arrays they are gathered into batches of a size set by `memory_limit`, checked (time
increasing, finite values; messages numbered in the whole topic), converted to the
in-memory reader's time base (Unix s from exact integer offsets to the first stamp),
written as a row group of the samples' Parquet and added to the first-pass statistics.

The result is `csv_stream.Streamed`, so `streamed_solve.solve_streamed` solves it unchanged.
Only the IMU topic is streamed: temperature and rate-table topics are interpolated onto
the whole IMU time base by the in-memory reader, and are refused here with the reason.
"""

from __future__ import annotations

import hashlib
import os
import struct
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import nullcontext
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from calib_core.solvers.static_bias import FirstPass
from calib_core.streamed import Execution, MedianStep
from pipelines.ingest.cdr import NS
from pipelines.ingest.csv_reader import PROGRESS_THRESHOLD_BYTES
from pipelines.ingest.csv_stream import (
    DEFAULT_MEMORY_LIMIT,
    ROW_BYTES,
    SAMPLE_COLUMNS,
    Progress,
    Streamed,
    block_bytes,
    parquet_table,
    windowed,
)
from pipelines.ingest.data_format import FormatSpec
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import impossible_reading
from pipelines.ingest.mcap_reader import McapChannel, McapReader, check_arguments, check_finite
from pipelines.ingest.readers import MCAP_KEYS, extra_keys
from pipelines.ingest.time_order import check_time_increases
from storage.rawstore import samples_parquet_options

SKIP_BLOCK = 1 << 20  # bytes read at a time when the reader skips records
_QUEUED = 4  # blocks waiting to be hashed and copied


class HashingTee:
    """A file read forward once: every byte is hashed and copied the first time it is read.

    The reader's forward skips of records (``seek(n, 1)``) read through, so skipped records
    are hashed too; reads ahead of that point (the summary, read first through the footer)
    are not, their bytes are hashed when the pass reaches them. `drain` hashes the rest.

    Hashing and copying run on one worker thread, in order, while the reader decodes
    (both release the GIL on large buffers): small reads (record headers, unchunked
    messages) are gathered into blocks of `SKIP_BLOCK` first; at most `_QUEUED` blocks
    wait (memory: a few chunks). `close` waits for them and raises what the worker raised.
    """

    def __init__(self, fh: BinaryIO, sha: Any, copy: BinaryIO | None):
        self.fh, self.sha, self.copy = fh, sha, copy
        self.at = 0  # the reader's position
        self.hashed = 0  # bytes handed to the worker: [0, hashed)
        self.small = bytearray()
        self.pool = ThreadPoolExecutor(1)
        self.queued: deque[Future] = deque()

    def read(self, n: int = -1) -> bytes:
        data = self.fh.read(n)
        start, self.at = self.at, self.at + len(data)
        if start <= self.hashed < self.at:
            self._take(data if start == self.hashed else data[self.hashed - start :])
        return data

    def _take(self, data: bytes) -> None:
        self.hashed += len(data)
        if len(data) < SKIP_BLOCK // 16:
            self.small += data
            if len(self.small) < SKIP_BLOCK:
                return
            data, self.small = self.small, bytearray()
        elif self.small:
            self._submit(self.small)
            self.small = bytearray()
        self._submit(data)

    def _submit(self, data: bytes | bytearray) -> None:
        while len(self.queued) >= _QUEUED:
            self.queued.popleft().result()
        self.queued.append(self.pool.submit(self._write, data))

    def _write(self, data: bytes | bytearray) -> None:
        self.sha.update(data)
        if self.copy is not None:
            self.copy.write(data)

    def close(self) -> None:
        """Hash and copy what is still queued (the worker's errors raised here)."""
        try:
            if self.small:
                self._submit(self.small)
                self.small = bytearray()
            while self.queued:
                self.queued.popleft().result()
        finally:
            self.pool.shutdown(cancel_futures=True)

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


class _StreamReader(McapReader):
    """`McapReader` whose IMU messages go to `SampleSink` batch by batch, not to the
    topic's arrays."""

    def __init__(self, name: str, imu_topic: str | None, stamp: str, sink: SampleSink):
        super().__init__(name, imu_topic, None, None, 0, stamp)
        self.sink = sink
        self.max_chunk = 0  # bytes: a decompressed chunk larger than this is refused

    def _definition(self, opcode: int, body: bytes, pos: int) -> None:
        super()._definition(opcode, body, pos)
        if sum(c.role == "imu" for c in self.channels.values()) > 1:
            self._pick("imu")  # several Imu topics and none named: the reader's error, early

    def _chunk(self, body: bytes, pos: int) -> None:
        try:
            (size,) = struct.unpack_from("<Q", body, 16)
        except struct.error:
            size = 0  # the reader names the damaged header
        if size > self.max_chunk:
            raise IngestError(
                f"chunk at byte {pos} holds {size} bytes uncompressed, more than the memory "
                f"limit allows ({self.max_chunk}); raise the memory limit",
                file=self.name,
            )
        super()._chunk(body, pos)

    def _keep(self, ch: McapChannel, part: dict[str, np.ndarray], pos: int) -> None:
        # The first Imu channel defined is the one `_pick` returns; any other is counted
        # only (`_pick` refuses an ambiguous choice, `_definition` as soon as it is seen).
        if ch is next(c for c in self.channels.values() if c.role == "imu"):
            self.sink.push(ch, part)
        ch.count += len(part["stamp"])


class SampleSink:
    """IMU messages in batches of `rows`: checked, in SI on the reader's time base, written
    to the samples' Parquet and added to the first-pass statistics.

    A batch's Parquet row group is encoded and written on a worker thread (pyarrow
    releases the GIL) while the next batch is decoded; one batch waits at most.
    """

    def __init__(
        self,
        name: str,
        rows: int,
        writer: pq.ParquetWriter,
        label: str,
        written: Callable[[int], None],
        window: tuple[float, float] | None = None,
    ):
        self.name, self.rows, self.writer, self.label = name, rows, writer, label
        self.window = window  # (start, end) s: the rows written (`csv_stream.windowed`)
        # the whole topic's median step (its rate check) when a window keeps part of it
        self.steps = MedianStep() if window is not None else None
        self.written = written  # called with the messages written so far (progress)
        self.channel: McapChannel | None = None  # the streamed Imu channel
        self.parts: list[dict[str, np.ndarray]] = []
        self.pending = 0
        self.done = 0  # messages written
        self.t0: np.int64 | None = None  # first stamp, ns
        self.last: np.int64 | None = None
        self.pool = ThreadPoolExecutor(2)  # the Parquet writes; the first pass's work
        self.first = FirstPass.empty(execution=Execution(submit=self.pool.submit))
        self.writing: Future | None = None

    def push(self, ch: McapChannel, part: dict[str, np.ndarray]) -> None:
        self.channel = ch
        self.parts.append(part)
        self.pending += len(part["stamp"])
        if self.pending >= self.rows:
            self.flush()

    def flush(self) -> None:
        if not self.pending or self.channel is None:
            return
        parts, self.parts, self.pending = self.parts, [], 0
        stamp = np.concatenate([p["stamp"] for p in parts])
        where = f"topic {self.channel.topic!r}"
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
        # The in-memory reader's time base: exact integer offsets, one rounding to s.
        t = (stamp - self.t0) / NS + self.t0 / NS
        chunk = {"t": t, "gyr": both[:, :3], "acc": both[:, 3:], "temp": np.full(n, np.nan)}
        self.done += n
        self.written(self.done)
        if self.steps is not None:
            self.steps.push(t)
        chunk = windowed(chunk, self.window)
        if len(chunk["t"]) == 0:
            return
        table = parquet_table(chunk, self.label, self.writer.schema)
        self.wait()
        self.writing = self.pool.submit(self.writer.write_table, table)
        self.first.push((chunk["t"], chunk["gyr"], chunk["acc"]))

    @property
    def span(self) -> tuple[float, float] | None:
        """The topic's first and last time, s (None: no message)."""
        if self.t0 is None or self.last is None:
            return None
        return self.t0 / NS, (self.last - self.t0) / NS + self.t0 / NS

    def wait(self) -> None:
        """Until the batch being written is (its errors raised here)."""
        if self.writing is not None:
            writing, self.writing = self.writing, None
            writing.result()

    def close(self) -> None:
        try:
            self.wait()
        finally:
            self.pool.shutdown(cancel_futures=True)


def stream_mcap(
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
    """One pass over a ROS 2 MCAP log: hash, raw copy, samples' Parquet, statistics.

    Parameters
    ----------
    path : the .mcap file (chunked or not; none, zstd or lz4 compression).
    fmt : the manifest's format section (kind mcap: ``imu_topic``, ``stamp`` as
        `mcap_reader.read_mcap`; ``temperature_topic`` / ``table_topic`` are refused).
    samples : the Parquet file to write (columns segment, t, acc_*, gyr_*, temp; SI;
        t in Unix s; temp NaN).
    copy_to : where the raw bytes are copied (None: not copied).
    label : the segment label of every row.
    memory_limit : bytes; sets the rows per batch and the largest chunk accepted.
    window : (start, end) s: the samples with start <= t < end only go to the Parquet and
        the statistics (`csv_stream.windowed`); None: all.
    progress : a progress line on stderr; None: for files above PROGRESS_THRESHOLD_BYTES.

    Returns
    -------
    Streamed, as `csv_stream.stream_csv`.

    Raises
    ------
    IngestError naming the file: not MCAP, truncated or damaged; the IMU topic absent,
    ambiguous or empty; a message that does not decode, a non-finite value or a stamp
    not after the previous one (with the message's index in the topic).
    """
    started = time.perf_counter()
    path = Path(path)
    keys = {"table_joint": 0, "stamp": "header", **extra_keys(fmt, "mcap", MCAP_KEYS)}
    check_arguments(str(path), **{k: keys.get(k) for k in MCAP_KEYS})
    for key in ("temperature_topic", "table_topic"):
        if keys.get(key) is not None:
            raise IngestError(
                f"a record read in chunks gives its IMU topic only; {key} is interpolated "
                "onto the whole IMU time base (raise the memory limit to read it into memory)",
                file=path,
                field=f"format.{key}",
            )
    size = path.stat().st_size
    show = size > PROGRESS_THRESHOLD_BYTES if progress is None else progress
    bar = Progress(path.name, size, show)
    sha = hashlib.sha256()
    schema = pa.schema([("segment", pa.string())] + [(c, pa.float64()) for c in SAMPLE_COLUMNS])
    try:
        with (
            path.open("rb", buffering=SKIP_BLOCK) as fh,
            pq.ParquetWriter(samples, schema, **samples_parquet_options(schema)) as writer,
            copy_to.open("wb") if copy_to is not None else nullcontext() as copy,
        ):
            tee = HashingTee(fh, sha, copy)
            rows = block_bytes(memory_limit) // ROW_BYTES
            shown = lambda n: bar.update(tee.hashed, n)  # noqa: E731
            sink = SampleSink(str(path), rows, writer, label, shown, window)
            try:
                reader = _StreamReader(str(path), keys.get("imu_topic"), keys["stamp"], sink)
                # a chunk, its records and their decoded arrays: a quarter of the limit
                reader.max_chunk = memory_limit // 4
                reader.read(tee, size)
                if reader.findings:  # a cut log: the streamed route carries no findings
                    reader._pick("imu")  # no IMU before the cut: the reader's own error
                    raise IngestError(
                        f"{reader.findings[0]['detail']}; a record streamed in chunks is "
                        "not read cut (raise the memory limit to read it into memory, with "
                        "the finding)",
                        file=path,
                    )
                sink.flush()
                sink.first.close()  # the last batch's motion windows (beside the reading)
                tee.drain()
            finally:
                sink.close()
                tee.close()
    except OSError as exc:
        raise IngestError(f"cannot read file: {exc.strerror or exc}", file=path) from exc
    bar.update(size, sink.done, final=True)
    reader._pick("imu")  # absent, ambiguous, empty or short of the statistics' count
    seconds = time.perf_counter() - started
    return Streamed(sha.hexdigest(), size, Path(samples), sink.first, seconds, span=sink.span)
