"""The archive's file store: raw bytes by content hash, run folders, Parquet samples.

Layout under the file store root::

    objects/ab/ab12...ef            raw file bytes, named by their SHA-256
    runs/<serial>/<YYYY-MM-DD>/<run_id>/   protocol and other per-run files
    samples/serial=<s>/date=<d>/<run_id>.parquet   IMU samples (hive partitions)

Every write goes to a temporary file in the destination directory and is then
renamed over the target (``os.replace`` is atomic on one file system), so a
crash leaves either the old state or the new file, never half a file.

The files of one archived run go through `PendingFiles`: written under temporary
names, fsynced on a background I/O thread while the caller goes on, then
renamed into place together and their directories fsynced, so all of them are
durable before the database transaction that refers to them. `stage_raw` puts
a raw file there while it is first read and hashed (at ingest), so archiving it
later needs no second read or hash.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import os
import re
import shutil
import socket
import tempfile
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from storage.naming import check_safe_name
from storage.write_failures import with_path

if TYPE_CHECKING:  # pyarrow is imported where samples are written or read: hashing and
    # copying files (the seal's check of `calib show`, verify) need none of it
    import pyarrow as pa

# Bytes per read or write call. Writing new files in calls of a few MiB was at times an
# order of magnitude slower than in calls of 256 KiB, which were never slower than larger
# ones (benchmarks/write_chunks.py measures it; benchmarks/README.md). Reads are as fast
# either way.
IO_CHUNK = 256 << 10
TEMP_SUFFIX = ".tmp"
# Temporary files of another host (a shared file store) are removed only past this age, s.
STALE_TEMP_S = 24 * 3600.0
_WRITER = f"{socket.gethostname().replace('.', '_')}-{os.getpid()}"
ZSTD_LEVEL = -1  # of the samples Parquet files (write_samples)
# Hive partition columns are read as strings: inferred types would turn serial "0012" into 12.


def object_path(root: Path, sha256: str) -> Path:
    """Where the bytes with this SHA-256 (64 lowercase hex digits) live."""
    if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
        raise ValueError(f"invalid sha256 {sha256!r}: expected 64 lowercase hex digits")
    return Path(root) / "objects" / sha256[:2] / sha256


def _chunks(path: Path) -> Iterator[memoryview]:
    """The bytes of a file in `IO_CHUNK` chunks, read into one reused buffer.

    Each chunk is a view of that buffer: valid until the next one is asked for.
    """
    buf = bytearray(IO_CHUNK)
    view = memoryview(buf)
    with open(path, "rb", buffering=0) as f:
        while n := f.readinto(buf):
            yield view[:n]


def hash_and_size(path: Path) -> tuple[str, int]:
    """(SHA-256 hex digest, size in bytes) of a file, read in `IO_CHUNK` chunks."""
    return copy_hashing(path, None)


def _read_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


# The mode of every file the archive writes: what open() gives under the process's umask
# (0644 under the usual 022), as for the reports and exports written beside them. mkstemp's
# 0600 would survive the rename and leave archived files unreadable to the lab's other
# accounts. Read once at import, before any thread (os.umask sets as it reads).
FILE_MODE = 0o666 & ~_read_umask()


def _mkstemp(folder: Path, prefix: str, suffix: str) -> tuple[int, Path]:
    """A new temporary file in `folder` with the archive's `FILE_MODE`."""
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=prefix, suffix=suffix)
    os.fchmod(fd, FILE_MODE)
    return fd, Path(tmp)


def _temp_beside(path: Path) -> tuple[int, Path]:
    path.parent.mkdir(parents=True, exist_ok=True)
    return _mkstemp(path.parent, f".{path.name}.", ".tmp")


def write_all(fd: int, data: bytes | memoryview | pa.Buffer, call: int = IO_CHUNK) -> None:
    """Write all of `data` to the open file `fd`, `call` bytes a call."""
    view = memoryview(data).cast("B")
    for start in range(0, len(view), call):
        chunk = view[start : start + call]
        while chunk:  # a write may be short
            chunk = chunk[os.write(fd, chunk) :]


def write_atomic(path: Path, data: bytes) -> None:
    """Write `data` to `path` atomically (temporary file in the same directory + rename)."""
    path = Path(path)
    fd, tmp = _temp_beside(path)
    try:
        try:
            write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def copy_hashing(src: Path, fd: int | None) -> tuple[str, int]:
    """Copy the bytes of `src` into the open file `fd` (not closed; None: only hash them);
    return (sha256, size)."""
    h, n = hashlib.sha256(), 0
    for chunk in _chunks(src):
        h.update(chunk)
        n += len(chunk)
        if fd is not None:
            write_all(fd, chunk)
    return h.hexdigest(), n


def _check_hash(src: Path, got: str, expected: str | None) -> None:
    if expected is not None and got != expected:
        raise ValueError(
            f"raw file {src}: content hashes to {got}, expected "
            f"{expected} (was the file changed after it was read?)"
        )


def copy_atomic(src: Path, dest: Path, expected_sha256: str | None = None) -> tuple[str, int]:
    """Copy `src` to `dest` through a temporary file beside it + rename, hashing on the way.

    Returns (sha256, size) of the bytes copied. With `expected_sha256`, a mismatch
    stores nothing and raises ValueError naming the file.
    """
    fd, tmp = _temp_beside(Path(dest))
    try:
        try:
            sha, n = copy_hashing(src, fd)
            os.fsync(fd)
        finally:
            os.close(fd)
        _check_hash(src, sha, expected_sha256)
        os.replace(tmp, dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return sha, n


def _fsync_close(fd: int) -> None:
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(path: Path) -> None:
    """Make a directory's entries (files renamed into it, new subfolders) durable."""
    _fsync_close(os.open(path, os.O_RDONLY))


def _make_dirs(path: Path) -> set[Path]:
    """``mkdir -p path``; return the folders that got a new entry (parents of new folders)."""
    missing: list[Path] = []
    p = path
    while not p.is_dir() and p.parent != p:
        missing.append(p)
        p = p.parent
    if missing:
        path.mkdir(parents=True, exist_ok=True)
    return {m.parent for m in missing}


@dataclass
class _Pending:
    tmp: Path
    keep_existing: bool  # content-addressed: an existing target is never replaced
    synced: Future[None]


class PendingFiles:
    """Files written under temporary names, then made durable and visible together.

    Each file goes to a temporary file in its target's folder (``.<name>.*.tmp``,
    skipped by readers and backups, an orphan to `verify`), except raw files
    staged before their hash is known (`stage_raw`), which wait in ``objects/``.
    Its fsync starts at once on a background I/O thread, so the disk writes one
    file while the caller prepares the next one (or parses and solves the run)
    instead of waiting for each in turn. `commit` waits for those fsyncs, renames
    every file to its target (atomic) and fsyncs each folder that got a new
    entry: on return the files are durable under their names, ready for database
    rows to refer to them. `close` (also on leaving a ``with`` block) deletes
    whatever was not committed. Not thread-safe: one owner.
    """

    def __init__(self) -> None:
        self._pending: dict[Path, _Pending] = {}  # target -> its temporary file
        self._dirs: set[Path] = set()  # folders to fsync at the commit
        self._io: ThreadPoolExecutor | None = None
        self._loose: set[Path] = set()  # `temp_file`s not yet queued

    def __enter__(self) -> PendingFiles:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __contains__(self, target: Path) -> bool:
        return Path(target) in self._pending

    def _temp(self, folder: Path, name: str) -> tuple[int, Path]:
        self._dirs |= _make_dirs(folder)
        # The writer's host and process in the name: `remove_stale_temp_files` can tell
        # a file a live writer still needs from one a killed writer left behind.
        prefix = f".{name}.{_WRITER}."
        return _mkstemp(folder, prefix, TEMP_SUFFIX)

    def _queue(self, fd: int, tmp: Path, target: Path, *, keep_existing: bool = False) -> None:
        """Queue `tmp`, written through `fd` (closed here, after its fsync), for `target`."""
        try:
            if self._io is None:
                self._io = ThreadPoolExecutor(max_workers=1, thread_name_prefix="calib-fsync")
            synced = self._io.submit(_fsync_close, fd)
        except BaseException:
            os.close(fd)
            tmp.unlink(missing_ok=True)
            raise
        _discard(self._pending.pop(target, None))
        self._pending[target] = _Pending(tmp, keep_existing, synced)

    def _write(self, target: Path, write: Callable[[int], None]) -> None:
        """A temporary file for `target`, filled by ``write(fd)``, then queued."""
        target = Path(target)
        fd, tmp = self._temp(target.parent, target.name)
        try:
            write(fd)
        except BaseException as exc:
            os.close(fd)
            tmp.unlink(missing_ok=True)
            if isinstance(exc, OSError):
                raise with_path(exc, target) from None
            raise
        self._queue(fd, tmp, target)

    def write_bytes(self, target: Path, data: bytes | pa.Buffer) -> None:
        """Queue `data` as the content of `target`."""

        self._write(target, lambda fd: write_all(fd, data))

    def copy(self, src: Path, target: Path, expected_sha256: str | None = None) -> tuple[str, int]:
        """Queue a copy of `src` for `target`, hashed on the way; return (sha256, size).

        With `expected_sha256`, a mismatch queues nothing and raises ValueError naming the file.
        """
        result: list[tuple[str, int]] = []

        def write(fd: int) -> None:
            result.append(copy_hashing(src, fd))
            _check_hash(src, result[0][0], expected_sha256)

        self._write(target, write)
        return result[0]

    def stage_raw(self, root: Path, src: Path) -> tuple[str, int]:
        """Copy a raw file towards the object store while hashing it; return (sha256, size).

        The one read and hash of the file at ingest: the copy is the bytes that
        hashed to the returned digest, and `commit` moves it to its content
        address (`object_path`), so `store_raw` with this `PendingFiles` has
        nothing left to read or verify. Nothing is kept when the object is
        already stored.
        """
        objects = Path(root) / "objects"
        fd, tmp = self._temp(objects, "incoming")
        try:
            sha, n = copy_hashing(Path(src), fd)
            target = object_path(root, sha)
            stored = target.exists() or target in self  # stored (or staged) already
            if not stored:
                self._dirs |= _make_dirs(target.parent)
        except BaseException as exc:
            os.close(fd)
            tmp.unlink(missing_ok=True)
            if isinstance(exc, OSError) and exc.filename is None:  # ENOSPC from write()
                raise with_path(exc, tmp.parent) from None
            raise
        if stored:
            os.close(fd)
            tmp.unlink(missing_ok=True)
        else:
            self._queue(fd, tmp, target, keep_existing=True)
        return sha, n

    def temp_file(self, folder: Path, name: str) -> Path:
        """A new empty temporary file in `folder` for the caller to fill (a streamed
        record's raw copy or samples, written before their target is known); deleted by
        `close` unless queued by `adopt` or `adopt_raw`."""
        fd, tmp = self._temp(Path(folder), name)
        os.close(fd)
        self._loose.add(tmp)
        return tmp

    def adopt(self, tmp: Path, target: Path) -> None:
        """Queue a filled `temp_file` for `target` (same file system: renamed at `commit`)."""
        self._loose.discard(tmp)
        self._dirs |= _make_dirs(Path(target).parent)
        self._queue(os.open(tmp, os.O_RDONLY), tmp, Path(target))

    def adopt_raw(self, root: Path, tmp: Path, sha256: str) -> None:
        """Queue a filled `temp_file` in ``objects/`` holding a raw file's bytes that hashed
        to `sha256` for its content address (`stage_raw` for a copy made while streaming)."""
        target = object_path(root, sha256)
        if target.exists() or target in self:
            self._loose.discard(tmp)
            tmp.unlink(missing_ok=True)
            return
        self._loose.discard(tmp)
        self._dirs |= _make_dirs(target.parent)
        self._queue(os.open(tmp, os.O_RDONLY), tmp, target, keep_existing=True)

    def commit(self) -> None:
        """Make every queued file durable under its target name (see the class docstring).

        Raises the OSError of a failed write or fsync; the files not yet renamed
        stay queued (and are deleted by `close`).
        """
        for item in self._pending.values():
            try:
                item.synced.result()
            except OSError as exc:  # a full disk often shows only at fsync
                raise with_path(exc, item.tmp) from None
        for target, item in list(self._pending.items()):
            if item.keep_existing and target.exists():
                item.tmp.unlink(missing_ok=True)  # stored meanwhile: the same bytes
            else:
                os.replace(item.tmp, target)
                self._dirs.add(target.parent)
            del self._pending[target]
        for folder in sorted(self._dirs):
            _fsync_dir(folder)
        self._dirs.clear()

    def close(self) -> None:
        """Delete the temporary files not committed; stop the I/O thread."""
        for item in self._pending.values():
            _discard(item)
        self._pending.clear()
        for tmp in self._loose:
            tmp.unlink(missing_ok=True)
        self._loose.clear()
        self._dirs.clear()
        if self._io is not None:
            self._io.shutdown(wait=True)
            self._io = None


def _discard(item: _Pending | None) -> None:
    if item is None:
        return
    # Wait until its descriptor is closed; a failed fsync of a file thrown away does not matter.
    with contextlib.suppress(Exception):
        item.synced.result()
    item.tmp.unlink(missing_ok=True)


def store_raw(root: Path, src: Path, sha256: str, pending: PendingFiles | None = None) -> Path:
    """Copy a raw file into the content-addressed store; return the stored path.

    The hash is verified while copying: if the bytes of `src` do not hash to
    `sha256` nothing is stored and ValueError names the file. An object that is
    already present (or staged in `pending` by `PendingFiles.stage_raw`) is not
    written again. With `pending`, the copy is queued there (stored at its commit).
    """
    dest = object_path(root, sha256)
    if dest.exists() or (pending is not None and dest in pending):
        return dest
    if pending is None:
        copy_atomic(src, dest, sha256)
    else:
        pending.copy(src, dest, sha256)
    return dest


def _day(d: dt.date) -> str:
    if not isinstance(d, dt.date):
        raise TypeError(f"run date: expected a date or datetime, got {type(d).__name__}")
    return d.strftime("%Y-%m-%d")


def run_dir(root: Path, serial: str, date: dt.date, run_id: str) -> Path:
    """The folder of one run: root/runs/<serial>/<YYYY-MM-DD>/<run_id> (not created)."""
    check_safe_name(serial, "serial")
    check_safe_name(run_id, "run id")
    return Path(root) / "runs" / serial / _day(date) / run_id


def samples_path(root: Path, serial: str, date: dt.date, run_id: str) -> Path:
    """Parquet file of one run's samples: root/samples/serial=<s>/date=<d>/<run_id>.parquet."""
    check_safe_name(serial, "serial")
    check_safe_name(run_id, "run id")
    return Path(root) / "samples" / f"serial={serial}" / f"date={_day(date)}" / f"{run_id}.parquet"


@dataclass(frozen=True)
class SamplesFile:
    """A run's samples already written as Parquet (`samples_parquet_options`) in a
    `PendingFiles.temp_file` under the samples folder: a record streamed in chunks,
    archived by renaming rather than writing a table."""

    path: Path
    sha256: str


def write_samples(
    pending: PendingFiles, root: Path, serial: str, date: dt.date, run_id: str, table: pa.Table
) -> tuple[Path, str]:
    """Queue one run's samples as zstd Parquet in `pending`; return (path, sha256 of the file).

    Integer columns (timestamps as int64 ns) use DELTA_BINARY_PACKED, which
    stores a steady sample clock in a few bits per row; floating-point columns
    use BYTE_STREAM_SPLIT (noisy samples have nearly as many distinct values as
    rows, so a dictionary would cost several times the write time for no smaller
    file); other columns (segment labels) are dictionary encoded. zstd at level -1,
    its fast mode: faster than the default level 1 for a file a few per cent larger;
    higher levels gain under one per cent. Partition columns must not be in `table`.
    """
    for col in ("serial", "date"):
        if col in table.column_names:
            raise ValueError(f"samples table: column {col!r} is the partition key, remove it")
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = samples_path(root, serial, date, run_id)
    # Written in memory first: the bytes are hashed there, not read back from the file.
    sink = pa.BufferOutputStream()
    try:
        pq.write_table(table, sink, **samples_parquet_options(table.schema))
    except (pa.ArrowNotImplementedError, pa.ArrowInvalid):
        # An older pyarrow without that encoding: plain zstd is still correct.
        sink = pa.BufferOutputStream()
        pq.write_table(table, sink, compression="zstd")
    data = sink.getvalue()
    pending.write_bytes(path, data)
    return path, hashlib.sha256(data).hexdigest()


def samples_parquet_options(schema: pa.Schema) -> dict:
    """The Parquet writer options of archived samples (`write_samples`; a streamed record's
    ``pq.ParquetWriter`` takes the same)."""
    import pyarrow as pa

    delta_cols = [
        f.name for f in schema if pa.types.is_int64(f.type) or pa.types.is_timestamp(f.type)
    ]
    split_cols = [f.name for f in schema if pa.types.is_floating(f.type)]
    return {
        "compression": "zstd",
        "compression_level": ZSTD_LEVEL,
        "use_dictionary": [c for c in schema.names if c not in delta_cols and c not in split_cols],
        "column_encoding": {
            **dict.fromkeys(delta_cols, "DELTA_BINARY_PACKED"),
            **dict.fromkeys(split_cols, "BYTE_STREAM_SPLIT"),
        },
    }


def read_samples(root: Path, serial: str | None = None) -> pa.Table:
    """All archived samples (or one serial's), with string columns `serial` and `date`."""
    import pyarrow as pa

    base = Path(root) / "samples"
    if serial is not None:
        check_safe_name(serial, "serial")
    if not base.is_dir():
        return pa.table({"serial": pa.array([], pa.string()), "date": pa.array([], pa.string())})
    import pyarrow.dataset as ds  # imports pandas (slow): only where samples are read

    dataset = ds.dataset(
        base,
        format="parquet",
        partitioning=ds.partitioning(
            pa.schema([("serial", pa.string()), ("date", pa.string())]), flavor="hive"
        ),
        exclude_invalid_files=False,
        ignore_prefixes=[".", "_"],  # skip temporary files of writes in progress
    )
    flt = None if serial is None else ds.field("serial") == serial
    return dataset.to_table(filter=flt)


def remove_tree(path: Path) -> None:
    """Remove a directory tree if it exists (cleanup after a failed archive attempt)."""
    shutil.rmtree(path, ignore_errors=True)


_TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.(?P<host>[^.]+)-(?P<pid>\d+)\.[^.]+\.tmp$")


def _writer_gone(path: Path, now: float) -> bool:
    """Whether the writer of a temporary file has ended (or the file is older than a day)."""
    try:
        age = now - path.stat().st_mtime
    except FileNotFoundError:
        return False
    m = _TEMP_NAME.match(path.name)
    host = socket.gethostname().replace(".", "_")
    if m is None or m["host"] != host:  # older naming, or another host's writer
        return age > STALE_TEMP_S
    try:
        os.kill(int(m["pid"]), 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # alive, another user's
        return False
    # Alive, or its pid taken by another process since: only a day-old file is let go.
    return age > STALE_TEMP_S


def stale_temp_files(root: Path) -> list[Path]:
    """Temporary files under objects/, samples/ and runs/ whose writer has ended.

    A writer killed before its commit (``kill -9``, a power cut) leaves its staged
    files (``objects/.incoming.*.tmp`` and ``.<name>.*.tmp`` beside targets); a
    failed run deletes its own. A file of a live writer on this host is never
    listed; one of another host only when older than `STALE_TEMP_S`.
    """
    now = time.time()
    found: list[Path] = []
    for top in ("objects", "samples", "runs"):
        base = Path(root) / top
        if base.is_dir():
            found += [
                p
                for p in sorted(base.rglob(f".*{TEMP_SUFFIX}"))
                if p.is_file() and _writer_gone(p, now)
            ]
    return found


def remove_stale_temp_files(root: Path) -> list[Path]:
    """Delete `stale_temp_files(root)`; return what was deleted."""
    removed = []
    for path in stale_temp_files(root):
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
            removed.append(path)
    return removed
