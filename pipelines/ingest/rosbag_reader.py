"""ROS 1 bag and ROS 2 sqlite3 bag (.db3) reader (rosbags) -> Recording.

The bag is recognised by content: a ROS 1 bag starts ``#ROSBAG V2.0``, a ROS 2
storage file is an SQLite database (``SQLite format 3``; the .db3 of a bag
folder is read directly, its metadata.yaml is not needed). Messages are
deserialised by rosbags with the bag's own message definitions (ROS 1) or its
typestore for ROS 2 Humble (the standard sensor_msgs types).

Topics, as for MCAP (docs/manifest.md): ``imu_topic`` (default: the one
``sensor_msgs/msg/Imu`` topic), ``temperature_topic`` (sensor_msgs/msg/Temperature,
default: the one such topic if any), ``table_topic`` (sensor_msgs/msg/JointState:
position -> reference ``table_angle`` rad, unwrapped; velocity -> ``table_rate``
rad/s; joint ``table_joint``, name or index). Low-rate channels are interpolated
onto the IMU time, holding their first / last value outside their span. Time:
``stamp = "header"`` (default; the message header stamp) or ``"log"`` (the bag's
receive time), Unix seconds. A bag with several Imu topics and no ``imu_topic``
is read from the one logged at the highest rate; an IMU topic below
``min_rate_hz`` is refused with every Imu topic's rate (pipelines.ingest.log_samples).
A ROS 1 bag cut while written (no index) is read to its last whole chunk with the
``record:cut:<file>`` finding (`pipelines.ingest.rosbag_cut`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib_core.recording import Recording
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import (
    MIN_RATE_HZ,
    LogSource,
    checked_recording,
    choose_source,
    stamp_rate,
)

ROS1_MAGIC = b"#ROSBAG V2.0\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
IMU = "sensor_msgs/msg/Imu"
TEMPERATURE = "sensor_msgs/msg/Temperature"
JOINT_STATE = "sensor_msgs/msg/JointState"
KEYS = ("imu_topic", "temperature_topic", "table_topic", "table_joint", "stamp", "min_rate_hz")
NS = 1e9


def bag_kind(path: Path) -> str:
    """``"rosbag1"`` or ``"rosbag2"`` by the file's first bytes; IngestError otherwise."""
    try:
        with Path(path).open("rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        raise IngestError(f"cannot read file: {exc.strerror or exc}", file=path) from None
    if head.startswith(ROS1_MAGIC):
        return "rosbag1"
    if head.startswith(SQLITE_MAGIC):
        return "rosbag2"
    raise IngestError(
        "not a ROS bag: expected '#ROSBAG V2.0' (ROS 1) or an SQLite database (ROS 2 .db3), "
        f"found {head.hex(' ')}",
        file=path,
    )


def open_bag(path: Path):
    """An open rosbags reader and the deserialising function for its messages."""
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    kind = bag_kind(path)
    try:
        if kind == "rosbag1":
            from rosbags.rosbag1 import Reader

            from pipelines.ingest.rosbag_cut import CutBagReader, is_cut

            reader = (CutBagReader if is_cut(path) else Reader)(path)
            reader.open()
            store = get_typestore(Stores.EMPTY)
            for conn in reader.connections:
                store.register(ros1_types(conn))
            return reader, lambda raw, msgtype: store.deserialize_ros1(raw, msgtype)
        from rosbags.rosbag2 import Reader

        reader = Reader(path)
        reader.open()
        store = get_typestore(Stores.ROS2_HUMBLE)
        return reader, lambda raw, msgtype: store.deserialize_cdr(raw, msgtype)
    except IngestError:
        raise
    except Exception as exc:  # rosbags' ReaderError, sqlite3 errors, ... on damaged bags
        raise IngestError(f"damaged {kind} ({type(exc).__name__}: {exc})", file=path) from None


def ros1_types(conn) -> dict:
    from rosbags.typesys import get_types_from_msg

    return get_types_from_msg(conn.msgdef.data, conn.msgtype)


def topic_connections(reader, path: Path, msgtype: str, name: str | None, key: str, required: bool):
    """The connections of topic `name`, or of the one topic of `msgtype`."""
    conns = [c for c in reader.connections if (c.topic == name if name else c.msgtype == msgtype)]
    topics = sorted({c.topic for c in conns})
    if name and conns and conns[0].msgtype != msgtype:
        raise IngestError(
            f"topic {name} is {conns[0].msgtype}, expected {msgtype}",
            file=path,
            field=f"format.{key}",
        )
    if len(topics) == 1 or (not required and not topics and not name):
        return conns
    found = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
    what = f"topic {name!r}" if name else f"one {msgtype} topic"
    raise IngestError(
        f"expected {what}, found {len(topics)}; the bag's topics: {found}",
        file=path,
        field=f"format.{key}",
    )


def _messages(reader, deserialize, conns, path: Path, stamp: str, extract):
    """(stamps in ns (N,), [extract(message)]) of the connections, in log order.

    Only what `extract` takes is kept: holding 10^5 decoded messages (each with
    numpy covariance arrays) would make the garbage collector's passes, and the
    read, twice as slow.
    """
    stamps, msgs = [], []
    try:
        for conn, log_ns, raw in reader.messages(connections=conns):
            msg = deserialize(raw, conn.msgtype)
            header = getattr(msg, "header", None)
            if stamp == "header" and header is not None:
                stamps.append(header.stamp.sec * 1_000_000_000 + header.stamp.nanosec)
            else:
                stamps.append(log_ns)
            msgs.append(extract(msg))
    except Exception as exc:  # a truncated record or a message that does not decode
        where = conns[0].topic if conns else "?"
        raise IngestError(
            f"{where} message {len(msgs)}: cannot decode ({type(exc).__name__}: {exc})",
            file=path,
            field=where,
        ) from None
    return np.array(stamps, dtype=np.int64), msgs


def read_rosbag(
    path: Path,
    *,
    imu_topic: str | None = None,
    temperature_topic: str | None = None,
    table_topic: str | None = None,
    table_joint: str | int = 0,
    stamp: str = "header",
    min_rate_hz: float = MIN_RATE_HZ,
) -> Recording:
    """Read sensor_msgs/Imu (+ Temperature, + JointState table feedback) from a ROS bag.

    Returns
    -------
    Recording with t (N,) Unix s, acc (N, 3) m/s^2, gyr (N, 3) rad/s, temp (N,)
    deg C when a temperature topic is present, reference ``table_angle`` /
    ``table_rate`` when `table_topic` is given.

    Raises
    ------
    IngestError naming the file and topic / field: not a bag, damaged, no or
    several IMU topics, a message that does not decode, a non-finite sample,
    time not increasing.
    """
    path = Path(path)
    if stamp not in ("header", "log"):
        raise IngestError(f"stamp must be 'header' or 'log', got {stamp!r}", field="format.stamp")
    reader, deserialize = open_bag(path)
    try:
        if imu_topic is None and len({c.topic for c in reader.connections if c.msgtype == IMU}) > 1:
            sources = bag_sources(reader, path)
            imu_topic = str(
                choose_source(path, sources, min_rate_hz=min_rate_hz, field="format.imu_topic").key
            )
        conns = topic_connections(reader, path, IMU, imu_topic, "imu_topic", True)
        t_ns, rows = _messages(reader, deserialize, conns, path, stamp, imu_values)
        values = np.array(rows, dtype=float).reshape(-1, 6)
        acc, gyr = values[:, :3].copy(), values[:, 3:].copy()
        t0 = int(t_ns[0]) if len(t_ns) else 0
        t = t0 / NS + (t_ns - t0) / NS
        temp = None
        tconns = topic_connections(
            reader, path, TEMPERATURE, temperature_topic, "temperature_topic", False
        )
        if tconns:
            ts, temps = _messages(reader, deserialize, tconns, path, stamp, _temperature)
            if len(ts):
                temp = np.interp(t_ns - t0, ts - t0, np.array(temps, dtype=float))
        reference = {}
        if table_topic:
            jconns = topic_connections(reader, path, JOINT_STATE, table_topic, "table_topic", True)
            reference = _table(reader, deserialize, jconns, path, stamp, table_joint, t_ns)
    finally:
        reader.close()
    findings = getattr(reader, "findings", ())  # a cut ROS 1 bag's (rosbag_cut)
    rec = checked_recording(
        path, conns[0].topic, t, {"acc": acc, "gyr": gyr}, temp=temp, findings=findings
    )
    rate, topic = stamp_rate(rec.t), conns[0].topic
    if rate is None or rate < min_rate_hz:
        choose_source(
            path,
            [LogSource(topic, topic, len(rec), rate, temp is not None)],
            min_rate_hz=min_rate_hz,
            field="format.imu_topic",
        )
    rec.reference.update(reference)
    return rec


def bag_sources(reader, path: Path) -> list[LogSource]:
    """One source per sensor_msgs/Imu topic, its rate from the bag's log times (no message
    is decoded), in topic order."""
    topics = sorted({c.topic for c in reader.connections if c.msgtype == IMU})
    has_temp = any(c.msgtype == TEMPERATURE for c in reader.connections)
    out = []
    for topic in topics:
        conns = [c for c in reader.connections if c.topic == topic]
        try:
            stamps = np.array([ns for _, ns, _ in reader.messages(connections=conns)], float)
        except Exception as exc:  # a damaged chunk or index
            raise IngestError(
                f"{topic}: cannot read its messages ({type(exc).__name__}: {exc})",
                file=path,
                field=topic,
            ) from None
        out.append(LogSource(topic, topic, len(stamps), stamp_rate(stamps / NS), has_temp))
    return out


def imu_values(m) -> tuple[float, ...]:
    a, w = m.linear_acceleration, m.angular_velocity
    return (a.x, a.y, a.z, w.x, w.y, w.z)


def _temperature(m) -> float:
    return m.temperature


def _joint(m) -> tuple[list[str], list[float], list[float]]:
    return list(m.name), list(m.position), list(m.velocity)


def _table(reader, deserialize, conns, path, stamp, joint, t_ns) -> dict[str, np.ndarray]:
    """table_angle (unwrapped, rad) and table_rate (rad/s) of one joint on the IMU time."""
    ts, msgs = _messages(reader, deserialize, conns, path, stamp, _joint)
    if not msgs:
        raise IngestError("no table messages", file=path, field="format.table_topic")
    names = msgs[0][0]
    if isinstance(joint, str):
        if joint not in names:
            raise IngestError(
                f"joint {joint!r} not in {names}", file=path, field="format.table_joint"
            )
        joint = names.index(joint)
    out = {}
    for key, k, unwrap in (("table_angle", 1, True), ("table_rate", 2, False)):
        values = [m[k] for m in msgs]
        if all(len(v) > joint for v in values):
            series = np.array([v[joint] for v in values], dtype=float)
            series = np.unwrap(series) if unwrap else series
            out[key] = np.interp(t_ns - ts[0], ts - ts[0], series)
    return out
