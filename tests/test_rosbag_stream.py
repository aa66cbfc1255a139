"""A ROS 1 bag read by its one reader (pipelines.ingest.ros1_bag): in memory, the values
rosbags' own reader decodes; a record larger than the memory limit streamed from its bag
(pipelines.ingest.rosbag_reader.stream_rosbag): the in-memory reader's samples and time
base bit for bit, the same parameters through `calib process`, its bytes hashed and
copied in the same pass, memory bounded by the limit, and the in-memory reader's refusals.

Bags are written by rosbags' ROS 1 Writer with the ROS 1 Noetic message definitions
(`log_writers._ros_messages`, the messages of tests/test_ingest_logs_e2e.py)."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from log_writers import T0_NS, _ros_messages, write_rosbag1, write_rosbag2
from test_process_streamed import (
    RATE,
    assert_streamed_as_in_memory,
    calib_process,
    manifest,
    write_profile,
)

from calib_core.recording import Recording
from calib_testing.calib_command import run_calib
from calib_testing.run_writers import dumps_toml
from calib_testing.streaming import assert_same_samples, streamed_memory_growth
from calib_testing.streaming import same_error as streamed_same_error
from pipelines.ingest.data_format import format_spec
from pipelines.ingest.errors import IngestError
from pipelines.ingest.rosbag_reader import read_rosbag, stream_rosbag
from pipelines.ingest.streaming import STREAMERS
from storage.db import resolve_archive
from storage.verify import verify

G = 9.80665
LIMIT = 5 << 20  # bytes: a quarter holds rosbags' 1 MiB chunks
TOPIC = "/imu/data"
IMU = "sensor_msgs/msg/Imu"


def static_record(n: int, seed: int = 5, temp: bool = False) -> Recording:
    """A still unit, z up: white noise, a gyro random walk, a spike on one gyro axis."""
    rng = np.random.default_rng(seed)
    gyr = rng.normal(0.0, 5e-4, (n, 3)) + [0.01, -0.02, 0.005]
    gyr += np.cumsum(rng.normal(0.0, 2e-6, (n, 3)), axis=0)
    acc = rng.normal(0.0, 0.02, (n, 3)) + [0.05, -0.03, G + 0.1]
    gyr[min(5000, n // 2) : min(5000, n // 2) + 2, 1] += 0.5
    t = np.arange(n) / RATE
    return Recording(t=t, acc=acc, gyr=gyr, temp=np.full(n, 25.0) if temp else None)


def write_bag(path: Path, rec: Recording, **options) -> Path:
    """`rec` as a ROS 1 bag (`log_writers.write_rosbag1`), each message logged 0.25 ms after
    its header stamp; `options` as write_rosbag1's."""
    return write_rosbag1(path, rec, log_delay_ns=250_000, **options)


def stream(path: Path, out: Path, limit: int = LIMIT, **keys):
    return stream_rosbag(
        path,
        format_spec({"kind": "rosbag", **keys}),
        out / "samples.parquet",
        copy_to=out / "raw",
        memory_limit=limit,
        progress=False,
    )


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    """80 000 messages, 30 MB: six times `LIMIT`."""
    path = write_bag(tmp_path_factory.mktemp("bag") / "imu.bag", static_record(80_000))
    assert path.stat().st_size > 5 * LIMIT
    return path


def test_registered_for_the_rosbag_kind():
    assert STREAMERS["rosbag"] is stream_rosbag


@pytest.mark.parametrize("stamp", ["header", pytest.param("log", marks=pytest.mark.slow)])
def test_same_samples_as_in_memory_hashed_and_copied(bag, tmp_path, stamp):
    streamed = stream(bag, tmp_path, stamp=stamp)
    data = bag.read_bytes()
    assert streamed.sha256 == hashlib.sha256(data).hexdigest() and streamed.size == len(data)
    assert (tmp_path / "raw").read_bytes() == data
    rec = read_rosbag(bag, stamp=stamp)
    table = pq.read_table(streamed.samples)
    assert table.num_rows == len(rec) == streamed.first.n
    assert pq.ParquetFile(streamed.samples).metadata.num_row_groups > 4  # written in batches
    # Bit for bit: the same values and the same time base (Unix s from integer offsets).
    assert_same_samples(table, rec)
    assert streamed.first.step.median() == np.median(np.diff(rec.t))


def test_read_as_rosbags_own_reader_decodes_it(tmp_path):
    """The chunk walker's IMU samples and interpolated temperature are those of rosbags'
    Reader (its index, its deserialiser), message by message: lz4 chunks, two Imu topics."""
    from rosbags.rosbag1 import Reader
    from rosbags.typesys import Stores, get_typestore

    path = write_bag(
        tmp_path / "o.bag", static_record(3000, temp=True), compression="LZ4", slow_every=7
    )
    rec = read_rosbag(path, imu_topic="/imu/slow", min_rate_hz=1.0)
    store = get_typestore(Stores.ROS1_NOETIC)
    with Reader(path) as reader:
        decoded = {
            topic: [
                store.deserialize_ros1(raw, c.msgtype)
                for c, _, raw in reader.messages(
                    [c for c in reader.connections if c.topic == topic]
                )
            ]
            for topic in ("/imu/slow", "/imu/temperature")
        }
    imu, temps = decoded["/imu/slow"], decoded["/imu/temperature"]
    ns = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in imu])
    assert len(rec) == len(imu) == 3000 // 7 + 1
    assert np.array_equal(rec.t, ns[0] / 1e9 + (ns - ns[0]) / 1e9)
    for key, field in (("acc", "linear_acceleration"), ("gyr", "angular_velocity")):
        want = [[getattr(getattr(m, field), a) for a in "xyz"] for m in imu]
        assert np.array_equal(getattr(rec, key), want)
    ts = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in temps])
    want = np.interp(ns - ns[0], ts - ns[0], [m.temperature for m in temps])
    assert len(temps) > 10 and np.array_equal(rec.temp, want)


def test_an_imu_of_another_definition_decoded_message_by_message(tmp_path):
    """A bag whose Imu definition is not sensor_msgs/Imu's (here: no orientation, the
    acceleration first; another md5) is decoded by rosbags with the bag's own definition,
    in memory and streamed alike: the values written, not the fixed layout's offsets."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    for text, name in (
        ("uint32 seq\ntime stamp\nstring frame_id\n", "std_msgs/msg/Header"),
        ("float64 x\nfloat64 y\nfloat64 z\n", "geometry_msgs/msg/Vector3"),
        (
            "std_msgs/Header header\ngeometry_msgs/Vector3 linear_acceleration\n"
            "geometry_msgs/Vector3 angular_velocity\n",
            IMU,
        ),
    ):
        store.register(get_types_from_msg(text, name))
    rec = static_record(3000)
    types = store.types
    path = tmp_path / "own.bag"
    with Writer(path) as writer:
        conn = writer.add_connection(TOPIC, IMU, typestore=store)
        for i in range(len(rec)):
            ns = T0_NS + i * 10_000_000
            stamp = types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            a, w = (types["geometry_msgs/msg/Vector3"](*v) for v in (rec.acc[i], rec.gyr[i]))
            msg = types[IMU](types["std_msgs/msg/Header"](i, stamp, "imu"), a, w)
            writer.write(conn, ns, store.serialize_ros1(msg, IMU))
    got = read_rosbag(path)
    assert np.array_equal(got.acc, rec.acc) and np.array_equal(got.gyr, rec.gyr)
    table = pq.read_table(stream(path, tmp_path).samples)
    assert_same_samples(table, got)


@pytest.mark.parametrize("compression", ["lz4", "bz2"])
def test_compressed_chunks_and_several_imu_topics_named(tmp_path, compression):
    path = write_bag(
        tmp_path / "c.bag", static_record(3000), compression=compression.upper(), slow_every=7
    )
    for topic in ("/imu/data", "/imu/slow"):
        streamed = stream(path, tmp_path, imu_topic=topic, min_rate_hz=1.0)
        rec = read_rosbag(path, imu_topic=topic, min_rate_hz=1.0)
        table = pq.read_table(streamed.samples)
        assert np.array_equal(table.column("t").to_numpy(), rec.t)
        assert np.array_equal(table.column("acc_x").to_numpy(), rec.acc[:, 0])
        assert streamed.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()


def test_record_headers_in_rosbag_cpp_order(tmp_path):
    """`rosbag record` (C++) writes a message record's header fields sorted by name (conn,
    op, time; rosbags writes op first): the same sizes, so the bag is rewritten in place,
    and read as the in-memory reader reads it."""
    path = write_bag(tmp_path / "py.bag", static_record(4000))
    op = b"\x04\x00\x00\x00op=\x02"
    conn = rb"(\x09\x00\x00\x00conn=.{4})"
    data, count = re.subn(
        re.escape(op) + conn, lambda m: m.group(1) + op, path.read_bytes(), flags=re.S
    )
    assert count == 4000
    cpp = tmp_path / "cpp.bag"
    cpp.write_bytes(data)
    streamed = stream(cpp, tmp_path)
    rec = read_rosbag(cpp)
    table = pq.read_table(streamed.samples)
    assert np.array_equal(table.column("t").to_numpy(), rec.t)
    assert np.array_equal(table.column("gyr_y").to_numpy(), rec.gyr[:, 1])


def same_error(path: Path, tmp_path: Path, **keys) -> str:
    """The streamed route's error is the in-memory reader's, word for word."""
    return streamed_same_error(read_rosbag, stream, path, tmp_path, **keys)


@pytest.mark.slow  # three 11 MB bags; fast: test_mcap_stream's twin, the refusals below
def test_time_going_back_and_damaged_values_numbered_in_the_whole_topic(tmp_path):
    """Errors past the first batch and chunk: the in-memory reader's text and record index."""
    n = 30_000  # 11 MB: ten chunks, several batches
    rec = static_record(n)
    stamps = T0_NS + 10_000_000 * np.arange(n, dtype=np.int64)
    stamps[21_000] = stamps[20_999]
    path = write_bag(tmp_path / "back.bag", rec, stamps=stamps)
    assert "record 21000 " in same_error(path, tmp_path)
    # log times stay in order; the values come from the message: 40 rad/s is a reading,
    # 1e4 rad/s is beyond any gyro (a damaged value)
    rec.gyr[25_432, 2] = 1e4
    path = write_bag(tmp_path / "big.bag", rec)
    assert "record 25432: gyr" in same_error(path, tmp_path)
    rec.gyr[25_432, 2] = 0.0
    rec.acc[17_777, 0] = np.nan
    path = write_bag(tmp_path / "nan.bag", rec)
    assert "record 17777: expected finite" in same_error(path, tmp_path)


def test_topic_choice_and_rate_as_in_memory(tmp_path):
    path = write_bag(tmp_path / "two.bag", static_record(300), slow_every=3)
    assert "'/nope'" in same_error(path, tmp_path, imu_topic="/nope")
    # /imu/slow at 33 Hz, below a 50 Hz minimum: refused with its rate
    message = same_error(path, tmp_path, imu_topic="/imu/slow", min_rate_hz=50.0)
    assert "33.33 Hz, below the 50 Hz" in message
    # none named: the fastest (rates from the index's log times), or every rate listed
    # when even the fastest is too slow
    streamed = stream(path, tmp_path)
    rec = read_rosbag(path)
    assert np.array_equal(pq.read_table(streamed.samples).column("acc_x").to_numpy(), rec.acc[:, 0])
    assert streamed.first.n == 300
    message = same_error(path, tmp_path, min_rate_hz=200.0)
    assert "/imu/data 100 Hz (300 samples); /imu/slow 33.33 Hz (100 samples)" in message


def test_what_the_route_does_not_take_is_refused_with_the_reason(tmp_path):
    path = write_bag(tmp_path / "temp.bag", static_record(300, temp=True))
    with pytest.raises(IngestError, match="temperature topic /imu/temperature") as err:
        stream(path, tmp_path)
    assert err.value.field == "format.temperature_topic" and str(path) in str(err.value)
    with pytest.raises(IngestError, match="table_topic"):
        stream(path, tmp_path, table_topic="/table")
    db3 = write_rosbag2(tmp_path / "ros2", static_record(300))
    with pytest.raises(IngestError, match="ROS 2 .db3 bag is read into memory only") as err:
        stream(db3, tmp_path)
    assert str(db3) in str(err.value)
    with pytest.raises(IngestError, match=r"chunk at byte \d+ holds \d+ bytes uncompressed"):
        stream(write_bag(tmp_path / "c.bag", static_record(5000)), tmp_path, limit=1 << 20)


def refused(bad: Path, raw: bytearray, match: str) -> IngestError:
    """The streamed route's refusal of the bag `raw` written to `bad`, naming the file."""
    bad.write_bytes(bytes(raw))
    with pytest.raises(IngestError, match=match) as err:
        stream(bad, bad.parent)
    assert str(bad) in str(err.value)
    return err.value


def test_truncated_unindexed_or_damaged_bag_names_the_file(bag, tmp_path):
    data = bag.read_bytes()
    for cut in (10, 2000, len(data) // 2, len(data) - 3):
        bad = tmp_path / f"cut{cut}.bag"
        bad.write_bytes(data[:cut])
        with pytest.raises(IngestError) as err:
            stream(bad, tmp_path)
        assert str(bad) in str(err.value)
        assert "truncated" in str(err.value) or "not a ROS bag" in str(err.value)
    # A recording that did not end cleanly: rosbag leaves index_pos 0 (`rosbag reindex`).
    raw = bytearray(data)
    at = raw.index(b"index_pos=") + len(b"index_pos=")
    raw[at : at + 8] = bytes(8)
    refused(tmp_path / "active.bag", raw, "not indexed")
    # The first chunk's data length damaged: refused before reading 4 GB into memory.
    raw = bytearray(data)
    at = raw.index(b"compression=none")
    at += len(b"compression=none") + 4 + len(b"size=") + 4  # after size, the data length
    assert raw[at - 9 : at - 4] == b"size="
    raw[at : at + 4] = (0xFFFFFFF0).to_bytes(4, "little")
    refused(tmp_path / "length.bag", raw, "declares 4294967280 bytes")
    # A byte of a message's header changed inside a chunk: the index disagrees.
    raw = bytearray(data)
    at = raw.index(b"time=", 10_000) + len(b"time=")
    raw[at] ^= 0xFF
    assert refused(tmp_path / "flipped.bag", raw, "does not match the index").field == TOPIC


def test_no_imu_topic_is_the_in_memory_error(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    rec = static_record(50, temp=True)
    path = tmp_path / "temp_only.bag"
    stamps = T0_NS + np.arange(50, dtype=np.int64) * 10_000_000
    with Writer(path) as writer:
        conn = None
        for topic, msgtype, ns, msg in _ros_messages(store, rec, stamps, None):
            if topic == "/imu/temperature":
                conn = conn or writer.add_connection(topic, msgtype, typestore=store)
                writer.write(conn, ns, store.serialize_ros1(msg, msgtype))
    assert "expected one sensor_msgs/msg/Imu topic, found 0" in same_error(path, tmp_path)


# --- through `calib process` -----------------------------------------------------------

PROCESS_N = 72_000  # 12 min at RATE: 27 MB of bag, five times a 5 MB limit
LIMIT_MB = 5


def write_run(folder: Path, data: Path, settings: dict) -> Path:
    """A static_bias run of the bag `data` (its Imu topic) with run settings `settings`."""
    folder.mkdir(parents=True)
    doc = manifest("2026-03-02T08:00:00+00:00", settings)
    doc["format"] = {"kind": "rosbag", "imu_topic": TOPIC}
    doc["segments"] = [{"label": "record", "file": data.name}]
    shutil.copyfile(data, folder / data.name)
    (folder / "run.toml").write_text(dumps_toml(doc), encoding="utf-8")
    return folder


@pytest.mark.slow  # a 27 MB bag processed twice; fast: the streamer above, test_process_streamed
def test_streamed_bag_run_matches_the_in_memory_run(tmp_path):
    """`calib process` of a ROS 1 bag larger than a 5 MB limit gives the in-memory run's
    parameters and checks to the rounding of chunked sums (test_process_streamed's bound
    for this N); the raw bag archived byte for byte; the archive verifies."""
    path = write_bag(tmp_path / "imu.bag", static_record(PROCESS_N))
    assert path.stat().st_size > 4 * LIMIT_MB * 10**6
    write_profile(tmp_path / "profiles", minutes=10.0)
    rel = 1e3 * PROCESS_N * np.finfo(float).eps
    runs = {}
    for route, settings in (("memory", {}), ("streamed", {"memory_limit_mb": LIMIT_MB})):
        archive = tmp_path / f"archive-{route}"
        runs[route], _ = calib_process(write_run(tmp_path / route, path, settings), archive)
        report = verify(resolve_archive(str(archive)))
        assert report.ok and report.orphans == [], (report.problems, report.orphans)
    assert_streamed_as_in_memory(tmp_path, runs, rel, LIMIT_MB, PROCESS_N, path)


@pytest.mark.slow  # four runs in calib process; fast: the refusals above, test_batch_survives
def test_bad_bags_fail_by_name_and_the_batch_goes_on(bag, tmp_path):
    """One `calib process` over four runs streamed: a truncated bag, a bag without the
    named Imu topic and a ROS 2 .db3 fail with an error naming their file; the good run
    is processed."""
    root = tmp_path / "runs"
    settings = {"memory_limit_mb": LIMIT_MB}
    good = write_run(root / "a_good", bag, settings)
    data = bag.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) * 2 // 3])
    write_run(root / "b_cut", cut, settings)
    notopic = write_run(root / "c_notopic", bag, settings)
    manifest_path = notopic / "run.toml"
    manifest_path.write_text(
        manifest_path.read_text(encoding="utf-8").replace(TOPIC, "/imu/missing"),
        encoding="utf-8",
    )
    db3 = write_rosbag2(tmp_path / "ros2", static_record(6000))
    write_run(root / "d_ros2", db3, {"memory_limit_mb": 1})
    assert db3.stat().st_size > 10**6
    write_profile(tmp_path / "profiles", minutes=10.0)
    env = {
        **os.environ,
        "CALIB_ARCHIVE": str(tmp_path / "archive"),
        "CALIB_ISSUE_CERTIFICATES": "0",
        "CALIB_PROFILES": str(tmp_path / "profiles"),
    }
    proc = run_calib("process", str(root), "--json", env=env)
    assert proc.stdout.startswith("{"), proc.stderr[-3000:]
    runs = {Path(r["source"]).name: r for r in json.loads(proc.stdout)["runs"]}
    assert runs["a_good"]["status"] == "ok", runs["a_good"]
    assert good.name in runs
    for name, file, said in (
        ("b_cut", "cut.bag", "truncated"),
        ("c_notopic", "imu.bag", "'/imu/missing'"),
        ("d_ros2", db3.name, "ROS 2 .db3 bag is read into memory only"),
    ):
        run = runs[name]
        assert run["status"] == "failed", run
        assert said in run["error"] and str(root / name / file) in run["error"], run
    assert verify(resolve_archive(str(tmp_path / "archive"))).ok


@pytest.mark.slow  # writes a 150 MB bag, streams it in a fresh interpreter
def test_streamed_bag_memory_bounded_by_the_limit(tmp_path):
    """In a fresh process, after a warm-up on a bag a quarter as long (lazily imported
    modules, worker threads: fixed costs), the peak resident memory grows by less than the
    limit while the whole bag, twelve times the limit, is read, hashed, copied, written
    and solved. rosbags' reader would hold its per-message index alone (about 170 bytes a
    message: 68 MB here) above the limit."""
    limit = 12 << 20
    n = 400_000  # 149 MB of bag
    big, small = tmp_path / "big.bag", tmp_path / "small.bag"
    write_bag(big, static_record(n))
    write_bag(small, static_record(n // 4))
    assert big.stat().st_size > 10 * limit
    settings = {"up_axis": "+z", "n_sigma": 3.0}
    grown = streamed_memory_growth(
        "pipelines.ingest.rosbag_reader:stream_rosbag",
        "rosbag",
        big,
        small,
        tmp_path / "s.parquet",
        limit,
        settings,
    )
    assert grown < limit, grown / 2**20
