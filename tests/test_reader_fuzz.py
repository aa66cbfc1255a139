"""Fuzzing every reader, and the bad-sample policy.

Each reader gets 500 mutated inputs (hypothesis, derandomized, fixed
max_examples, no deadline, no database): valid small files written by
the test writers (MPU-6000 text by calib_testing.run_writers, CSV, PX4 ULog by
pyulog, DataFlash, ROS 1 and ROS 2 bags by rosbags) with bytes replaced by
characters that break parsers (separators, decimal marks, 'nan', 'inf', line
ends, NUL, non-ASCII) or arbitrary bytes, lines dropped or repeated, and the
file truncated. The reader must return a Recording whose samples are finite
with time increasing, or raise IngestError naming the file, and, for a
problem at one place, its line (text) or field (column, topic, message). Any
other exception fails the test, as would a hang.

Then a batch of mutated MPU-6000 runs is processed into a real SQLite archive
and every number the archive holds (every REAL column of every table, every
JSON and text file of the object store) is scanned for NaN and inf.
"""

from __future__ import annotations

import atexit
import functools
import json
import math
import os
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_writers import write_dataflash, write_rosbag1, write_rosbag2, write_ulog
from sqlalchemy import inspect as sa_inspect
from sqlalchemy import text

from calib_core.recording import Recording
from pipelines.ingest.csv_reader import read_csv
from pipelines.ingest.data_format import FormatSpec
from pipelines.ingest.dataflash_reader import read_dataflash
from pipelines.ingest.errors import IngestError
from pipelines.ingest.mpu6000 import read_mpu6000_file
from pipelines.ingest.rosbag_reader import read_rosbag
from pipelines.ingest.ulog_reader import read_ulog

pytestmark = pytest.mark.slow

EXAMPLES = 500
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=True,  # reproducible; a new seed is a code change
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
_WORKDIR = Path(tempfile.mkdtemp(prefix="fuzz_readers_"))
atexit.register(shutil.rmtree, _WORKDIR, ignore_errors=True)
N = 40
CSV_HEADER = "# meta\nt [s];ax [m/s^2];ay [m/s^2];az [m/s^2];gx;gy;gz;temp"
BREAKERS = [
    b"",
    b",",
    b";",
    b"\t",
    b" ",
    b"nan",
    b"inf",
    b"-",
    b"e",
    b"\r",
    b"\n",
    b"_",
    b"x",
    b"\x00",
    b"\xd0",
    b"\xe9",
    b"1e400",
    b"..",
    b"mean",
    b"std",
]
# Problems of a whole file (no one line or field to name).
WHOLE_FILE = re.compile(
    r"truncated|empty|not an? |NUL byte|no data|damaged|neither UTF-8"
    r"|no (topic|IMU|channel|\w+ column)|expected (one|topic)|missing|no header|header line"
    r"|two separate|cannot (read|parse|open)"
)
# A binary file's place: a byte offset, a message, record or sample index, a channel.
BINARY_PLACE = re.compile(r"(byte|offset|message|record|sample index) \d+|channel '[^']+'")


def segment() -> Recording:
    rng = np.random.default_rng(5)
    t = np.arange(N) / 50.0
    acc = rng.normal(0, 0.02, (N, 3)) + (0, 0, 9.81)
    return Recording(t=t, acc=acc, gyr=rng.normal(0, 0.01, (N, 3)), temp=np.full(N, 21.0))


@functools.cache
def valid_file(kind: str) -> Path:
    """One small valid file of `kind`, written once per session."""
    rec = segment()
    folder = _WORKDIR / f"valid_{kind}"
    folder.mkdir()
    if kind == "mpu6000":
        from calib_testing.run_writers import write_mpu6000_run

        return write_mpu6000_run({"x_up": rec.with_label("x_up")}, folder, "F1")[0]
    if kind == "csv":
        path = folder / "imu.csv"
        rows = np.column_stack([rec.t, rec.acc, rec.gyr, rec.temp])
        np.savetxt(path, rows, delimiter=";", fmt="%.6f", comments="", header=CSV_HEADER)
        return path
    path = folder / {"ulog": "a.ulg", "dataflash": "a.bin", "rosbag1": "a.bag"}.get(kind, "b")
    if kind == "ulog":
        write_ulog(path, rec, topics="both")
    elif kind == "dataflash":
        write_dataflash(path, rec, instances=2)
    elif kind == "rosbag1":
        write_rosbag1(path, rec)
    else:
        path = write_rosbag2(path, rec)
    return path


READERS = {
    "mpu6000": read_mpu6000_file,
    "csv": lambda p: read_csv(p, FormatSpec(kind="csv")),
    "ulog": read_ulog,
    "dataflash": read_dataflash,
    "rosbag1": read_rosbag,
    "rosbag2": read_rosbag,
}


def mutations(kind: str):
    """Up to 6 edits (a position and a breaker or a byte), a line dropped or doubled, a cut."""
    size = valid_file(kind).stat().st_size
    edit = st.tuples(
        st.integers(0, size - 1),
        st.one_of(st.sampled_from(BREAKERS), st.binary(min_size=1, max_size=2)),
    )
    return st.tuples(
        st.lists(edit, max_size=6),
        st.one_of(st.none(), st.tuples(st.integers(0, 2 * N), st.booleans())),
        st.one_of(st.none(), st.integers(0, size - 1)),
    )


def apply(kind: str, edits, line_op, cut) -> Path:
    data = valid_file(kind).read_bytes()
    for pos, value in sorted(edits, reverse=True):
        data = data[:pos] + value + data[pos + 1 :]
    if line_op is not None:
        lines = data.split(b"\n")
        i, double = line_op
        if i < len(lines):
            lines[i : i + 1] = [lines[i]] * 2 if double else []
        data = b"\n".join(lines)
    if cut is not None:
        data = data[:cut]
    path = _WORKDIR / f"case_{kind}" / valid_file(kind).name
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(data)
    return path


def assert_names_the_place(exc: IngestError, path: Path) -> None:
    """The error names the file, and the line or field unless the whole file is bad."""
    assert exc.file == str(path), str(exc)
    located = exc.line is not None or exc.field is not None or BINARY_PLACE.search(exc.problem)
    assert located or WHOLE_FILE.search(exc.problem), str(exc)
    assert len(exc.problem) >= 10, str(exc)  # says what was expected / found
    # bytes quoted from the damaged file reach no terminal or page as control characters
    assert str(exc).replace("\n", " ").replace("\t", " ").isprintable(), repr(str(exc))


def check(kind: str, case) -> None:
    path = apply(kind, *case)
    try:
        rec = READERS[kind](path)
    except IngestError as exc:
        assert_names_the_place(exc, path)
        return
    assert isinstance(rec, Recording) and len(rec) > 0
    assert np.isfinite(rec.acc).all() and np.isfinite(rec.gyr).all()
    assert np.isfinite(rec.t).all() and np.all(np.diff(rec.t) > 0)
    assert rec.temp is None or np.isfinite(rec.temp).all()


@pytest.mark.parametrize("kind", sorted(READERS))
def test_valid_file_reads(kind: str) -> None:
    assert len(READERS[kind](valid_file(kind))) == N


@pytest.mark.parametrize("kind", list(READERS))
@FUZZ
@given(data=st.data())
def test_mutations(kind: str, data: st.DataObject) -> None:
    check(kind, data.draw(mutations(kind), label="case"))


SAMPLE = Path(__file__).resolve().parents[1] / "data_samples" / "mpu6000_MPU0001"
NONFINITE = re.compile(rb"\b(nan|NaN|-?inf|-?Infinity)\b")


def test_no_nan_in_the_archive_after_a_fuzz_batch(tmp_path: Path) -> None:
    """40 copies of the sample run, each with one file damaged by the mutations above,
    processed into one SQLite archive: refused runs leave nothing, processed ones hold no
    NaN or inf in any REAL column or any JSON / text file of the object store."""
    from pipelines.ingest import discover_runs
    from pipelines.process import process_run
    from storage.db import resolve_archive

    rng = np.random.default_rng(17)
    archive = resolve_archive(str(tmp_path / "archive"))
    archive.upgrade()
    statuses = []
    try:
        for k in range(40):
            folder = tmp_path / f"run{k}"
            shutil.copytree(SAMPLE, folder)
            for f in folder.iterdir():
                os.utime(f, (1.7e9 + k * 86400, 1.7e9 + k * 86400))  # distinct start times
            victim = sorted(folder.glob("*.txt"))[int(rng.integers(12))]
            data = bytearray(victim.read_bytes())
            for _ in range(int(rng.integers(1, 4))):
                pos = int(rng.integers(len(data)))
                data[pos : pos + 1] = BREAKERS[int(rng.integers(len(BREAKERS)))]
            victim.write_bytes(bytes(data))
            (source,) = discover_runs([folder])
            statuses.append(process_run(source, archive)["status"])
        assert "failed" in statuses and "ok" in statuses, statuses  # both kinds exercised
        with archive.engine().connect() as conn:
            for table in sa_inspect(conn).get_table_names():
                for row in conn.execute(text(f'SELECT * FROM "{table}"')):
                    for value in row:
                        assert not (isinstance(value, float) and not math.isfinite(value)), table
                        if isinstance(value, str) and value[:1] in "{[":
                            assert not NONFINITE.search(value.encode()), (table, value[:200])
    finally:
        archive.dispose()
    for path in (tmp_path / "archive").rglob("*"):
        if path.is_file() and path.suffix in (".json", ".txt", ".html", ".toml"):
            assert not NONFINITE.search(path.read_bytes()), path
    json.dumps(statuses)
