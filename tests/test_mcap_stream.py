"""A ROS 2 IMU record larger than the memory limit, streamed from MCAP
(pipelines.ingest.mcap_reader.stream_mcap): the in-memory reader's samples and time base, the same
static-bias parameters, its bytes hashed and copied in the same pass, and the in-memory
reader's errors (same text, messages numbered in the whole topic).

Files are written with mcap-ros2-support's Writer (`test_ingest_mcap.write_run`)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.writer import CompressionType
from test_ingest_mcap import T0_NS, rewrite, write_run

from calib_core.solvers.static_bias import solve_static_bias
from calib_testing.streaming import assert_same_samples, assert_same_solve, streamed_memory_growth
from calib_testing.streaming import same_error as streamed_same_error
from pipelines.ingest.data_format import FormatSpec, format_spec
from pipelines.ingest.errors import IngestError
from pipelines.ingest.mcap_reader import read_mcap, stream_mcap
from pipelines.streamed_solve import solve_streamed

LIMIT = 1 << 20  # bytes: 1024 messages a batch; the files are several times larger
N = 20_000
G = 9.80665
SETTINGS = {"up_axis": "+z", "n_sigma": 3.0}


def fmt(**keys) -> FormatSpec:
    return format_spec({"kind": "mcap", **keys})


def static_acc(n: int, seed: int = 1) -> np.ndarray:
    """A still unit, z up; a spike exercises the outlier rule's fill."""
    acc = np.random.default_rng(seed).normal(0.0, 0.02, (n, 3)) + [0.05, -0.03, G + 0.1]
    acc[5000:5003, 0] += 1.0
    return acc


@pytest.fixture(scope="module")
def big_mcap(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("mcap") / "static.mcap"
    write_run(path, n=N, acc=static_acc(N), compression=CompressionType.NONE)
    assert path.stat().st_size > 4 * LIMIT
    return path


def stream(path: Path, out: Path, **keys):
    return stream_mcap(
        path,
        fmt(**keys),
        out / "samples.parquet",
        copy_to=out / "raw",
        memory_limit=LIMIT,
        progress=False,
    )


def test_streamed_mcap_same_samples_and_parameters_as_in_memory(big_mcap, tmp_path):
    streamed = stream(big_mcap, tmp_path)
    data = big_mcap.read_bytes()
    assert streamed.sha256 == hashlib.sha256(data).hexdigest()
    assert streamed.size == len(data)
    assert (tmp_path / "raw").read_bytes() == data
    rec = read_mcap(big_mcap)
    table = pq.read_table(streamed.samples)
    assert table.num_rows == len(rec) == N
    assert pq.ParquetFile(streamed.samples).metadata.num_row_groups > 4  # written in batches
    # Bit for bit: the same decoder and the same time base (Unix s from integer offsets).
    assert_same_samples(table, rec)
    assert set(table.column("segment").to_pylist()) == {"record"}
    assert streamed.first.n == N
    assert streamed.first.step.median() == np.median(np.diff(rec.t))
    # chunked moments against one pass: rounding only, within the error bound of pairwise
    # sums (eps log2 N of the largest value) for both, four times
    both = np.hstack([rec.gyr, rec.acc])
    bound = 4 * np.finfo(float).eps * np.log2(N) * np.abs(both).max(axis=0)
    assert (np.abs(streamed.first.moments.mean - both.mean(axis=0)) <= bound).all()
    np.testing.assert_allclose(streamed.first.moments.std(), both.std(axis=0), rtol=1e-9)

    got = solve_streamed(streamed, SETTINGS, gravity=G, memory_limit=LIMIT)
    ref = solve_static_bias(rec, gravity=G, **SETTINGS)
    assert_same_solve(got, ref)
    assert got.info["outliers"]["acc"][0] >= 3


@pytest.mark.parametrize("chunking", [True, False])
def test_log_time_and_unchunked_file_as_in_memory(tmp_path, chunking):
    src = tmp_path / "run.mcap"
    write_run(src, n=3000, compression=CompressionType.ZSTD)
    path = tmp_path / "plain.mcap"
    rewrite(src, path, chunking=chunking)  # unchunked: every message a record of the file
    streamed = stream(path, tmp_path, stamp="log")
    rec = read_mcap(path, stamp="log")
    table = pq.read_table(streamed.samples)
    assert np.array_equal(table.column("t").to_numpy(), rec.t)
    assert np.array_equal(table.column("gyr_z").to_numpy(), rec.gyr[:, 2])
    assert streamed.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    assert (tmp_path / "raw").read_bytes() == path.read_bytes()


def same_error(path: Path, tmp_path: Path, **keys) -> str:
    """The streamed route's error is the in-memory reader's, word for word."""
    return streamed_same_error(read_mcap, stream, path, tmp_path, **keys)


def test_truncated_file_names_the_file(big_mcap, tmp_path):
    data = big_mcap.read_bytes()
    for cut in (40, len(data) - 3):
        bad = tmp_path / f"cut{cut}.mcap"
        bad.write_bytes(data[:cut])
        message = same_error(bad, tmp_path)
        assert "truncated" in message or "damaged" in message or "topic" in message
    # Cut in its data: read into memory to its last whole record with the finding; the
    # streamed route, which carries no findings, refuses it naming the bytes dropped.
    bad = tmp_path / "cut_half.mcap"
    bad.write_bytes(data[: len(data) // 2])
    (finding,) = read_mcap(bad).findings
    with pytest.raises(IngestError) as err:
        stream(bad, tmp_path)
    assert err.value.file == str(bad) and finding["detail"] in str(err.value)


def test_time_going_back_and_non_finite_numbered_in_the_whole_topic(tmp_path):
    n = 5000  # several batches: the message index counts across them
    stamps = T0_NS + 10_000_000 * np.arange(n, dtype=np.int64)
    stamps[3500] = stamps[3400]
    path = tmp_path / "back.mcap"
    write_run(path, n=n, stamps_ns=stamps)
    assert "at message 3500 " in same_error(path, tmp_path)
    good = tmp_path / "good.mcap"
    write_run(good, n=n)
    first = pq.ParquetFile(stream(good, tmp_path).samples).metadata.row_group(0).num_rows
    assert first < n
    stamps[first] = stamps[first - 1]  # the first message of the second batch
    write_run(path, n=n, stamps_ns=stamps)
    assert f"at message {first} " in same_error(path, tmp_path)
    acc = np.random.default_rng(0).normal(size=(n, 3))
    acc[4321, 2] = np.nan
    path = tmp_path / "nan.mcap"
    write_run(path, n=n, acc=acc)
    assert "in message 4321 " in same_error(path, tmp_path)


def test_value_no_imu_can_read_is_refused_naming_the_message(tmp_path):
    """A finite reading beyond any IMU's range (a damaged value: 1e30 m/s^2) is refused as
    the in-memory route refuses it (run_loader: check_readings), numbered in the whole topic
    across batches."""
    n = 5000
    acc = np.random.default_rng(0).normal(size=(n, 3))
    acc[4321, 1] = 1e30
    path = tmp_path / "huge.mcap"
    write_run(path, n=n, acc=acc)
    with pytest.raises(IngestError, match=r"message 4321 \(0-based\): acc .* beyond what any IMU"):
        stream(path, tmp_path)


def test_topic_choice_as_in_memory(tmp_path):
    path = tmp_path / "two.mcap"
    write_run(path, n=30, imu_topics=("/imu_a", "/imu_b"))
    assert "several sensor_msgs/msg/Imu topics" in same_error(path, tmp_path)
    assert "'/nope' not found" in same_error(path, tmp_path, imu_topic="/nope")
    streamed = stream(path, tmp_path, imu_topic="/imu_b")
    rec = read_mcap(path, imu_topic="/imu_b")
    assert np.array_equal(pq.read_table(streamed.samples).column("acc_y").to_numpy(), rec.acc[:, 1])


def test_temperature_topic_is_refused_with_the_reason(tmp_path):
    path = tmp_path / "run.mcap"
    write_run(path, n=100, temperature=True)
    with pytest.raises(IngestError, match="read in chunks gives its IMU topic only") as err:
        stream(path, tmp_path, temperature_topic="/imu/temperature")
    assert err.value.field == "format.temperature_topic" and str(path) in str(err.value)


def test_chunk_larger_than_the_limit_allows_is_refused(big_mcap, tmp_path):
    """The writer's 16 kB chunks against a 32 kB limit (a quarter for a chunk): refused
    before decompressing, naming the chunk, rather than read past the limit."""
    with pytest.raises(IngestError, match=r"chunk at byte \d+ holds \d+ bytes uncompressed"):
        stream_mcap(big_mcap, fmt(), tmp_path / "s.parquet", memory_limit=32 << 10)


@pytest.mark.slow  # writes a 150 MB log, streams it in a fresh interpreter
def test_streamed_mcap_memory_bounded_by_the_limit(tmp_path):
    """In a fresh process, after a warm-up on a log a quarter as long (which loads the
    lazily imported modules, the worker threads and the codecs: fixed costs), the peak
    resident memory grows by less than the limit while the whole log, twelve times the
    limit, is read, hashed, copied, written and solved (its samples alone, held in
    memory, would be twice the limit)."""
    limit = 12 << 20
    n = 400_000  # 148 MB of log; its samples alone (t and six channels) take 22 MB
    big, small = tmp_path / "big.mcap", tmp_path / "small.mcap"
    write_run(big, n=n, acc=static_acc(n), compression=CompressionType.NONE)
    write_run(small, n=n // 4, acc=static_acc(n // 4), compression=CompressionType.NONE)
    assert big.stat().st_size > 10 * limit
    grown = streamed_memory_growth(
        "pipelines.ingest.mcap_reader:stream_mcap",
        "mcap",
        big,
        small,
        tmp_path / "s.parquet",
        limit,
        SETTINGS,
    )
    assert grown < limit, grown / 2**20
