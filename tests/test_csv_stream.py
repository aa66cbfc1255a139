"""A static record larger than the memory limit, streamed from CSV
(pipelines.ingest.csv_reader.stream_csv): the same parameters as the in-memory path, its
bytes hashed and copied in the same pass, its samples in Parquet, the resident memory it
adds bounded by the limit."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest

from calib_core.preprocess.motion import motion_check
from calib_core.solvers.static_bias import solve_static_bias
from calib_testing.streaming import assert_same_solve, streamed_memory_growth
from pipelines.ingest.csv_reader import read_csv, stream_csv
from pipelines.ingest.data_format import FormatSpec, format_dict
from pipelines.streamed_solve import phase_rows, solve_streamed

RATE = 100.0
LIMIT = 20 << 20  # bytes: the file is 2.5 times larger
SETTINGS = {"up_axis": "+z", "n_sigma": 3.0}
G = 9.80665


def write_static_csv(path: Path, n: int, seed: int = 0) -> None:
    """A still unit at RATE: white noise and a slow gyro random walk, accelerometer z up."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    gyr = rng.normal(0.0, 2e-3, (n, 3)) + [0.01, -0.02, 0.005]
    gyr += np.cumsum(rng.normal(0.0, 2e-6, (n, 3)), axis=0)
    acc = rng.normal(0.0, 0.02, (n, 3)) + [0.05, -0.03, G + 0.1]
    gyr[5000:5003, 1] += 0.5  # a spike: the outlier rule's fill is exercised
    cols = {
        "time": t,
        **{f"acc_{a}": acc[:, i] for i, a in enumerate("xyz")},
        **{f"gyr_{a}": gyr[:, i] for i, a in enumerate("xyz")},
    }
    pacsv.write_csv(pa.table(cols), path)


@pytest.fixture(scope="module")
def big_csv(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("long") / "static.csv"
    write_static_csv(path, 400_000)
    assert path.stat().st_size > 2 * LIMIT
    return path


FMT = FormatSpec(kind="csv")  # the columns by their recognised names (write_static_csv)


@pytest.mark.parametrize("solve_limit", [LIMIT, 2 << 20])
def test_streamed_record_same_parameters_as_in_memory(big_csv, tmp_path, solve_limit):
    """The solve with each channel's whole Allan phase in memory (the limit's half holds
    it), and with a limit whose half does not (its last rows, the long lags from phase
    files)."""
    streamed = stream_csv(
        big_csv,
        FMT,
        tmp_path / "samples.parquet",
        copy_to=tmp_path / "raw",
        memory_limit=LIMIT,
        progress=False,
    )
    data = big_csv.read_bytes()
    assert streamed.sha256 == hashlib.sha256(data).hexdigest()
    assert (tmp_path / "raw").read_bytes() == data
    rec = read_csv(big_csv, FMT, progress=False)
    table = pq.read_table(streamed.samples)
    assert table.num_rows == len(rec)
    assert np.array_equal(table.column("t").to_numpy(), rec.t)
    assert np.array_equal(table.column("gyr_y").to_numpy(), rec.gyr[:, 1])

    whole = phase_rows(solve_limit, len(rec)) > len(rec)
    assert whole is (solve_limit == LIMIT)
    got = solve_streamed(streamed, SETTINGS, gravity=G, memory_limit=solve_limit)
    ref = solve_static_bias(rec, gravity=G, **SETTINGS)
    assert_same_solve(got, ref)
    assert got.info["outliers"]["gyr"][1] >= 3
    # the motion check made on the stream is the in-memory one (the 3-sample spike is
    # more than a window's trim leaves out: it fails on both routes)
    (motion,) = [c for c in got.info["solver_checks"] if c["name"].startswith("motion:")]
    want = motion_check("record", rec)
    assert motion["passed"] is want["passed"] is False, (motion, want)
    assert motion["detail"] == want["detail"]  # the same window, channel and figures
    assert math.isclose(motion["value"], want["value"], rel_tol=1e-12)


@pytest.mark.slow  # a fresh interpreter reads the whole file twice
def test_streamed_record_memory_bounded_by_the_limit(big_csv, tmp_path):
    """In a fresh process, after a warm-up on the file's first quarter (which loads the
    lazily imported modules, the parser's threads and the codecs: fixed costs), the peak
    resident memory grows by less than the limit while the whole file, 2.5 times the
    limit, is read, hashed, copied, written and solved."""
    lines = big_csv.read_bytes().splitlines(keepends=True)
    quarter = tmp_path / "quarter.csv"
    quarter.write_bytes(b"".join(lines[: len(lines) // 4]))
    del lines
    grown = streamed_memory_growth(
        "pipelines.ingest.csv_reader:stream_csv",
        json.dumps(format_dict(FMT)),
        big_csv,
        quarter,
        tmp_path / "s.parquet",
        LIMIT,
        SETTINGS,
    )
    assert grown < LIMIT, grown / 2**20


def test_progress_line_names_bytes_samples_rate_and_time_left(tmp_path, capsys):
    path = tmp_path / "short.csv"
    write_static_csv(path, 2000)
    stream_csv(path, FMT, tmp_path / "s.parquet", memory_limit=1 << 20, progress=True)
    err = capsys.readouterr().err
    assert "reading short.csv" in err and "2,000 samples" in err
    assert "MB/s" in err and "s left" in err


def test_time_going_back_names_the_line(tmp_path):
    from pipelines.ingest.errors import IngestError

    path = tmp_path / "back.csv"
    write_static_csv(path, 50_000)
    lines = path.read_bytes().split(b"\n")
    lines[40_001], lines[40_002] = lines[40_002], lines[40_001]  # data rows 40000, 40001
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(IngestError, match="time must increase") as err:
        stream_csv(path, FMT, tmp_path / "s.parquet", memory_limit=1 << 20, progress=False)
    assert "line 40003" in str(err.value)


def test_value_no_imu_can_read_names_the_line(tmp_path):
    """A finite gyro reading of 1e30 rad/s is a damaged value, refused as in memory
    (run_loader: check_readings), naming the file and the line."""
    from pipelines.ingest.errors import IngestError

    path = tmp_path / "huge.csv"
    write_static_csv(path, 50_000)
    lines = path.read_bytes().split(b"\n")
    cells = lines[40_001].split(b",")  # data row 40000
    cells[5] = b"1e30"  # gyr_y
    lines[40_001] = b",".join(cells)
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(IngestError, match="gyr .* beyond what any IMU") as err:
        stream_csv(path, FMT, tmp_path / "s.parquet", memory_limit=1 << 20, progress=False)
    assert "line 40002" in str(err.value) and str(path) in str(err.value)
    assert err.value.field == "gyr_y"


def _fixed_width_lines(n: int) -> list[str]:
    """A counter (time at 100 Hz) and six channels in data lines of 64 bytes each: a 64 kB
    streamed block holds rows 0-1023 exactly, so does a 4 kB slice of 64 rows."""
    lines = [f"{k:09d},0.100000,0.200000,9.800000,0.010000,0.020000,0.030000" for k in range(n)]
    assert {len(line) for line in lines} == {63}
    return lines


@pytest.mark.parametrize(
    ("row", "edit", "field"),
    [(1024, ("000001024", "000001023"), "samples"), (1500, ("0.200000", ""), "ay")],
)
def test_a_refusal_is_the_same_on_both_routes(tmp_path, monkeypatch, row, edit, field):
    """One chunk loop: time that stops increasing at the first row of a block (streamed
    64 kB blocks and 4 kB in-memory slices both start at row 1024) and an empty cell are
    refused naming the same file, line and column in the same words on both routes."""
    from pipelines.ingest import csv_reader
    from pipelines.ingest.errors import IngestError

    lines = _fixed_width_lines(3000)
    lines[row] = lines[row].replace(*edit, 1)
    path = tmp_path / "fixed.csv"
    path.write_text("\n".join(["samples,ax,ay,az,gx,gy,gz", *lines]) + "\n")
    fmt = FormatSpec(
        kind="csv",
        time_column="samples",
        time_unit="samples",
        sample_rate_hz=RATE,
        acc_columns=["ax", "ay", "az"],
        gyr_columns=["gx", "gy", "gz"],
    )
    with pytest.raises(IngestError) as streamed:
        stream_csv(path, fmt, tmp_path / "s.parquet", memory_limit=1 << 20, progress=False)
    monkeypatch.setattr(csv_reader, "SLICE_BYTES", 4096)
    with pytest.raises(IngestError) as in_memory:
        read_csv(path, fmt, progress=False)
    assert str(streamed.value) == str(in_memory.value)
    assert (streamed.value.file, streamed.value.line) == (str(path), row + 2)
    assert streamed.value.field == field


def test_blocks_pass_every_byte_once_and_cut_at_line_ends():
    """Lines longer than a block, a last line without its newline: the blocks join to the
    file, each ends at a line end, and the hash and the copy are of the whole file."""
    import io

    from pipelines.ingest.csv_reader import blocks

    data = b"".join(b"x" * (i % 300) + b"\n" for i in range(5000)) + b"no newline"
    sha, copy = hashlib.sha256(), io.BytesIO()
    blocks = [bytes(b) for b in blocks(io.BytesIO(data), 100, copy, sha)]
    assert b"".join(blocks) == data
    assert all(b.endswith(b"\n") for b in blocks[:-1])
    assert copy.getvalue() == data and sha.hexdigest() == hashlib.sha256(data).hexdigest()
