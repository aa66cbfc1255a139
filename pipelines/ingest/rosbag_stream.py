"""A long ROS 1 IMU record from a bag in bounded memory (the streamed route, `streamed_pass`).

rosbags' ROS 1 reader, which `pipelines.ingest.rosbag_reader` uses, reads the index of
every message when it opens a bag (a Python tuple per message: about 170 bytes each,
15 GB for a day at 1 kHz), so `stream_rosbag` walks the bag itself, once, front to back,
its bytes passing through `streamed_pass.HashingTee`, which hashes and copies them (the raw
copy) as they are read:

1. the bag header, then the index at its end (the connections and one record per
   chunk: small), then back to the chunks in file order;
2. each chunk is decompressed (none, bz2, lz4) and held until its index records
   (which follow it) give the offset and log time of each of its IMU messages;
3. ``sensor_msgs/Imu`` has a fixed layout once the header's ``frame_id`` length is
   known (`cdr.IMU_LAYOUT`, the same offsets in ROS 1's packed serialisation), so every
   IMU message of a chunk is decoded at once by numpy gathers; its record header is
   checked against the index (op, connection, time) and the chunk's first message is
   decoded again by rosbags with the bag's own message definition, as the in-memory
   reader does: they must agree;
4. the messages go, in log-time order (the in-memory reader's), through the in-memory
   reader's checks (`log_samples.check_samples`, records numbered in the whole topic)
   into `streamed_pass.SampleSink`: batches of a size set by the memory limit, written as row
   groups of the samples' Parquet and pushed to the first-pass statistics.

The topic choice, the stamp (``header`` or ``log``), the rate check and their refusals
are the in-memory reader's (`rosbag_reader.topic_connections`, `log_samples.choose_source`; rates
from exact median steps: of several Imu topics and none named, the fastest by its log
times, read from the index records after each chunk in a first, seeking pass over them;
the chosen topic's from `FirstPass`). What the route does not take is refused with the
reason: a bag with a temperature or table topic (interpolated onto the whole IMU time
base in memory), an Imu definition other than sensor_msgs/Imu's, log times that go back
across chunks (the in-memory reader sorts them), ROS 2 .db3 bags (an SQLite database is
not read front to back) and bags that are not indexed.
"""

from __future__ import annotations

import io
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Unpack

import numpy as np

from calib_core.streamed import MedianStep
from pipelines.ingest.cdr import IMU_LAYOUT, NS, BadMessageError, gather
from pipelines.ingest.data_format import FormatSpec, extra_keys
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import MIN_RATE_HZ, LogSource, check_samples, choose_source
from pipelines.ingest.rosbag_reader import (
    IMU,
    KEYS,
    ROS1_MAGIC,
    TEMPERATURE,
    bag_kind,
    imu_values,
    ros1_types,
    topic_connections,
)
from pipelines.ingest.streamed_pass import (
    HashingTee,
    SampleSink,
    Streamed,
    StreamOptions,
    streamed_pass,
)

OP_MSGDATA, OP_BAGHEADER, OP_IDXDATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
INDEX_ENTRY = np.dtype([("sec", "<u4"), ("nsec", "<u4"), ("offset", "<u4")])  # IDXDATA's


class _Bag:
    """One pass over a ROS 1 bag: its index first, then its chunks; the IMU messages of
    each chunk decoded and handed to `SampleSink`."""

    def __init__(self, path: Path, f: HashingTee, stamp: str, sink: SampleSink, max_chunk: int):
        self.path, self.f, self.stamp, self.sink = path, f, stamp, sink
        self.max_chunk = max_chunk  # bytes: a larger decompressed chunk is refused
        self.connections: list[Any] = []  # rosbags Connection, from the index
        self.expected: dict[int, int] = {}  # messages per connection, from the index
        self.chunk_infos: list[tuple[int, int]] = []  # (byte, connections) of each chunk
        self.imu: dict[int, Any] = {}  # the IMU topic's connections by id
        self.deserialize: Any = None
        self.topic: str | None = None  # the IMU topic
        self.last_log: int | None = None  # ns, the previous chunk's last IMU log time
        self.last_t: float | None = None  # s, the previous message's time
        self.t0: int | None = None  # ns, the first stamp (the time base)
        self.read = 0  # IMU messages read

    # --- records -----------------------------------------------------------------

    def _record(self, f: Any = None) -> tuple[Any, int]:
        """The header fields and data length of the record at the position of `f` (default:
        the pass's tee)."""
        from rosbags.rosbag1.reader import read_uint32

        f = self.f if f is None else f
        return self._header(f), read_uint32(f)

    def _header(self, f: Any = None) -> Any:
        """rosbags' parse of the record header here, its length checked before it is read."""
        from rosbags.rosbag1.reader import Header, read_uint32

        f = self.f if f is None else f
        length = read_uint32(f)
        return Header.read(io.BytesIO(length.to_bytes(4, "little") + self._bytes(length, f)))

    def _bytes(self, n: int, f: Any = None) -> bytes:
        """The next `n` bytes; a length beyond what the limit allows is a damaged field (or
        a record too large for the limit), refused before it is read."""
        from rosbags.rosbag1.reader import read_bytes

        f = self.f if f is None else f
        if n > self.max_chunk:
            at = f.at if isinstance(f, HashingTee) else f.tell()
            raise IngestError(
                f"a record near byte {at} declares {n} bytes, more than the memory "
                f"limit allows ({self.max_chunk}): a damaged bag, or raise the memory limit",
                file=self.path,
            )
        return read_bytes(f, n)

    def header(self, size: int) -> tuple[int, int, int]:
        """The bag header: where the index starts, how many connections and chunks it lists."""
        if self.f.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
            raise IngestError("not a ROS 1 bag: expected '#ROSBAG V2.0'", file=self.path)
        fields, length = self._record()
        if fields.get_uint8("op") != OP_BAGHEADER:
            raise IngestError("damaged bag: no bag header record after the magic", file=self.path)
        index_pos, chunks = fields.get_uint64("index_pos"), fields.get_uint32("chunk_count")
        self.f.seek(length, 1)  # the header's padding
        if index_pos == 0:
            raise IngestError(
                "the bag is not indexed (its recording did not end cleanly); "
                "run `rosbag reindex` on it first",
                file=self.path,
            )
        if index_pos > size:
            raise IngestError(
                f"truncated: the bag's index is at byte {index_pos}, the file has {size} bytes",
                file=self.path,
            )
        return index_pos, fields.get_uint32("conn_count"), chunks

    def index(self, conn_count: int, chunk_count: int) -> None:
        """The connections and per-chunk message counts of the index (read ahead: the
        tee hashes these bytes when the pass reaches them)."""
        from rosbags.interfaces import (
            Connection,
            ConnectionExtRosbag1,
            MessageDefinition,
            MessageDefinitionFormat,
        )
        from rosbags.rosbag1.reader import normalize
        from rosbags.typesys.msg import normalize_msgtype

        for _ in range(conn_count):
            # its data is a second header, its length the data's length
            fields, f = self._header(), self._header()
            if fields.get_uint8("op") != OP_CONNECTION:
                raise IngestError("damaged index: expected a connection record", file=self.path)
            conn, topic = fields.get_uint32("conn"), normalize(fields.get_string("topic"))
            msgdef = MessageDefinition(
                MessageDefinitionFormat.MSG, f.get_string("message_definition")
            )
            self.connections.append(
                Connection(
                    conn,
                    topic,
                    normalize_msgtype(f.get_string("type")),
                    msgdef,
                    f.get_string("md5sum"),
                    0,
                    ConnectionExtRosbag1(None, None),
                    None,
                )
            )
        for _ in range(chunk_count):
            fields, length = self._record()
            if fields.get_uint8("op") != OP_CHUNK_INFO:
                raise IngestError("damaged index: expected a chunk info record", file=self.path)
            counts = np.frombuffer(self._bytes(length), "<u4").reshape(-1, 2)
            for conn, count in counts.tolist():
                self.expected[conn] = self.expected.get(conn, 0) + count
            self.chunk_infos.append((fields.get_uint64("chunk_pos"), len(counts)))

    def sources(self) -> list[LogSource]:
        """`rosbag_reader.bag_sources` without rosbags' whole index: one source per Imu
        topic, its rate from the median step of its log times, read from the index records
        after each chunk (a separate handle; the chunks' data is skipped, not read). Log
        times are sorted within a chunk; across chunks they are taken in file order (the
        chosen topic's going back is refused by the pass)."""
        topics = sorted({c.topic for c in self.connections if c.msgtype == IMU})
        of = {c.id: c.topic for c in self.connections if c.topic in topics}
        steps = {topic: MedianStep() for topic in topics}
        counts = dict.fromkeys(topics, 0)
        has_temp = any(c.msgtype == TEMPERATURE for c in self.connections)
        with self.path.open("rb") as fh:
            for pos, n in self.chunk_infos:
                fh.seek(pos)
                fields, length = self._record(fh)
                if fields.get_uint8("op") != OP_CHUNK:
                    raise IngestError(f"damaged index: no chunk at byte {pos}", file=self.path)
                fh.seek(length, 1)
                times: dict[str, list[np.ndarray]] = {topic: [] for topic in topics}
                for _ in range(n):
                    fields, length = self._record(fh)
                    conn = fields.get_uint32("conn")
                    if fields.get_uint8("op") != OP_IDXDATA or conn not in of:
                        fh.seek(length, 1)
                        continue
                    entry = np.frombuffer(self._bytes(length, fh), INDEX_ENTRY)
                    times[of[conn]].append(entry["sec"].astype(np.int64) * NS + entry["nsec"])
                for topic, parts in times.items():
                    if parts:  # in log-time order, as rosbags merges a topic's connections
                        ns = np.sort(np.concatenate(parts), kind="stable")
                        steps[topic].push(ns / NS)
                        counts[topic] += len(ns)
        return [
            LogSource(t, t, counts[t], _rate(steps[t]) if counts[t] > 1 else None, has_temp)
            for t in topics
        ]

    def choose(
        self, imu_topic: str | None, temperature_topic: str | None, min_rate_hz: float
    ) -> None:
        """The IMU topic's connections, as the in-memory reader chooses them (of several
        Imu topics and none named, the fastest: `sources`, `log_samples.choose_source`)."""
        bag = SimpleNamespace(connections=self.connections)
        if imu_topic is None and len({c.topic for c in self.connections if c.msgtype == IMU}) > 1:
            chosen = choose_source(
                self.path, self.sources(), min_rate_hz=min_rate_hz, field="format.imu_topic"
            )
            imu_topic = str(chosen.key)
        conns = topic_connections(bag, self.path, IMU, imu_topic, "imu_topic", True)
        temps = topic_connections(
            bag, self.path, TEMPERATURE, temperature_topic, "temperature_topic", False
        )
        if temps:
            raise IngestError(
                f"the bag's temperature topic {temps[0].topic} is interpolated onto the whole "
                "IMU time base, which a record read in chunks does not hold (raise the memory "
                "limit to read it into memory)",
                file=self.path,
                field="format.temperature_topic",
            )
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.ROS1_NOETIC)
        md5 = store.generate_msgdef("sensor_msgs/msg/Imu")[1]
        own = get_typestore(Stores.EMPTY)
        for c in conns:
            if c.digest != md5:
                raise IngestError(
                    f"topic {c.topic}'s message definition is not sensor_msgs/Imu's (md5 "
                    f"{c.digest}, expected {md5}); raise the memory limit to read it with "
                    "its own definition",
                    file=self.path,
                    field=c.topic,
                )
            own.register(ros1_types(c))
        self.imu = {c.id: c for c in conns}
        self.deserialize = own.deserialize_ros1
        self.topic = self.sink.topic = conns[0].topic

    # --- the pass ----------------------------------------------------------------

    def chunks(self, index_pos: int) -> None:
        """Every record from here to the index: chunks and their index records."""
        chunk: tuple[int, bytes] | None = None
        entries: list[np.ndarray] = []
        conns: list[int] = []
        while self.f.at < index_pos:
            pos = self.f.at
            fields, length = self._record()
            op = fields.get_uint8("op")
            if op == OP_CHUNK:
                if chunk is not None:
                    self._decode(*chunk, entries, conns)
                chunk, entries, conns = self._chunk(fields, length, pos), [], []
            elif op == OP_IDXDATA:
                conn, count = fields.get_uint32("conn"), fields.get_uint32("count")
                if length != 12 * count:
                    raise IngestError(
                        f"damaged index record at byte {pos}: {length} bytes for {count} messages",
                        file=self.path,
                    )
                if conn in self.imu:
                    entries.append(np.frombuffer(self._bytes(length), INDEX_ENTRY))
                    conns.append(conn)
                else:
                    self.f.seek(length, 1)
            else:
                self.f.seek(length, 1)  # connection records outside chunks, ...
        if self.f.at != index_pos:
            raise IngestError(
                f"damaged bag: a record runs past the index at byte {index_pos}", file=self.path
            )
        if chunk is not None:
            self._decode(*chunk, entries, conns)

    def _chunk(self, fields: Any, length: int, pos: int) -> tuple[int, bytes]:
        """A chunk record's data, decompressed."""
        from rosbags.rosbag1.reader import decompressors

        size, compression = fields.get_uint32("size"), fields.get_string("compression")
        if size > self.max_chunk:
            raise IngestError(
                f"chunk at byte {pos} holds {size} bytes uncompressed, more than the memory "
                f"limit allows ({self.max_chunk}); raise the memory limit",
                file=self.path,
            )
        if compression not in decompressors:
            raise IngestError(
                f"chunk at byte {pos} uses compression {compression!r}; expected none, bz2 or lz4",
                file=self.path,
            )
        data = decompressors[compression](self._bytes(length))
        if len(data) != size:
            raise IngestError(
                f"damaged chunk at byte {pos}: {len(data)} bytes decompressed, its header says "
                f"{size}",
                file=self.path,
            )
        return pos, data

    def _decode(self, pos: int, buf: bytes, entries: list[np.ndarray], conns: list[int]) -> None:
        """The chunk's IMU messages, in log-time order, to the sink."""
        if not entries:
            return
        index = np.concatenate(entries)
        conn = np.repeat(np.array(conns, np.uint32), [len(e) for e in entries])
        log = index["sec"].astype(np.int64) * NS + index["nsec"]
        order = np.argsort(log, kind="stable")  # the in-memory reader's merge by log time
        index, conn, log = index[order], conn[order], log[order]
        topic = self.topic
        if self.last_log is not None and log[0] < self.last_log:
            raise IngestError(
                f"{topic}: the log time of the chunk at byte {pos} goes back before the "
                "previous chunk's; a record read in chunks keeps the file's order (raise the "
                "memory limit to read it into memory, where messages are sorted)",
                file=self.path,
                field=topic,
            )
        self.last_log = int(log[-1])
        try:
            start, length = self._messages(buf, index, conn)
            part = self._imu(buf, start, length, log)
        except BadMessageError as bad:
            raise IngestError(
                f"{topic} message {self.read + bad.index}: cannot decode ({bad.problem}; "
                f"chunk at byte {pos})",
                file=self.path,
                field=topic,
            ) from None
        t0 = self.t0 = part["stamp"][0] if self.t0 is None else self.t0
        t = (part["stamp"] - t0) / NS + t0 / NS  # the in-memory reader's time base
        check_samples(
            self.path,
            topic,
            t,
            {"acc": part["acc"], "gyr": part["gyr"]},
            offset=self.read,
            last=self.last_t,
        )
        self.last_t = float(t[-1])
        self.read += len(t)
        self.sink.push(part)

    def _messages(
        self, buf: bytes, index: np.ndarray, conn: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Where each indexed message's data lies in the chunk, its record header checked
        against the index (op, connection, time); every record laid out as the first."""
        arr = np.frombuffer(buf, np.uint8)
        off = index["offset"].astype(np.int64)
        beyond = off + 8 > len(buf)
        if beyond.any():
            raise BadMessageError(int(np.flatnonzero(beyond)[0]), "offset beyond the chunk")
        head = gather(arr, off, "<u4").astype(np.int64)
        where = _field_offsets(buf, int(off[0]), int(head[0]))
        ok = head == head[0]
        if (
            ok.all()
            and {"op", "conn", "time"} <= where.keys()
            and off.max() + 8 + head[0] <= len(buf)
        ):
            base = off + 4
            ok &= arr[base + where["op"]] == OP_MSGDATA
            ok &= gather(arr, base + where["conn"], "<u4") == conn
            ok &= gather(arr, base + where["time"], "<u4") == index["sec"]
            ok &= gather(arr, base + where["time"] + 4, "<u4") == index["nsec"]
        else:
            ok[:] = False
        if not ok.all():
            raise BadMessageError(
                int(np.flatnonzero(~ok)[0]), "its record does not match the index"
            )
        length = gather(arr, off + 4 + head, "<u4").astype(np.int64)
        start = off + 8 + head
        short = start + length > len(buf)
        if short.any():
            raise BadMessageError(int(np.flatnonzero(short)[0]), "runs past the end of its chunk")
        return start, length

    def _imu(
        self, buf: bytes, start: np.ndarray, length: np.ndarray, log: np.ndarray
    ) -> dict[str, np.ndarray]:
        """sensor_msgs/Imu messages decoded at once: stamp (ns), gyr, acc; the first one
        compared with rosbags' decoding by the bag's definition."""
        arr = np.frombuffer(buf, np.uint8)
        short = length < 16
        if short.any():
            raise BadMessageError(int(np.flatnonzero(short)[0]), "too short for a Header")
        strlen = gather(arr, start + 12, "<u4").astype(np.int64)
        wrong = length != 16 + strlen + IMU_LAYOUT.size
        if wrong.any():
            k = int(np.flatnonzero(wrong)[0])
            raise BadMessageError(
                k, f"{length[k]} bytes, sensor_msgs/Imu with this frame_id has "
                f"{16 + strlen[k] + IMU_LAYOUT.size}"
            )  # fmt: skip
        rest = start + 16 + strlen
        part = {key: gather(arr, rest + o, "<f8", n) for key, (o, n) in IMU_LAYOUT.fields.items()}
        if self.stamp == "header":
            part["stamp"] = gather(arr, start + 4, "<u4").astype(np.int64) * NS + gather(
                arr, start + 8, "<u4"
            )
        else:
            part["stamp"] = log
        msgtype = next(iter(self.imu.values())).msgtype
        try:
            msg = self.deserialize(buf[start[0] : start[0] + length[0]], msgtype)
        except Exception as exc:  # what the in-memory reader reports for such a message
            raise BadMessageError(0, f"{type(exc).__name__}: {exc}") from None
        stamp = msg.header.stamp.sec * NS + msg.header.stamp.nanosec
        ours = np.concatenate([part["acc"][0], part["gyr"][0]])
        same = np.array_equal(np.array(imu_values(msg), float), ours, equal_nan=True)
        if not same or (self.stamp == "header" and stamp != part["stamp"][0]):
            raise BadMessageError(0, "its fields differ from rosbags' decoding of it")
        return part

    def check_counts(self) -> None:
        """The IMU messages read against the index's count (a damaged bag differs)."""
        want = sum(self.expected.get(c, 0) for c in self.imu)
        if self.read != want:
            topic = self.topic or "?"
            raise IngestError(
                f"{topic}: {self.read} messages read but the bag's index counts {want} "
                "(damaged bag?)",
                file=self.path,
                field=topic,
            )


def _field_offsets(buf: bytes, pos: int, size: int) -> dict[str, int]:
    """Where each field's value of the record header at `pos` lies, in bytes from the end
    of the header's length (fields ``name=value`` each after its uint32 length)."""
    out, at = {}, 0
    while at + 4 <= size:
        n = int.from_bytes(buf[pos + 4 + at : pos + 8 + at], "little")
        name, sep, _ = buf[pos + 8 + at : pos + 8 + at + n].partition(b"=")
        if sep:
            out[name.decode(errors="replace")] = at + 4 + len(name) + 1
        at += 4 + n
    return out


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
        ``min_rate_hz`` as `rosbag_reader.read_rosbag`; a temperature or table topic
        is refused).
    samples : the Parquet file to write (columns segment, t, acc_*, gyr_*, temp; SI;
        t in Unix s; temp NaN).
    options : `streamed_pass.StreamOptions` (raw copy, label, memory limit: the rows per
        batch and the largest chunk accepted, a quarter of it; progress, time window).

    Returns
    -------
    Streamed (`streamed_pass`).

    Raises
    ------
    IngestError naming the file: not a ROS 1 bag (a ROS 2 .db3 is refused with the
    reason), not indexed, truncated or damaged; the IMU topic absent, ambiguous or
    below ``min_rate_hz``; a message that does not decode, a non-finite or impossible
    value, a stamp not after the previous one (records numbered in the whole topic).
    """
    path = Path(path)
    keys = {"stamp": "header", **extra_keys(fmt, "rosbag", KEYS)}
    if keys["stamp"] not in ("header", "log"):
        raise IngestError(
            f"stamp must be 'header' or 'log', got {keys['stamp']!r}", field="format.stamp"
        )
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
        bag = walk(path, run.tee, keys, run.sink, run.memory_limit, run.size)
        run.sink.finish()
        run.tee.drain()
    check_rate(path, bag, run.sink, keys.get("min_rate_hz", MIN_RATE_HZ))
    return run.result()


def walk(
    path: Path,
    tee: HashingTee,
    keys: dict[str, Any],
    sink: SampleSink,
    memory_limit: int,
    size: int,
) -> _Bag:
    """The bag's header, index and chunks, read through `tee`; rosbags' errors on a
    truncated or damaged record named with the byte where the record starts."""
    from rosbags.rosbag1.reader import ReaderError

    # a chunk, its decompressed copy and their decoded arrays: a quarter of the limit
    bag = _Bag(path, tee, keys["stamp"], sink, memory_limit // 4)
    try:
        index_pos, conn_count, chunk_count = bag.header(size)
        start = tee.at
        tee.seek(index_pos)
        bag.index(conn_count, chunk_count)
        tee.seek(start)
        bag.choose(
            keys.get("imu_topic"),
            keys.get("temperature_topic"),
            keys.get("min_rate_hz", MIN_RATE_HZ),
        )
        bag.chunks(index_pos)
    except ReaderError as exc:
        raise IngestError(
            f"truncated or damaged bag near byte {tee.at} ({exc})", file=path
        ) from None
    bag.check_counts()
    return bag


def check_rate(path: Path, bag: _Bag, sink: SampleSink, min_rate_hz: float) -> None:
    """No samples, or a rate below `min_rate_hz`: the in-memory reader's refusals, with the
    rate from the exact median step of the first pass (`log_samples.stamp_rate`'s)."""
    topic = bag.topic or "?"
    if sink.done == 0:
        raise IngestError(f"{topic}: no samples", file=path, field=topic)
    rate = _rate(sink.steps or sink.first.step) if sink.done > 1 else None
    if rate is None or rate < min_rate_hz:
        choose_source(
            path,
            [LogSource(topic, topic, sink.done, rate, False)],
            min_rate_hz=min_rate_hz,
            field="format.imu_topic",
        )


def _rate(step: MedianStep) -> float | None:
    """Samples per second from the exact median step (`log_samples.stamp_rate`'s rule)."""
    median = step.median()
    return float(1.0 / median) if median > 0 else None
