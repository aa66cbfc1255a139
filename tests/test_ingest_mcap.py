"""MCAP (ROS 2) reader: round trips through the real writers, cross-check with mcap-ros2-support.

Fixtures are written with mcap-ros2-support's Writer and the real ROS 2 message
definitions (concatenated ros2msg text with its dependencies), the way
``ros2 bag record`` stores them. Expected values are the arrays that were
written; the vectorised decoder is also compared with mcap-ros2-support's own
decoder on the same bytes, field by field.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

from calib_testing.ros_messages import IMU_MSGDEF, JOINT_STATE_MSGDEF, TEMPERATURE_MSGDEF
from pipelines.ingest.cdr import FixedLayout, decode_fixed_cdr
from pipelines.ingest.errors import IngestError
from pipelines.ingest.mcap_reader import read_mcap

T0_NS = 1_700_000_000_123_456_789  # a Unix time in 2023, ns; not a round number on purpose
# float64 spacing at 1.7e9 s is 2**-22 s = 2.4e-7 s; t is formed with <= 2 roundings there.
T_ABS_TOL = 2 * 2.0**-22


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def imu_message(ns: int, acc, gyr, frame_id: str = "imu_link", extra: np.ndarray | None = None):
    """A sensor_msgs/msg/Imu as a dict; `extra` (22,) fills orientation and covariances."""
    extra = np.zeros(22) if extra is None else extra
    return {
        "header": {"stamp": _stamp(ns), "frame_id": frame_id},
        "orientation": dict(zip("xyzw", map(float, extra[0:4]), strict=True)),
        "orientation_covariance": list(map(float, extra[4:13])),
        "angular_velocity": dict(zip("xyz", map(float, gyr), strict=True)),
        "angular_velocity_covariance": list(map(float, extra[13:22])),
        "linear_acceleration": dict(zip("xyz", map(float, acc), strict=True)),
        "linear_acceleration_covariance": list(map(float, extra[4:13][::-1])),
    }


def write_run(
    path: Path,
    n: int = 300,
    *,
    seed: int = 0,
    rate_hz: float = 100.0,
    imu_topics: tuple[str, ...] = ("/imu/data",),
    temperature: bool = False,
    joint_state: bool = False,
    compression: CompressionType = CompressionType.ZSTD,
    chunk_size: int = 16 * 1024,
    stamps_ns: np.ndarray | None = None,
    acc: np.ndarray | None = None,
    enable_crcs: bool = True,
) -> dict:
    """Write a simulated ROS 2 log with mcap-ros2-support; return the truth that was written."""
    rng = np.random.default_rng(seed)
    step = int(round(1e9 / rate_hz))
    if stamps_ns is None:
        stamps_ns = T0_NS + step * np.arange(n, dtype=np.int64)
    acc = rng.normal(0.0, 9.81, (n, 3)) if acc is None else acc
    gyr = rng.normal(0.0, 1.0, (n, 3))
    frames = rng.choice(["", "a", "imu", "imu_link", "base_imu_link_01"], n)  # all alignments
    truth = {"stamps_ns": stamps_ns, "acc": acc, "gyr": gyr, "frames": frames}
    with open(path, "wb") as f:
        w = Ros2Writer(f, chunk_size=chunk_size, compression=compression, enable_crcs=enable_crcs)
        imu_schema = w.register_msgdef("sensor_msgs/msg/Imu", IMU_MSGDEF)
        temp_schema = w.register_msgdef("sensor_msgs/msg/Temperature", TEMPERATURE_MSGDEF)
        joint_schema = w.register_msgdef("sensor_msgs/msg/JointState", JOINT_STATE_MSGDEF)
        log_ns = stamps_ns + 250_000  # logged 0.25 ms after the stamp
        truth["log_ns"] = log_ns
        for i in range(n):
            for topic in imu_topics:
                msg = imu_message(int(stamps_ns[i]), acc[i], gyr[i], str(frames[i]))
                w.write_message(topic, imu_schema, msg, log_time=int(log_ns[i]))
            if temperature and i % 10 == 5:  # 10 Hz, inside the IMU span
                ts = int(stamps_ns[i]) + 3_000_000  # 3 ms off the IMU's stamps
                deg = 20.0 + 0.5 * (ts - T0_NS) / 1e9  # a 0.5 K/s ramp
                msg = {
                    "header": {"stamp": _stamp(ts), "frame_id": ""},
                    "temperature": deg,
                    "variance": 0.0,
                }
                w.write_message("/imu/temperature", temp_schema, msg, log_time=int(log_ns[i]))
            if joint_state and i % 2 == 1:  # 50 Hz, stamps 1 ms off the IMU's
                ts = int(stamps_ns[i]) + 1_000_000
                angle = 1.5 * (ts - T0_NS) / 1e9  # 1.5 rad/s, reported wrapped to [0, 2 pi)
                msg = {
                    "header": {"stamp": _stamp(ts), "frame_id": ""},
                    "name": ["table_inner", "table_outer"],
                    "position": [0.1, float(np.mod(angle, 2 * np.pi))],
                    "velocity": [0.0, 1.5],
                    "effort": [],
                }
                w.write_message("/table/joint_states", joint_schema, msg, log_time=int(log_ns[i]))
        w.finish()
    return truth


def raw_messages(path: Path) -> list:
    """(channel topic, schema, message) of every message, via mcap's reader."""
    with open(path, "rb") as f:
        return list(make_reader(f).iter_messages())


def rewrite(src: Path, dst: Path, *, chunking: bool = True, extra=None, payload=None) -> None:
    """Copy the messages of `src` into `dst` with mcap's plain Writer.

    extra(writer, log_ns) may add channels; payload(topic, data) may alter message bytes.
    """
    with open(dst, "wb") as f:
        w = McapWriter(f, use_chunking=chunking, chunk_size=16 * 1024)
        w.start(profile="ros2", library="test")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        for schema, channel, message in raw_messages(src):
            if schema.id not in schema_ids:
                schema_ids[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channel_ids:
                channel_ids[channel.id] = w.register_channel(
                    channel.topic, channel.message_encoding, schema_ids[schema.id]
                )
            data = message.data if payload is None else payload(channel.topic, message.data)
            w.add_message(channel_ids[channel.id], message.log_time, data, message.publish_time)
        if extra is not None:
            extra(w)
        w.finish()


# --- round trips ----------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_round_trip_matches_written_arrays(tmp_path, seed):
    path = tmp_path / "run.mcap"
    truth = write_run(path, n=400, seed=seed)
    rec = read_mcap(path)
    # float64 values are copied bit for bit by CDR: exact equality.
    np.testing.assert_array_equal(rec.acc, truth["acc"])
    np.testing.assert_array_equal(rec.gyr, truth["gyr"])
    np.testing.assert_allclose(rec.t, truth["stamps_ns"] / 1e9, rtol=0, atol=T_ABS_TOL)
    # spacing is formed from exact integer offsets: 10 ms to float64 rounding of 0.01 s
    np.testing.assert_allclose(np.diff(rec.t), 0.01, rtol=0, atol=T_ABS_TOL)
    assert rec.temp is None and rec.reference == {}
    assert rec.source == str(path)


@pytest.mark.parametrize(
    "compression", [CompressionType.NONE, CompressionType.LZ4, CompressionType.ZSTD]
)
def test_compressions_and_unchunked_give_the_same_samples(tmp_path, compression):
    path = tmp_path / "run.mcap"
    truth = write_run(path, n=250, compression=compression)
    plain = tmp_path / "unchunked.mcap"
    rewrite(path, plain, chunking=False)
    for p in (path, plain):
        rec = read_mcap(p)
        np.testing.assert_array_equal(rec.acc, truth["acc"])
        np.testing.assert_array_equal(rec.gyr, truth["gyr"])


def test_log_time_stamp(tmp_path):
    path = tmp_path / "run.mcap"
    truth = write_run(path, n=120)
    rec = read_mcap(path, stamp="log")
    np.testing.assert_allclose(rec.t, truth["log_ns"] / 1e9, rtol=0, atol=T_ABS_TOL)
    # The header stamps differ from log times by 0.25 ms, far above the float64 tolerance.
    assert np.all(np.abs(read_mcap(path).t - rec.t) > 0.2e-3)


def test_vectorised_decoder_equals_mcap_ros2_on_every_field(tmp_path):
    """All 37 doubles and the stamp of every message, against mcap-ros2-support's decoder."""
    path = tmp_path / "full.mcap"
    rng = np.random.default_rng(7)
    n = 200
    extras = rng.normal(size=(n, 22))
    with open(path, "wb") as f:
        w = Ros2Writer(f, chunk_size=8 * 1024)
        schema = w.register_msgdef("sensor_msgs/msg/Imu", IMU_MSGDEF)
        for i in range(n):
            frame = "x" * int(rng.integers(0, 20))
            msg = imu_message(
                T0_NS + i * 5_000_000, rng.normal(size=3), rng.normal(size=3), frame, extras[i]
            )
            w.write_message("/imu", schema, msg, log_time=T0_NS + i)
        w.finish()
    # A big-endian CDR message (encapsulation 00 00) too: the decoders must agree on it.
    big_endian = _big_endian_imu(T0_NS + n * 5_000_000, "be_frame", rng.normal(size=37))
    dst = tmp_path / "full_be.mcap"

    def add_be(w):
        sid = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", IMU_MSGDEF.encode())
        cid = w.register_channel("/imu_be", "cdr", sid)
        w.add_message(cid, T0_NS, big_endian, T0_NS)

    rewrite(path, dst, extra=add_be)

    factory = DecoderFactory()
    full = FixedLayout(
        {
            "orientation": (0, 4),
            "orientation_covariance": (32, 9),
            "angular_velocity": (104, 3),
            "angular_velocity_covariance": (128, 9),
            "linear_acceleration": (200, 3),
            "linear_acceleration_covariance": (224, 9),
        },
        37 * 8,
    )
    checked = 0
    for schema, channel, message in raw_messages(dst):
        ref = factory.decoder_for(channel.message_encoding, schema)(message.data)
        arr = np.frombuffer(message.data, np.uint8)
        ours = decode_fixed_cdr(arr, np.array([0]), np.array([len(message.data)]), full)
        s = ref.header.stamp
        assert ours["stamp"][0] == s.sec * 1_000_000_000 + s.nanosec
        for key in ("orientation",):
            q = getattr(ref, key)
            assert list(ours[key][0]) == [q.x, q.y, q.z, q.w]
        for key in ("angular_velocity", "linear_acceleration"):
            v = getattr(ref, key)
            assert list(ours[key][0]) == [v.x, v.y, v.z]
        for key in (
            "orientation_covariance",
            "angular_velocity_covariance",
            "linear_acceleration_covariance",
        ):
            assert list(ours[key][0]) == list(getattr(ref, key))
        checked += 1
    assert checked == n + 1


def _big_endian_imu(ns: int, frame: str, values: np.ndarray) -> bytes:
    """A sensor_msgs/msg/Imu in big-endian CDR, packed by hand with struct."""
    raw = frame.encode() + b"\0"
    head = struct.pack(">iiI", ns // 1_000_000_000, ns % 1_000_000_000, len(raw)) + raw
    head += b"\0" * (-len(head) % 8)  # doubles align to 8 after the encapsulation header
    return b"\x00\x00\x00\x00" + head + struct.pack(">37d", *values)


def test_big_endian_messages_decode(tmp_path):
    path = tmp_path / "be.mcap"
    rng = np.random.default_rng(3)
    values = rng.normal(size=(50, 37))

    def add(w):
        sid = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", IMU_MSGDEF.encode())
        cid = w.register_channel("/imu", "cdr", sid)
        for i in range(50):
            ns = T0_NS + i * 1_000_000
            w.add_message(cid, ns, _big_endian_imu(ns, "f" * (i % 9), values[i]), ns)

    with open(path, "wb") as f:
        w = McapWriter(f)
        w.start()
        add(w)
        w.finish()
    rec = read_mcap(path)
    np.testing.assert_array_equal(rec.gyr, values[:, 13:16])
    np.testing.assert_array_equal(rec.acc, values[:, 25:28])


def test_temperature_and_joint_state_merged_on_imu_time(tmp_path):
    path = tmp_path / "run.mcap"
    truth = write_run(path, n=600, temperature=True, joint_state=True)
    rec = read_mcap(
        path,
        temperature_topic="/imu/temperature",
        table_topic="/table/joint_states",
        table_joint="table_outer",
    )
    t_rel = (truth["stamps_ns"] - T0_NS) / 1e9
    # Linear truth is reproduced exactly by linear interpolation inside the reference's span;
    # outside it the first/last value is held.  Tolerances: a few float64 roundings of ~20 / ~4.
    temp_span = (truth["stamps_ns"][5] + 3_000_000, truth["stamps_ns"][595] + 3_000_000)
    inside = (truth["stamps_ns"] >= temp_span[0]) & (truth["stamps_ns"] <= temp_span[1])
    np.testing.assert_allclose(rec.temp[inside], 20.0 + 0.5 * t_rel[inside], rtol=0, atol=1e-12)
    assert rec.temp[0] == pytest.approx(20.0 + 0.5 * (temp_span[0] - T0_NS) / 1e9, abs=1e-12)
    # The table angle is reported wrapped to [0, 2 pi): the reader unwraps it (1.5 rad/s * 6 s
    # = 9 rad, one wrap), so the merged angle is the continuous 1.5 t.
    joint_first = truth["stamps_ns"][1] + 1_000_000
    inside = truth["stamps_ns"] >= joint_first
    np.testing.assert_allclose(
        rec.reference["table_angle"][inside], 1.5 * t_rel[inside], rtol=0, atol=1e-12
    )
    np.testing.assert_array_equal(rec.reference["table_rate"], 1.5)
    # by index: joint 0 is fixed at 0.1 rad
    rec0 = read_mcap(path, table_topic="/table/joint_states", table_joint=0)
    np.testing.assert_array_equal(rec0.reference["table_angle"], 0.1)


def test_json_table_channel(tmp_path):
    src = tmp_path / "imu.mcap"
    truth = write_run(src, n=200)
    dst = tmp_path / "with_json.mcap"
    # 20 Hz JSON feedback, log-time stamped, angle = 0.3 + 0.2 t, rate = 0.2 rad/s
    table_ns = T0_NS + np.arange(45) * 50_000_000

    def add_json(w):
        cid = w.register_channel("/table/feedback", "json", 0)
        for ns in table_ns:
            t = (ns - T0_NS) / 1e9
            body = json.dumps({"angle": 0.3 + 0.2 * t, "rate": 0.2}).encode()
            w.add_message(cid, int(ns), body, int(ns))

    rewrite(src, dst, extra=add_json)
    rec = read_mcap(dst, table_topic="/table/feedback", stamp="log")
    t_rel = (truth["log_ns"] - T0_NS) / 1e9
    inside = truth["log_ns"] <= table_ns[-1]
    np.testing.assert_allclose(
        rec.reference["table_angle"][inside], 0.3 + 0.2 * t_rel[inside], rtol=0, atol=1e-12
    )
    np.testing.assert_array_equal(rec.reference["table_rate"], 0.2)


# --- bad input ------------------------------------------------------------------------


def _raises(path: Path, match: str, **kwargs) -> IngestError:
    with pytest.raises(IngestError, match=match) as info:
        read_mcap(path, **kwargs)
    assert str(path) in str(info.value)
    return info.value


def test_missing_topic_lists_topics_present(tmp_path):
    path = tmp_path / "run.mcap"
    write_run(path, n=50, temperature=True)
    err = _raises(path, "not found", imu_topic="/imu/raw")
    assert "/imu/data [sensor_msgs/msg/Imu]" in str(err)
    assert "/imu/temperature [sensor_msgs/msg/Temperature]" in str(err)
    _raises(path, "'/table' not found", table_topic="/table")


def test_auto_topic_choice_refuses_ambiguity(tmp_path):
    path = tmp_path / "two.mcap"
    write_run(path, n=30, imu_topics=("/imu_a", "/imu_b"))
    err = _raises(path, "several sensor_msgs/msg/Imu topics")
    assert "/imu_a" in str(err) and "/imu_b" in str(err)
    assert len(read_mcap(path, imu_topic="/imu_b")) == 30


def test_no_imu_channel(tmp_path):
    src = tmp_path / "run.mcap"
    write_run(src, n=30, temperature=True)
    dst = tmp_path / "temp_only.mcap"
    with open(dst, "wb") as f:
        w = McapWriter(f)
        w.start()
        for schema, channel, message in raw_messages(src):
            if channel.topic == "/imu/temperature":
                sid = w.register_schema(schema.name, schema.encoding, schema.data)
                cid = w.register_channel(channel.topic, "cdr", sid)
                w.add_message(cid, message.log_time, message.data, message.publish_time)
        w.finish()
    _raises(dst, "no channel with schema sensor_msgs/msg/Imu")


def test_undecodable_schema_names_topic_schema_and_encoding(tmp_path):
    path = tmp_path / "run.mcap"
    write_run(path, n=40, temperature=True)
    err = _raises(path, "cannot decode topic '/imu/temperature'", imu_topic="/imu/temperature")
    assert "sensor_msgs/msg/Temperature" in str(err) and "'cdr'" in str(err)
    # an IMU published as JSON (e.g. by a foxglove bridge): the schema name fits, the encoding not
    dst = tmp_path / "json_imu.mcap"

    def add(w):
        sid = w.register_schema("sensor_msgs/msg/Imu", "jsonschema", b"{}")
        cid = w.register_channel("/imu_json", "json", sid)
        w.add_message(cid, T0_NS, b'{"linear_acceleration": {}}', T0_NS)

    rewrite(path, dst, extra=add)
    err = _raises(dst, "cannot decode topic '/imu_json'", imu_topic="/imu_json")
    assert "'json'" in str(err)


def test_truncated_file(tmp_path):
    """A file cut before any IMU message, or in its closing magic, is refused; one cut in
    its data (a recorder that lost power) is read to its last whole record: the intact
    file's first samples, with the finding naming the file and the bytes dropped."""
    path = tmp_path / "run.mcap"
    truth = write_run(path, n=200)
    data = path.read_bytes()
    for cut in (4, 9, 40, len(data) - 3):
        bad = tmp_path / f"cut{cut}.mcap"
        bad.write_bytes(data[:cut])
        _raises(bad, "truncated|magic|damaged|ends|no IMU|no messages|topic")
    for cut in (len(data) // 3, len(data) // 2):
        bad = tmp_path / f"cut{cut}.mcap"
        bad.write_bytes(data[:cut])
        rec = read_mcap(bad)
        k = len(rec)
        assert 0 < k < 200
        np.testing.assert_array_equal(rec.gyr, truth["gyr"][:k])
        (finding,) = rec.findings
        assert finding["name"] == f"record:cut:{bad.name}" and str(bad) in finding["detail"]
        assert f"of {cut}, a record the file cuts short" in finding["detail"]


def test_wrong_magic(tmp_path):
    path = tmp_path / "run.mcap"
    write_run(path, n=20)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP1\r\n" + path.read_bytes()[8:])
    _raises(bad, "not an MCAP file")


def test_non_increasing_and_duplicated_stamps(tmp_path):
    stamps = T0_NS + 10_000_000 * np.arange(100, dtype=np.int64)
    dup = stamps.copy()
    dup[40] = dup[39]
    path = tmp_path / "dup.mcap"
    write_run(path, n=100, stamps_ns=dup)
    _raises(path, r"not strictly increasing at message 40 .*duplicated")
    back = stamps.copy()
    back[70] = back[60]
    path = tmp_path / "back.mcap"
    write_run(path, n=100, stamps_ns=back)
    _raises(path, r"not strictly increasing at message 70 .*going back")


@pytest.mark.parametrize("bad_value", [np.nan, np.inf])
def test_non_finite_samples(tmp_path, bad_value):
    acc = np.random.default_rng(0).normal(size=(60, 3))
    acc[33, 1] = bad_value
    path = tmp_path / "nan.mcap"
    write_run(path, n=60, acc=acc)
    _raises(path, r"non-finite linear_acceleration in message 33")


def test_damaged_payload_is_reported_with_message_index(tmp_path):
    path = tmp_path / "run.mcap"
    write_run(path, n=30)
    dst = tmp_path / "short.mcap"
    count = {"n": 0}

    def shorten(topic, data):
        count["n"] += 1
        return data[:-8] if count["n"] == 12 else data  # message 11 loses its last double

    rewrite(path, dst, payload=shorten)
    _raises(dst, r"message 11 \(0-based\) of topic '/imu/data'.*does not hold")


def test_bad_arguments(tmp_path):
    path = tmp_path / "run.mcap"
    write_run(path, n=10)
    _raises(path, "stamp must be", stamp="receive")
    _raises(path, "same topic", imu_topic="/imu/data", temperature_topic="/imu/data")
    _raises(path, "table_joint", table_topic="/imu/data", table_joint=1.5)


def test_writer_in_memory_matches_file(tmp_path):
    """The helper itself: mcap's reader sees what write_run wrote (guards the fixture)."""
    path = tmp_path / "run.mcap"
    truth = write_run(path, n=25)
    messages = raw_messages(path)
    assert len(messages) == 25
    decoded = DecoderFactory().decoder_for("cdr", messages[3][0])(messages[3][2].data)
    assert decoded.linear_acceleration.y == truth["acc"][3, 1]
