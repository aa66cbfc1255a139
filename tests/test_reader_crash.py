"""Damaged binary files never take the process down: MAT v5, MAT v7.3 and MCAP readers.

Each reader gets 500 damaged copies of a small valid file (written by scipy,
hdf5storage and mcap-ros2-support): 8 zeroed bytes at a random offset (the
damage that made scipy's MAT v5 reader segfault), 1-8 random bytes, or a
cut. Every case runs in this pytest process: a segfault would end the test
run, so passing means 0 process deaths. Each case must either read the
original samples or raise IngestError naming the file. The cases are drawn
from a fixed seed (reproducible); how many of them crashed the isolated MAT
reader is printed (-s) and must be more than zero for MAT v5, or the test
could not tell isolation from luck.
(Property-based fuzzing of the readers' error messages lives in test_ingest_fuzz.py.)
"""

from __future__ import annotations

import functools
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType
from test_ingest_fuzz import write_valid
from test_ingest_mcap import write_run

from pipelines.ingest import discover_runs, load_run
from pipelines.ingest.errors import IngestError
from pipelines.ingest.matlab import read_mat
from pipelines.ingest.mcap_reader import read_mcap

pytestmark = pytest.mark.slow

CASES = 500
ROOT = Path(__file__).resolve().parents[1]
VARIABLES = {"t": "imu.t", "acc": "imu.acc", "gyr": "imu.gyr"}


@functools.cache
def valid(kind: str, folder: Path) -> bytes:
    path = folder / f"valid_{kind}.{'mcap' if kind == 'mcap' else 'mat'}"
    mcap = {"chunk_size": 2048, "compression": CompressionType.ZSTD, "enable_crcs": True}
    return write_valid(path, kind, **mcap).read_bytes()


def read(kind: str, path: Path):  # noqa: ANN201
    if kind == "mcap":
        return read_mcap(
            path, temperature_topic="/imu/temperature", table_topic="/table/joint_states"
        )
    return read_mat(path, variables=VARIABLES)


def damaged(data: bytes, rng: np.random.Generator) -> bytes:
    out = bytearray(data)
    kind = rng.integers(3)
    if kind == 0:  # 8 zeroed bytes, often on a 4-byte boundary as the MAT tags are
        pos = int(rng.integers(0, len(out) - 8))
        if rng.random() < 0.5:
            pos -= pos % 4
        out[pos : pos + 8] = bytes(8)
    elif kind == 1:
        for _ in range(int(rng.integers(1, 9))):
            out[int(rng.integers(len(out)))] = int(rng.integers(256))
    else:
        del out[int(rng.integers(len(out))) :]
    return bytes(out)


@pytest.mark.parametrize("kind", ["mat5", "mat73", "mcap"])
def test_damaged_files_fail_their_run_not_the_process(kind: str, tmp_path: Path) -> None:
    original = read(kind, _write(tmp_path / "orig", valid(kind, tmp_path)))
    rng = np.random.default_rng({"mat5": 5, "mat73": 73, "mcap": 11}[kind])
    read_ok = failed = crashed = 0
    for i in range(CASES):
        path = _write(tmp_path / f"case{i % 2}", damaged(valid(kind, tmp_path), rng))
        try:
            rec = read(kind, path)
        except IngestError as exc:
            assert str(path) in str(exc), f"case {i}: error without the file: {exc}"
            failed += 1
            crashed += "crashed on this file" in str(exc)
            continue
        read_ok += 1
        if kind == "mcap":  # chunk CRCs: any sample that survives is an original sample
            np.testing.assert_array_equal(rec.acc, original.acc[: len(rec)])
        assert np.isfinite(rec.acc).all() and np.all(np.diff(rec.t) > 0), f"case {i}"
    print(
        f"{kind}: {CASES} damaged files: {read_ok} read, {failed} IngestError "
        f"({crashed} of them crashed the isolated reader), 0 process deaths"
    )
    assert read_ok + failed == CASES
    if kind == "mat5":
        assert crashed > 0


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def test_mcap_chunk_crc_mismatch_names_the_chunk(tmp_path: Path) -> None:
    path = tmp_path / "crc.mcap"
    write_run(path, n=60, chunk_size=4096, compression=CompressionType.NONE)
    data = bytearray(path.read_bytes())
    # The first chunk (opcode 0x06) holds the messages uncompressed: change one sample byte.
    chunk = data.index(b"\x06", 8)
    data[chunk + 200] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(IngestError, match=rf"{path}: chunk at byte {chunk} fails its CRC check"):
        read(kind="mcap", path=path)


@pytest.mark.parametrize(("bad", "column"), [(b"\xff", 1), (b"\xc3\xa9\xe9", 2)])
def test_non_utf8_csv_names_file_line_and_column(tmp_path: Path, bad: bytes, column: int) -> None:
    """A latin-1 byte in the shipped CSV sample run: file, line and column, no traceback."""
    run = tmp_path / "run"
    shutil.copytree(ROOT / "data_samples" / "csv_IMU-2026-0042", run)
    csv = run / "imu.csv"
    lines = csv.read_bytes().split(b"\n")
    lines[930] = bad + lines[930]  # line 931 (1-based)
    csv.write_bytes(b"\n".join(lines))
    (source,) = discover_runs([run])
    with pytest.raises(IngestError) as info:
        load_run(source)
    assert (info.value.file, info.value.line) == (str(csv), 931)
    assert f"not UTF-8 text: byte 0x{bad[-1]:02x} at column {column}" in info.value.problem
