"""The archive's file store: raw bytes by content hash, run folders, Parquet samples.

Layout under the file store root::

    objects/ab/ab12...ef            raw file bytes, named by their SHA-256
    runs/<serial>/<YYYY-MM-DD>/<run_id>/   protocol and other per-run files
    samples/serial=<s>/date=<d>/<run_id>.parquet   IMU samples (hive partitions)

Every write goes to a temporary file in the destination directory and is then
renamed over the target (``os.replace`` is atomic on one file system), so a
crash leaves either the old state or the new file, never half a file.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import os
import shutil
import tempfile
from pathlib import Path

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from storage.naming import check_safe_name

_CHUNK = 1 << 20
# Hive partition columns are read as strings: inferred types would turn serial "0012" into 12.
SAMPLES_PARTITIONING = pa.schema([("serial", pa.string()), ("date", pa.string())])


def object_path(root: Path, sha256: str) -> Path:
    """Where the bytes with this SHA-256 (64 lowercase hex digits) live."""
    if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
        raise ValueError(f"invalid sha256 {sha256!r}: expected 64 lowercase hex digits")
    return Path(root) / "objects" / sha256[:2] / sha256


def hash_and_size(path: Path) -> tuple[str, int]:
    """(SHA-256 hex digest, size in bytes) of a file, read in 1 MiB chunks."""
    h, n = hashlib.sha256(), 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
            n += len(chunk)
    return h.hexdigest(), n


def sha256_file(path: Path) -> str:
    """SHA-256 hex digest of a file."""
    return hash_and_size(path)[0]


def _temp_beside(path: Path) -> tuple[int, Path]:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    return fd, Path(tmp)


def write_atomic(path: Path, data: bytes) -> None:
    """Write `data` to `path` atomically (temporary file in the same directory + rename)."""
    path = Path(path)
    fd, tmp = _temp_beside(path)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def copy_atomic(src: Path, dest: Path, expected_sha256: str | None = None) -> tuple[str, int]:
    """Copy `src` to `dest` through a temporary file beside it + rename, hashing on the way.

    Returns (sha256, size) of the bytes copied. With `expected_sha256`, a mismatch
    stores nothing and raises ValueError naming the file.
    """
    fd, tmp = _temp_beside(Path(dest))
    h, n = hashlib.sha256(), 0
    try:
        with open(src, "rb") as fin, os.fdopen(fd, "wb") as fout:
            while chunk := fin.read(_CHUNK):
                h.update(chunk)
                n += len(chunk)
                fout.write(chunk)
            fout.flush()
            os.fsync(fout.fileno())
        if expected_sha256 is not None and h.hexdigest() != expected_sha256:
            raise ValueError(
                f"raw file {src}: content hashes to {h.hexdigest()}, expected "
                f"{expected_sha256} (was the file changed after it was read?)"
            )
        os.replace(tmp, dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return h.hexdigest(), n


def store_raw(root: Path, src: Path, sha256: str) -> Path:
    """Copy a raw file into the content-addressed store; return the stored path.

    The hash is verified while copying: if the bytes of `src` do not hash to
    `sha256` nothing is stored and ValueError names the file. An object that is
    already present is not written again.
    """
    dest = object_path(root, sha256)
    if not dest.exists():
        copy_atomic(src, dest, sha256)
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


def store_samples(root: Path, serial: str, date: dt.date, run_id: str, table: pa.Table) -> Path:
    """Write one run's samples as zstd Parquet, atomically; return the path.

    Integer columns (timestamps as int64 ns) use DELTA_BINARY_PACKED, which
    stores a steady sample clock in a few bits per row; floating-point columns
    use BYTE_STREAM_SPLIT (noisy samples have nearly as many distinct values as
    rows, so a dictionary would cost ~5x the write time for no smaller file);
    other columns (segment labels) are dictionary encoded. Partition columns
    must not be in `table`.
    """
    for col in ("serial", "date"):
        if col in table.column_names:
            raise ValueError(f"samples table: column {col!r} is the partition key, remove it")
    path = samples_path(root, serial, date, run_id)
    delta_cols = [
        f.name for f in table.schema if pa.types.is_int64(f.type) or pa.types.is_timestamp(f.type)
    ]
    split_cols = [f.name for f in table.schema if pa.types.is_floating(f.type)]
    fd, tmp = _temp_beside(path)
    os.close(fd)
    try:
        try:
            pq.write_table(
                table,
                tmp,
                compression="zstd",
                use_dictionary=[
                    c for c in table.column_names if c not in delta_cols and c not in split_cols
                ],
                column_encoding={
                    **dict.fromkeys(delta_cols, "DELTA_BINARY_PACKED"),
                    **dict.fromkeys(split_cols, "BYTE_STREAM_SPLIT"),
                },
            )
        except (pa.ArrowNotImplementedError, pa.ArrowInvalid):
            # An older pyarrow without that encoding: plain zstd is still correct.
            pq.write_table(table, tmp, compression="zstd")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def read_samples(root: Path, serial: str | None = None) -> pa.Table:
    """All archived samples (or one serial's), with string columns `serial` and `date`."""
    base = Path(root) / "samples"
    if serial is not None:
        check_safe_name(serial, "serial")
    if not base.is_dir():
        return pa.table({"serial": pa.array([], pa.string()), "date": pa.array([], pa.string())})
    dataset = ds.dataset(
        base,
        format="parquet",
        partitioning=ds.partitioning(SAMPLES_PARTITIONING, flavor="hive"),
        exclude_invalid_files=False,
        ignore_prefixes=[".", "_"],  # skip temporary files of writes in progress
    )
    flt = None if serial is None else ds.field("serial") == serial
    return dataset.to_table(filter=flt)


def remove_tree(path: Path) -> None:
    """Remove a directory tree if it exists (cleanup after a failed archive attempt)."""
    shutil.rmtree(path, ignore_errors=True)
