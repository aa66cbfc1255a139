"""Writers of real log files for the reader tests, each through its ecosystem's own library.

- PX4 ULog: pyulog's ``ULog.write_ulog`` on a ULog built from pyulog's own
  message classes (MessageFormat, _MessageAddLogged, Data), with the PX4 field
  layouts of sensor_combined, sensor_accel and sensor_gyro.
- ArduPilot DataFlash: pymavlink has a reader only; the file is written
  record by record as ArduPilot's logger does (FMT records, then IMU records)
  with pymavlink's own format table types (DFReader.FORMAT_TO_STRUCT).
- ROS 1 bags and ROS 2 sqlite3 bags: rosbags' Writer classes with its typestore's
  sensor_msgs/msg/Imu and Temperature.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from calib_core.recording import Recording

T0_US = 5_000_000  # boot time of the first sample, us
ACCEL_FIELDS = [
    ("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"), ("uint32_t", "device_id"),
    ("float", "x"), ("float", "y"), ("float", "z"), ("float", "temperature"),
    ("uint32_t", "error_count"), ("uint8_t[3]", "clip_counter"), ("uint8_t", "samples"),
]  # fmt: skip
COMBINED_FIELDS = [
    ("uint64_t", "timestamp"), ("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"),
    ("int32_t", "accelerometer_timestamp_relative"), ("float[3]", "accelerometer_m_s2"),
    ("uint32_t", "accelerometer_integral_dt"), ("uint8_t", "accelerometer_clipping"),
    ("uint8_t", "gyro_clipping"), ("uint8_t", "accel_calibration_count"),
    ("uint8_t", "gyro_calibration_count"),
]  # fmt: skip
_NUMPY = {"uint64_t": "<u8", "uint32_t": "<u4", "int32_t": "<i4", "uint8_t": "u1", "float": "<f4"}


def _ulog_topic(ulog_cls, formats, name: str, fields, msg_id: int, multi_id: int, values):
    """A pyulog Data of topic `name` from {field: (N,) or (N, k) values}."""
    text = name + ":" + "".join(f"{t} {n};" for t, n in fields)
    formats[name] = ulog_cls.MessageFormat(text.encode(), None)
    added = ulog_cls._MessageAddLogged(
        struct.pack("<BH", multi_id, msg_id) + name.encode(), None, formats
    )
    n = len(values["timestamp"])
    array = np.zeros(n, dtype=added.dtype)
    for field in added.dtype.names:
        base, _, index = field.partition("[")
        if base in values:
            v = np.asarray(values[base])
            array[field] = v[:, int(index[:-1])] if index else v
    added.buffer = bytearray(array.tobytes())
    return ulog_cls.Data(added)


def write_ulog(
    path: Path,
    rec: Recording,
    *,
    topics: str = "separate",
    separate_every: int = 1,
    device_ids: tuple[int, int] = (1, 1),
) -> None:
    """One segment as a ULog: ``separate`` (sensor_accel + sensor_gyro, with temperature),
    ``combined`` (sensor_combined) or ``both``. `separate_every` > 1 logs sensor_accel /
    sensor_gyro with every so many samples only (PX4 logs them at 1 Hz beside a fast
    sensor_combined). `device_ids`: the (accel, gyro) ``device_id`` fields."""
    from pyulog import ULog

    ulog = ULog(None)
    stamps = T0_US + np.round((rec.t - rec.t[0]) * 1e6).astype(np.uint64)
    ulog._start_timestamp = int(stamps[0])
    formats = ulog._message_formats
    temp = rec.temp if rec.temp is not None else np.full(len(rec), 25.0)
    data = []
    if topics in ("separate", "both"):
        k = slice(None, None, separate_every)
        for i, (name, v) in enumerate((("sensor_accel", rec.acc), ("sensor_gyro", rec.gyr))):
            fields = (
                ACCEL_FIELDS
                if name == "sensor_accel"
                else [f for f in ACCEL_FIELDS if f[1] != "samples"]
            )
            values = {
                "timestamp": stamps[k],
                "timestamp_sample": stamps[k],
                "device_id": device_ids[i],
                "x": v[k, 0],
                "y": v[k, 1],
                "z": v[k, 2],
                "temperature": temp[k],
            }
            data.append(_ulog_topic(ULog, formats, name, fields, i, 0, values))
    if topics in ("combined", "both"):
        values = {"timestamp": stamps, "gyro_rad": rec.gyr, "accelerometer_m_s2": rec.acc}
        data.append(_ulog_topic(ULog, formats, "sensor_combined", COMBINED_FIELDS, 2, 0, values))
    ulog._data_list = data
    ulog.write_ulog(str(path))


# --- ArduPilot DataFlash -------------------------------------------------------------

DF_HEAD = b"\xa3\x95"
FMT_ID = 128
IMU_FORMAT = ("QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
IMU_OLD_FORMAT = ("QffffffIIfBB", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH")


def _df_struct(fmt: str) -> struct.Struct:
    from pymavlink.DFReader import FORMAT_TO_STRUCT

    return struct.Struct("<" + "".join(FORMAT_TO_STRUCT[c][0] for c in fmt))


def _df_fmt_record(type_id: int, name: str, fmt: str, columns: str) -> bytes:
    length = 3 + _df_struct(fmt).size
    body = struct.pack(
        "<BB4s16s64s", type_id, length, name.encode(), fmt.encode(), columns.encode()
    )
    return DF_HEAD + bytes([FMT_ID]) + body


def write_dataflash(
    path: Path,
    rec: Recording,
    *,
    instances: int = 1,
    old: bool = False,
    every: tuple[int, ...] | None = None,
    temperature: bool = True,
) -> None:
    """One segment as an ArduPilot .bin: IMU records (``I`` = instance), or with `old`
    the pre-4.1 layout: IMU, IMU2, ... messages without an instance field. Instances
    after the first hold the same samples + 1 m/s^2 on x. `every` (one per instance)
    logs an instance with every so many samples only; without `temperature` the ``T``
    field is 0 (an IMU without a thermometer)."""
    stamps = (T0_US + np.round((rec.t - rec.t[0]) * 1e6)).astype(np.uint64)
    temp = rec.temp if rec.temp is not None else np.full(len(rec), 25.0)
    temp = temp if temperature else np.zeros(len(rec))
    every = every or (1,) * instances
    out = bytearray(_df_fmt_record(FMT_ID, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
    fmt, columns = IMU_OLD_FORMAT if old else IMU_FORMAT
    names = [f"IMU{k + 1}" if k else "IMU" for k in range(instances)] if old else ["IMU"]
    for k, name in enumerate(names):
        out += _df_fmt_record(129 + k, name, fmt, columns)
    pack = _df_struct(fmt).pack
    for i in range(len(rec)):
        for k in range(instances):
            if i % every[k]:
                continue
            type_id = 129 + k if old else 129
            acc = rec.acc[i] + (k, 0, 0)
            g, a, ts = rec.gyr[i], acc, int(stamps[i])
            values = (
                (ts, *g, *a, 0, 0, float(temp[i]), 1, 1)
                if old
                else (ts, k, *g, *a, 0, 0, float(temp[i]), 1, 1, 1000, 1000)
            )
            out += DF_HEAD + bytes([type_id]) + pack(*values)
    path.write_bytes(bytes(out))


# --- ROS bags (rosbags' writers) ----------------------------------------------------

T0_NS = 1_763_600_000_000_000_000  # 2025-11-20, Unix ns


def _ros_messages(store, rec: Recording, stamps, table_rate: float | None, slow_every=None):
    """(topic, msgtype, stamp ns, message) of one segment: Imu, Temperature at 1/10 rate,
    JointState (angle = table_rate * t) when `table_rate` is given, and with `slow_every`
    a second Imu topic /imu/slow holding every so many samples (+1 m/s^2 on x)."""
    Imu = store.types["sensor_msgs/msg/Imu"]
    Temperature = store.types["sensor_msgs/msg/Temperature"]
    JointState = store.types["sensor_msgs/msg/JointState"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    Vector3 = store.types["geometry_msgs/msg/Vector3"]
    Quaternion = store.types["geometry_msgs/msg/Quaternion"]
    zeros = np.zeros(9)
    for i, ns in enumerate(stamps.tolist()):
        time = Time(sec=ns // 10**9, nanosec=ns % 10**9)
        extra = {"seq": i} if "seq" in Header.__dataclass_fields__ else {}  # ROS 1's Header
        header = Header(stamp=time, frame_id="imu", **extra)
        imu = Imu(
            header=header,
            orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=zeros,
            angular_velocity=Vector3(x=rec.gyr[i, 0], y=rec.gyr[i, 1], z=rec.gyr[i, 2]),
            angular_velocity_covariance=zeros,
            linear_acceleration=Vector3(x=rec.acc[i, 0], y=rec.acc[i, 1], z=rec.acc[i, 2]),
            linear_acceleration_covariance=zeros,
        )
        yield "/imu/data", "sensor_msgs/msg/Imu", ns, imu
        if slow_every and i % slow_every == 0:
            a = rec.acc[i] + (1.0, 0.0, 0.0)
            slow = Imu(
                header=header,
                orientation=imu.orientation,
                orientation_covariance=zeros,
                angular_velocity=imu.angular_velocity,
                angular_velocity_covariance=zeros,
                linear_acceleration=Vector3(x=a[0], y=a[1], z=a[2]),
                linear_acceleration_covariance=zeros,
            )
            yield "/imu/slow", "sensor_msgs/msg/Imu", ns, slow
        if i % 10 == 0 and rec.temp is not None:
            msg = Temperature(header=header, temperature=float(rec.temp[i]), variance=0.0)
            yield "/imu/temperature", "sensor_msgs/msg/Temperature", ns, msg
        if table_rate is not None and i % 5 == 0:
            angle = table_rate * (ns - int(stamps[0])) / 1e9
            msg = JointState(
                header=header,
                name=["table"],
                position=np.array([angle]),
                velocity=np.array([table_rate]),
                effort=np.array([0.0]),
            )
            yield "/table/joint_states", "sensor_msgs/msg/JointState", ns, msg


def _write_ros(  # noqa: ANN001
    writer, store, serialize, rec: Recording, table_rate, slow_every, stamps=None, log_delay_ns=0
) -> None:
    """`rec`'s messages into an open rosbags `writer`, serialised by `serialize`
    (the typestore's CDR for ROS 2, ROS 1 for ROS 1): header stamps `stamps` (ns; default
    from rec.t), log times `log_delay_ns` later."""
    if stamps is None:
        stamps = T0_NS + np.round((rec.t - rec.t[0]) * 1e9).astype(np.int64)
    conns = {}
    for topic, msgtype, ns, msg in _ros_messages(store, rec, stamps, table_rate, slow_every):
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
        writer.write(conns[topic], ns + log_delay_ns, serialize(msg, msgtype))


def write_rosbag2(
    folder: Path, rec: Recording, *, table_rate: float | None = None, slow_every: int | None = None
) -> Path:
    """One segment as a ROS 2 sqlite3 bag folder; returns its .db3 file."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(folder, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        _write_ros(writer, store, store.serialize_cdr, rec, table_rate, slow_every)
    (db3,) = folder.glob("*.db3")
    return db3


def write_rosbag1(
    path: Path,
    rec: Recording,
    *,
    stamps: np.ndarray | None = None,
    log_delay_ns: int = 0,
    compression: str | None = None,
    chunk_bytes: int | None = None,
    table_rate: float | None = None,
    slow_every: int | None = None,
) -> Path:
    """One segment as a ROS 1 bag (message definitions of ROS 1 Noetic); returns `path`.

    Header stamps `stamps` (ns; default from rec.t), log times `log_delay_ns` later, chunks
    compressed by `compression` (a rosbags CompressionFormat name, e.g. "LZ4");
    `chunk_bytes`: rosbags' chunk threshold (default 1 MiB; ``rosbag record``'s is 768 KiB).
    """
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    writer = Writer(path)
    if compression:
        writer.set_compression(Writer.CompressionFormat[compression])
    if chunk_bytes is not None:
        writer.chunk_threshold = chunk_bytes
    with writer:
        serialize = store.serialize_ros1
        _write_ros(writer, store, serialize, rec, table_rate, slow_every, stamps, log_delay_ns)
    return path


# --- MCAP (mcap-ros2-support's writer) ------------------------------------------------


def write_mcap(path: Path, rec: Recording, *, chunk_size: int = 4096) -> None:
    """One segment as a ROS 2 MCAP log (sensor_msgs/msg/Imu on /imu/data, header stamps on
    T0_NS), written by mcap-ros2-support in zstd chunks of about `chunk_size` bytes."""
    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer as Ros2Writer
    from test_ingest_mcap import IMU_MSGDEF, imu_message

    stamps = T0_NS + np.round((rec.t - rec.t[0]) * 1e9).astype(np.int64)
    with path.open("wb") as f:
        w = Ros2Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        schema = w.register_msgdef("sensor_msgs/msg/Imu", IMU_MSGDEF)
        for i in range(len(rec)):
            msg = imu_message(int(stamps[i]), rec.acc[i], rec.gyr[i])
            w.write_message("/imu/data", schema, msg, log_time=int(stamps[i]))
        w.finish()
