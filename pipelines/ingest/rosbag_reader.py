"""ROS 1 bag and ROS 2 sqlite3 bag (.db3) reader: chunks of decoded messages, joined into a
Recording (`read_rosbag`) or streamed to the samples' Parquet (`stream_rosbag`).

A ROS 1 bag (``#ROSBAG V2.0``) is walked front to back by `pipelines.ingest.ros1_bag`; a
ROS 2 storage file (an SQLite database; the .db3 of a bag folder, its metadata.yaml not
needed) is read by rosbags with its typestore for ROS 2 Humble, into memory only.

Topics (docs/manifest.md): ``imu_topic`` (default: the one Imu topic, the fastest of
several; below ``min_rate_hz`` refused with every rate), ``temperature_topic``,
``table_topic`` / ``table_joint`` (JointState position -> ``table_angle`` rad, unwrapped;
velocity -> ``table_rate`` rad/s), interpolated onto the IMU time; ``stamp`` ``"header"``
or ``"log"``; Unix s, in log-time order. A ROS 1 bag cut while written is read into
memory to its last whole chunk, with its finding.

Streamed, a ROS 1 bag's IMU chunks go through the in-memory reader's checks
(`log_samples.check_samples`, records numbered in the whole topic) to
`streamed_pass.SampleSink`. Refused there with the reason: a temperature or table topic
(interpolated onto the whole IMU time base), log times going back across chunks (the
join sorts them), a cut bag (the route carries no findings), a ROS 2 .db3 (an SQLite
database is not read front to back).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Unpack

import numpy as np

from calib_core.recording import Recording
from pipelines.ingest.cdr import NS
from pipelines.ingest.data_format import extra_keys
from pipelines.ingest.errors import IngestError, file_head
from pipelines.ingest.log_samples import (
    MIN_RATE_HZ,
    LogSource,
    check_samples,
    checked_recording,
    choose_source,
    stamp_rate,
)
from pipelines.ingest.ros1_bag import IMU, MAGIC, TEMPERATURE, Ros1Bag, message_part, rate_of

if TYPE_CHECKING:
    from pipelines.ingest.data_format import FormatSpec
    from pipelines.ingest.streamed_pass import SampleSink, Streamed, StreamOptions

ROS1_MAGIC = MAGIC
SQLITE_MAGIC = b"SQLite format 3\x00"
JOINT_STATE = "sensor_msgs/msg/JointState"
KEYS = ("imu_topic", "temperature_topic", "table_topic", "table_joint", "stamp", "min_rate_hz")


def bag_kind(path: Path) -> str:
    """``"rosbag1"`` or ``"rosbag2"`` by the file's first bytes; IngestError otherwise."""
    head = file_head(path, 16)
    if head.startswith(ROS1_MAGIC):
        return "rosbag1"
    if head.startswith(SQLITE_MAGIC):
        return "rosbag2"
    raise IngestError(
        "not a ROS bag: expected '#ROSBAG V2.0' (ROS 1) or an SQLite database (ROS 2 .db3), "
        f"found {head.hex(' ')}",
        file=path,
    )


def topic_connections(
    conns: list, path: Path, msgtype: str, name: str | None, key: str, required: bool
):
    """The connections of topic `name`, or of the one topic of `msgtype`, among `conns`."""
    found = [c for c in conns if (c.topic == name if name else c.msgtype == msgtype)]
    topics = sorted({c.topic for c in found})
    if name and found and found[0].msgtype != msgtype:
        raise IngestError(
            f"topic {name} is {found[0].msgtype}, expected {msgtype}",
            file=path,
            field=f"format.{key}",
        )
    if len(topics) == 1 or (not required and not topics and not name):
        return found
    listed = ", ".join(f"{c.topic} ({c.msgtype})" for c in conns) or "none"
    what = f"topic {name!r}" if name else f"one {msgtype} topic"
    raise IngestError(
        f"expected {what}, found {len(topics)}; the bag's topics: {listed}",
        file=path,
        field=f"format.{key}",
    )


def chosen_topics(
    conns: list, path: Path, keys: dict[str, Any], sources: Callable[[], list[LogSource]]
) -> dict[str, list]:
    """The connections of each role (imu, temp if any, table if named) the [format] keys
    name; of several Imu topics and none named, the fastest of `sources`."""
    imu_topic = keys.get("imu_topic")
    if imu_topic is None and len({c.topic for c in conns if c.msgtype == IMU}) > 1:
        min_rate = keys.get("min_rate_hz", MIN_RATE_HZ)
        chosen = choose_source(path, sources(), min_rate_hz=min_rate, field="format.imu_topic")
        imu_topic = str(chosen.key)
    out = {"imu": topic_connections(conns, path, IMU, imu_topic, "imu_topic", True)}
    name = keys.get("temperature_topic")
    if temps := topic_connections(conns, path, TEMPERATURE, name, "temperature_topic", False):
        out["temp"] = temps
    if table := keys.get("table_topic"):
        out["table"] = topic_connections(conns, path, JOINT_STATE, table, "table_topic", True)
    return out


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
    keys = {
        "imu_topic": imu_topic,
        "temperature_topic": temperature_topic,
        "table_topic": table_topic,
        "min_rate_hz": min_rate_hz,
    }
    check_stamp(stamp)
    parts: dict[str, list[dict[str, np.ndarray]]] = {"imu": [], "temp": [], "table": []}
    if bag_kind(path) == "rosbag1":
        try:
            with path.open("rb") as fh:
                bag = Ros1Bag(path, fh, stamp)
                bag.open(os.fstat(fh.fileno()).st_size, cut_ok=True)
                bag.select(chosen_topics(bag.connections, path, keys, bag.sources), table_joint)
                for role, _, part in bag.parts():
                    parts[role].append(part)
                bag.check_counts()
        except OSError as exc:
            raise IngestError(f"cannot read file: {exc.strerror or exc}", file=path) from None
        topics, findings = bag.topics, bag.findings
    else:
        topics, findings = read_db3(path, keys, stamp, table_joint, parts), ()
    return joined_recording(path, topics, parts, findings, min_rate_hz)


def check_stamp(stamp: str) -> None:
    if stamp not in ("header", "log"):
        raise IngestError(f"stamp must be 'header' or 'log', got {stamp!r}", field="format.stamp")


def joined(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """A role's chunks joined, in log-time order (stable: rosbags' order on a tie)."""
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    order = np.argsort(out["log"], kind="stable")
    if (order[1:] < order[:-1]).any():
        out = {k: v[order] for k, v in out.items()}
    return out


def joined_recording(
    path: Path,
    topics: dict[str, str],
    parts: dict[str, list[dict[str, np.ndarray]]],
    findings: tuple[dict, ...],
    min_rate_hz: float,
) -> Recording:
    """The Recording of the chunks of each role: the IMU's time base (Unix s from exact
    integer offsets to the first stamp), temperature and table interpolated onto it."""
    topic = topics["imu"]
    if not parts["imu"]:
        raise IngestError(f"{topic}: no samples", file=path, field=topic)
    imu = joined(parts["imu"])
    t_ns = imu["stamp"]
    t0 = int(t_ns[0])
    t = t0 / NS + (t_ns - t0) / NS
    temp = None
    if parts["temp"]:
        temps = joined(parts["temp"])
        temp = np.interp(t_ns - t0, temps["stamp"] - t0, temps["temp"])
    reference = {}
    if "table" in topics:
        if not parts["table"]:
            raise IngestError("no table messages", file=path, field="format.table_topic")
        table = joined(parts["table"])
        ts = table["stamp"]
        for key, name, unwrap in (("table_angle", "angle", True), ("table_rate", "rate", False)):
            if not np.isnan(series := table[name]).any():
                series = np.unwrap(series) if unwrap else series
                reference[key] = np.interp(t_ns - ts[0], ts - ts[0], series)
    channels = {"acc": imu["acc"], "gyr": imu["gyr"]}
    rec = checked_recording(path, topic, t, channels, temp=temp, findings=findings)
    check_rate(path, topic, len(rec), stamp_rate(rec.t), min_rate_hz, temp is not None)
    rec.reference.update(reference)
    return rec


# --- ROS 2 .db3 ------------------------------------------------------------------------


def open_db3(path: Path):
    """An open rosbags ROS 2 reader of the .db3 at `path`."""
    from rosbags.rosbag2 import Reader

    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags' ReaderError, sqlite3 errors, ... on damaged bags
        raise IngestError(f"damaged rosbag2 ({type(exc).__name__}: {exc})", file=path) from None
    return reader


def read_db3(
    path: Path, keys: dict[str, Any], stamp: str, joint: str | int, parts: dict[str, list]
) -> dict[str, str]:
    """A ROS 2 .db3's messages of each chosen role, as one chunk, to `parts`; the topics
    read by role."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    reader = open_db3(path)
    try:
        chosen = chosen_topics(reader.connections, path, keys, lambda: db3_sources(reader, path))
        for role, conns in chosen.items():
            logs: list[int] = []

            def decoded(conns: list = conns, logs: list[int] = logs):
                # one message at a time: 10^5 decoded messages held would slow the read
                for conn, log_ns, raw in reader.messages(connections=conns):
                    msg = store.deserialize_cdr(raw, conn.msgtype)
                    logs.append(log_ns)
                    yield msg

            try:
                part = message_part(path, role, decoded(), joint)
            except IngestError:
                raise
            except Exception as exc:  # a truncated record or a message that does not decode
                raise IngestError(
                    f"{conns[0].topic} message {len(logs)}: cannot decode "
                    f"({type(exc).__name__}: {exc})",
                    file=path,
                    field=conns[0].topic,
                ) from None
            if logs:
                part["log"] = np.array(logs, dtype=np.int64)
                parts[role].append({**part, "stamp": part["log"]} if stamp == "log" else part)
    finally:
        reader.close()
    return {role: conns[0].topic for role, conns in chosen.items()}


def db3_sources(reader, path: Path) -> list[LogSource]:
    """One source per sensor_msgs/Imu topic of a .db3, its rate from the log times (no
    message is decoded), in topic order."""
    topics = sorted({c.topic for c in reader.connections if c.msgtype == IMU})
    has_temp = any(c.msgtype == TEMPERATURE for c in reader.connections)
    out = []
    for topic in topics:
        conns = [c for c in reader.connections if c.topic == topic]
        try:
            stamps = np.array([ns for _, ns, _ in reader.messages(connections=conns)], float)
        except Exception as exc:  # a damaged database
            raise IngestError(
                f"{topic}: cannot read its messages ({type(exc).__name__}: {exc})",
                file=path,
                field=topic,
            ) from None
        out.append(LogSource(topic, topic, len(stamps), stamp_rate(stamps / NS), has_temp))
    return out


def bag_sources(path: Path) -> list[LogSource]:
    """The Imu topics of a ROS 1 or ROS 2 bag with their rates (`calib inspect`)."""
    path = Path(path)
    if bag_kind(path) == "rosbag2":
        reader = open_db3(path)
        try:
            return db3_sources(reader, path)
        finally:
            reader.close()
    with path.open("rb") as fh:
        bag = Ros1Bag(path, fh, "header")
        bag.open(os.fstat(fh.fileno()).st_size, cut_ok=True)
        return bag.sources()


# --- streamed ----------------------------------------------------------------------------


def stream_rosbag(
    path: Path,
    fmt: FormatSpec,
    samples: Path,
    **options: Unpack[StreamOptions],
) -> Streamed:
    """One pass over a ROS 1 bag: hash, raw copy, samples' Parquet, statistics.

    Parameters
    ----------
    path : the .bag file (ROS 1, format 2.0, indexed; none, bz2 or lz4 chunks).
    fmt : the manifest's format section (kind rosbag: ``imu_topic``, ``stamp``,
        ``min_rate_hz`` as `read_rosbag`; a temperature or table topic is refused).
    samples : the Parquet file to write (columns segment, t, acc_*, gyr_*, temp; SI;
        t in Unix s; temp NaN).
    options : `streamed_pass.StreamOptions` (raw copy, label, memory limit: the rows per
        batch and the largest chunk accepted, a quarter of it; progress, time window).

    Raises
    ------
    IngestError as `read_rosbag`, and naming the file: a ROS 2 .db3, a bag not indexed
    or truncated, a temperature or table topic, log times going back across chunks.
    """
    from pipelines.ingest.streamed_pass import streamed_pass

    path = Path(path)
    keys = {"stamp": "header", **extra_keys(fmt, "rosbag", KEYS)}
    check_stamp(keys["stamp"])
    if keys.get("table_topic") is not None:
        raise IngestError(
            "a record read in chunks gives its IMU topic only; table_topic is interpolated "
            "onto the whole IMU time base (raise the memory limit to read it into memory)",
            file=path,
            field="format.table_topic",
        )
    if bag_kind(path) == "rosbag2":
        raise IngestError(
            "a ROS 2 .db3 bag is read into memory only (an SQLite database is not read front "
            "to back in one pass); raise the memory limit, or convert the bag to MCAP "
            "(`ros2 bag convert`), which is read in chunks",
            file=path,
            field="format.kind",
        )
    with streamed_pass(path, samples, tee=True, **options) as run:
        # a chunk, its decompressed copy and their decoded arrays: a quarter of the limit
        bag = Ros1Bag(path, run.tee, keys["stamp"], run.memory_limit // 4)
        bag.open(run.size, cut_ok=False)
        chosen = chosen_topics(bag.connections, path, keys, bag.sources)
        if "temp" in chosen:
            raise IngestError(
                f"the bag's temperature topic {chosen['temp'][0].topic} is interpolated onto "
                "the whole IMU time base, which a record read in chunks does not hold (raise "
                "the memory limit to read it into memory)",
                file=path,
                field="format.temperature_topic",
            )
        bag.select(chosen)
        run.sink.topic = bag.topics["imu"]
        to_sink(path, bag, run.sink)
        bag.check_counts()
        run.sink.finish()
        run.tee.drain()
    topic, sink = bag.topics["imu"], run.sink
    if sink.done == 0:
        raise IngestError(f"{topic}: no samples", file=path, field=topic)
    # the rate from the exact median step of the first pass (`log_samples.stamp_rate`'s)
    rate = rate_of(sink.steps or sink.first.step) if sink.done > 1 else None
    check_rate(path, topic, sink.done, rate, keys.get("min_rate_hz", MIN_RATE_HZ))
    return run.result()


def to_sink(path: Path, bag: Ros1Bag, sink: SampleSink) -> None:
    """Each chunk's IMU messages through `check_samples` (on the joined time base, records
    numbered in the whole topic) to `sink`; log times going back across chunks refused."""
    topic = bag.topics["imu"]
    last_log, last_t, t0, read = None, None, None, 0
    for _, pos, part in bag.parts():
        log = part["log"]
        if last_log is not None and log[0] < last_log:
            raise IngestError(
                f"{topic}: the log time of the chunk at byte {pos} goes back before the "
                "previous chunk's; a record read in chunks keeps the file's order (raise the "
                "memory limit to read it into memory, where messages are sorted)",
                file=path,
                field=topic,
            )
        last_log = int(log[-1])
        t0 = part["stamp"][0] if t0 is None else t0
        t = (part["stamp"] - t0) / NS + t0 / NS
        arrays = {"time": t, "acc": part["acc"], "gyr": part["gyr"]}
        check_samples(path, topic, arrays, offset=read, last=last_t)
        last_t, read = float(t[-1]), read + len(t)
        sink.push(part)


def check_rate(
    path: Path, topic: str, n: int, rate: float | None, min_rate_hz: float, temp: bool = False
) -> None:
    """An IMU topic of `n` samples at `rate` Hz below `min_rate_hz` refused with its rate."""
    if rate is None or rate < min_rate_hz:
        source = LogSource(topic, topic, n, rate, temp)
        choose_source(path, [source], min_rate_hz=min_rate_hz, field="format.imu_topic")
