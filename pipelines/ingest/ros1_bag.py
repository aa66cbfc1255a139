"""A ROS 1 bag (format 2.0) walked once, front to back: the one reader of the format.
`Ros1Bag.parts` yields each chunk's messages of the chosen topics, decoded;
`rosbag_reader.read_rosbag` joins them into a Recording, `rosbag_reader.stream_rosbag`
sends each to the samples' Parquet (the file read through `streamed_pass.HashingTee`).
rosbags' own reader holds a Python tuple per message of the bag's index (170 bytes each:
15 GB for a day at 1 kHz), so only its record header parser and deserialiser are used:

1. the bag header, the index at its end (connections, one record per chunk), then the
   chunks in file order. A bag cut while written (no whole index: `whole_records`) may
   be read to its last whole chunk, its index rebuilt from the whole chunks' own records
   (as ``rosbag reindex`` does), with the ``record:cut:<file>`` finding.
2. each chunk is decompressed (none, bz2, lz4) and held until its index records (which
   follow it) give each message's offset and log time, checked against the message's
   record header; a role's messages in log-time order, then by offset (rosbags' order).
3. ``sensor_msgs/Imu`` has a fixed layout once the header's ``frame_id`` length is known
   (`cdr.IMU_LAYOUT`, the same offsets in ROS 1's packed serialisation): a chunk's IMU
   messages are decoded at once by numpy gathers, its first one again by rosbags (they
   must agree). Other definitions and topics are decoded one by one (`message_part`).
"""

from __future__ import annotations

import io
import os
import struct
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calib_core.streamed import MedianStep
from pipelines.ingest.cdr import IMU_LAYOUT, NS, BadMessageError, gather
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import LogSource, cut_tail

MAGIC = b"#ROSBAG V2.0\n"
OP_MSGDATA, OP_BAGHEADER, OP_IDXDATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
INDEX_ENTRY = np.dtype([("sec", "<u4"), ("nsec", "<u4"), ("offset", "<u4")])  # IDXDATA's
IMU = "sensor_msgs/msg/Imu"
TEMPERATURE = "sensor_msgs/msg/Temperature"
COLUMNS = {"imu": (("acc", "gyr"), 6), "temp": (("temp",), 1), "table": (("angle", "rate"), 2)}
MAX_CHUNK = 1 << 30  # bytes: writers use ~1 MiB chunks; more is a damaged length field


@dataclass(frozen=True)
class Connection:
    """A bag's connection: its id, topic, message type (``pkg/msg/Name``), the message
    definition's text and md5."""

    id: int
    topic: str
    msgtype: str
    msgdef: str
    digest: str


def whole_records(path: Path) -> tuple[int, int, bool]:
    """(end, size, indexed): the byte where the first top-level record the file cuts short
    starts (`size` when none is), the file's size, and whether the bag holds its whole
    index (``index_pos`` inside the file, followed by as many whole records as the bag
    header's ``conn_count`` + ``chunk_count``). Only the records' length fields are read."""
    size = os.path.getsize(path)
    with Path(path).open("rb") as fh:
        fh.seek(len(MAGIC))
        header = rb().Header.read(fh)
        index_pos = header.get_uint64("index_pos")
        listed = header.get_uint32("conn_count") + header.get_uint32("chunk_count")
        pos = fh.tell()
        (padding,) = struct.unpack("<I", fh.read(4))
        pos += 4 + padding
        in_index = 0  # whole records from index_pos on
        while pos < size:
            fh.seek(pos)
            head = fh.read(4)
            if len(head) < 4 or pos + 8 + (hlen := struct.unpack("<I", head)[0]) > size:
                break
            fh.seek(hlen, os.SEEK_CUR)
            (dlen,) = struct.unpack("<I", fh.read(4))
            if pos + 8 + hlen + dlen > size:
                break
            in_index += 0 < index_pos <= pos
            pos += 8 + hlen + dlen
    return pos, size, pos == size and 0 < index_pos < size and in_index >= listed


def message_part(
    path: Path, role: str, msgs: Iterable[Any], joint: str | int = 0
) -> dict[str, np.ndarray]:
    """Messages decoded by rosbags (one role's, in order) as arrays: ``stamp`` (ns, header)
    and ``acc``, ``gyr`` (imu), ``temp`` (temp) or ``angle``, ``rate`` (table: the joint's
    position and velocity, NaN where a message has none)."""

    def values(m: Any) -> tuple[float, ...]:
        if role == "imu":
            a, w = m.linear_acceleration, m.angular_velocity
            return (a.x, a.y, a.z, w.x, w.y, w.z)
        if role == "temp":
            return (m.temperature,)
        names, k = list(m.name), joint
        if isinstance(joint, str):
            if joint not in names:
                raise IngestError(
                    f"joint {joint!r} not in {names}", file=path, field="format.table_joint"
                )
            k = names.index(joint)
        return tuple(v[k] if len(v) > k else np.nan for v in (m.position, m.velocity))

    rows = [(m.header.stamp.sec * NS + m.header.stamp.nanosec, *values(m)) for m in msgs]
    cols = np.array([r[1:] for r in rows], dtype=float).reshape(len(rows), COLUMNS[role][1])
    part = {"stamp": np.array([r[0] for r in rows], dtype=np.int64)}
    for i, key in enumerate(COLUMNS[role][0]):
        part[key] = np.ascontiguousarray(
            cols[:, 3 * i : 3 * i + 3] if role == "imu" else cols[:, i]
        )
    return part


def rate_of(step: MedianStep) -> float | None:
    """Samples per second from the exact median step (`log_samples.stamp_rate`'s rule)."""
    median = step.median()
    return float(1.0 / median) if median > 0 else None


def rb() -> Any:
    """rosbags' ROS 1 reader module, imported on first use (it takes 0.2 s)."""
    from rosbags.rosbag1 import reader

    return reader


class Ros1Bag:
    """One pass over a ROS 1 bag read from `f` (a file, or a `HashingTee`): `open`, then
    `select` the topics, then `parts` yields each chunk's decoded messages of each role.

    `max_chunk`: bytes; a larger record or decompressed chunk is refused before it is read.
    `stamp`: ``"header"`` (the message header's stamp) or ``"log"`` (the bag's log time).
    """

    def __init__(self, path: Path, f: Any, stamp: str, max_chunk: int = MAX_CHUNK):
        self.path, self.f, self.stamp, self.max_chunk = path, f, stamp, max_chunk
        self.connections: list[Connection] = []
        self.expected: dict[int, int] = {}  # messages per connection, from the index
        self.chunk_infos: list[tuple[int, int]] = []  # (byte, connections) of each chunk
        self.rebuilt: dict[int, dict[int, np.ndarray]] | None = None  # a cut bag's index
        self.findings: tuple[dict, ...] = ()
        self.start = self.end = 0  # the first record after the bag header; the pass's end
        self.roles: dict[int, str] = {}  # the chosen connections' roles (imu, temp, table)
        self.topics: dict[str, str] = {}  # role -> topic
        self.read: dict[str, int] = {}  # messages decoded per role
        self.fast = False  # the IMU topic has sensor_msgs/Imu's definition: vectorised
        self.joint: str | int = 0
        self.deserialize: Callable[[bytes, str], Any] | None = None
        self.msgtypes: dict[int, str] = {}

    def error(self, problem: str, field: str | None = None) -> IngestError:
        """The IngestError of `problem` in this bag (at `field`: a topic, a manifest key)."""
        return IngestError(problem, file=self.path, field=field)

    # --- records -----------------------------------------------------------------

    def _record(self, f: Any = None) -> tuple[Any, int]:
        """The header fields and data length of the record at the position of `f`."""
        f = self.f if f is None else f
        return self._header(f), rb().read_uint32(f)

    def _header(self, f: Any = None) -> Any:
        """rosbags' parse of the record header here, its length checked before it is read."""
        f = self.f if f is None else f
        length = rb().read_uint32(f)
        return rb().Header.read(io.BytesIO(length.to_bytes(4, "little") + self._bytes(length, f)))

    def _bytes(self, n: int, f: Any = None) -> bytes:
        """The next `n` bytes; a length beyond `max_chunk` is a damaged field (or a record
        too large for the memory limit), refused before it is read."""
        f = self.f if f is None else f
        if n > self.max_chunk:
            raise self.error(
                f"a record near byte {f.tell()} declares {n} bytes, more than the memory "
                f"limit allows ({self.max_chunk}): a damaged bag, or raise the memory limit"
            )
        return rb().read_bytes(f, n)

    def _connection(self, fields: Any, f: Any = None) -> Connection:
        """A connection record's (its data is a second header)."""
        data = self._header(f)
        return Connection(
            fields.get_uint32("conn"),
            rb().normalize(fields.get_string("topic")),
            rb().normalize_msgtype(data.get_string("type")),
            data.get_string("message_definition"),
            data.get_string("md5sum"),
        )

    @contextmanager
    def named(self) -> Iterator[None]:
        """rosbags' error (ReaderError; struct, unicode errors) on a truncated or damaged
        record as the IngestError naming the file and the byte reached."""
        try:
            yield
        except IngestError:
            raise
        except Exception as exc:
            raise self.error(
                f"truncated or damaged bag near byte {self.f.tell()} ({type(exc).__name__}: {exc})"
            ) from None

    # --- the bag header and the index ----------------------------------------------

    def open(self, size: int, cut_ok: bool) -> None:
        """The bag header and the index (or, `cut_ok`, a cut bag's index rebuilt; else
        refused)."""
        with self.named():
            if self.f.read(len(MAGIC)) != MAGIC:
                raise self.error("not a ROS 1 bag: expected '#ROSBAG V2.0'")
            fields, length = self._record()
            if fields.get_uint8("op") != OP_BAGHEADER:
                raise self.error("damaged bag: no bag header record after the magic")
            index_pos = fields.get_uint64("index_pos")
            self.f.seek(length, 1)  # the header's padding
            self.start = self.f.tell()
            if cut_ok and not (ends := whole_records(self.path))[2]:
                self.end = ends[0]
                # no index is a bag cut while written, even at a record boundary
                self.findings = (cut_tail(self.path, "ROS 1 bag", ends[0], size - ends[0], size),)
                self._rebuild()
                self.f.seek(self.start)
                return
            if index_pos == 0:
                raise self.error(
                    "the bag is not indexed (its recording did not end cleanly); "
                    "run `rosbag reindex` on it first"
                )
            if index_pos > size:
                raise self.error(
                    f"truncated: the bag's index is at byte {index_pos}, the file has {size} bytes"
                )
            self.end = index_pos
            self.f.seek(index_pos)  # read ahead: a tee hashes it when the pass gets there
            self._index(fields.get_uint32("conn_count"), fields.get_uint32("chunk_count"))
            self.f.seek(self.start)

    def _index(self, conn_count: int, chunk_count: int) -> None:
        """The connections and per-chunk message counts of the index."""
        for _ in range(conn_count):
            fields = self._header()
            if fields.get_uint8("op") != OP_CONNECTION:
                raise self.error("damaged index: expected a connection record")
            self.connections.append(self._connection(fields))
        for _ in range(chunk_count):
            fields, length = self._record()
            if fields.get_uint8("op") != OP_CHUNK_INFO:
                raise self.error("damaged index: expected a chunk info record")
            counts = np.frombuffer(self._bytes(length), "<u4").reshape(-1, 2)
            for conn, count in counts.tolist():
                self.expected[conn] = self.expected.get(conn, 0) + count
            self.chunk_infos.append((fields.get_uint64("chunk_pos"), len(counts)))

    def _rebuild(self) -> None:
        """A cut bag's connections and message index from its records before `end`."""
        conns: dict[int, Connection] = {}
        self.rebuilt = {}
        while (pos := self.f.tell()) < self.end:
            try:
                fields, length = self._record()
                op = fields.get_uint8("op")
                if op == OP_CONNECTION:
                    self.f.seek(-4, 1)  # the data length is the second header's
                    conn = self._connection(fields)
                    conns.setdefault(conn.id, conn)
                    continue
            except Exception as exc:  # rosbags' ReaderError, struct, unicode errors: damage
                raise self.error(
                    f"damaged ROS 1 bag: the record at byte offset {pos} does not parse ({exc})"
                ) from None
            if op == OP_CHUNK:
                self.rebuilt[pos] = self._chunk_records(
                    pos, self._chunk(fields, length, pos), conns
                )
            else:
                self.f.seek(length, 1)  # index data, chunk info: rebuilt from the chunks
        self.connections = list(conns.values())
        for entries in self.rebuilt.values():
            for conn, e in entries.items():
                self.expected[conn] = self.expected.get(conn, 0) + len(e)

    def _chunk_records(self, pos: int, data: bytes, conns: dict) -> dict[int, np.ndarray]:
        """The index entries of the whole chunk at byte `pos` from its own records (its
        connection records added to `conns`)."""
        buf, found = io.BytesIO(data), defaultdict(list)
        try:
            while (at := buf.tell()) < len(data):
                fields, length = self._record(buf)
                op = fields.get_uint8("op")
                if op == OP_CONNECTION:
                    buf.seek(-4, 1)
                    conn = self._connection(fields, buf)
                    conns.setdefault(conn.id, conn)
                    continue
                if op == OP_MSGDATA:
                    conn_id = fields.get_uint32("conn")
                    if conn_id not in conns:
                        raise rb().ReaderError(f"a message of connection {conn_id}, never defined")
                    found[conn_id].append((*struct.unpack("<II", fields["time"]), at))
                buf.seek(length, os.SEEK_CUR)
            if buf.tell() != len(data):
                raise rb().ReaderError("a record runs past the chunk's end")
        except Exception as exc:  # rosbags' ReaderError, struct, unicode errors: damage
            raise self.error(
                f"damaged ROS 1 bag: the records of the chunk at byte offset {pos} do not "
                f"follow each other ({exc})"
            ) from None
        return {c: np.array(rows, INDEX_ENTRY) for c, rows in found.items()}

    def _chunk_index(self) -> Iterator[dict[int, list[np.ndarray]]]:
        """Each chunk's index entries by connection: rebuilt, or the index records after
        each chunk (a separate handle; the chunks' data is skipped, not read)."""
        if self.rebuilt is not None:
            yield from ({c: [e] for c, e in ents.items()} for ents in self.rebuilt.values())
            return
        with self.path.open("rb") as fh, self.named():
            for pos, n in self.chunk_infos:
                fh.seek(pos)
                fields, length = self._record(fh)
                if fields.get_uint8("op") != OP_CHUNK:
                    raise self.error(f"damaged index: no chunk at byte {pos}")
                fh.seek(length, 1)
                entries = defaultdict(list)
                for _ in range(n):
                    fields, length = self._record(fh)
                    if fields.get_uint8("op") != OP_IDXDATA:
                        fh.seek(length, 1)
                        continue
                    entries[fields.get_uint32("conn")].append(
                        np.frombuffer(self._bytes(length, fh), INDEX_ENTRY)
                    )
                yield entries

    def sources(self) -> list[LogSource]:
        """One source per Imu topic, its rate from the median step of its log times (no
        message is decoded). Log times are sorted within a chunk; across chunks taken in
        file order."""
        topics = sorted({c.topic for c in self.connections if c.msgtype == IMU})
        of = {c.id: c.topic for c in self.connections if c.topic in topics}
        steps = {topic: MedianStep() for topic in topics}
        counts = dict.fromkeys(topics, 0)
        has_temp = any(c.msgtype == TEMPERATURE for c in self.connections)
        for entries in self._chunk_index():
            times: dict[str, list[np.ndarray]] = {topic: [] for topic in topics}
            for conn, parts in entries.items():
                if conn in of:
                    e = np.concatenate(parts)
                    times[of[conn]].append(e["sec"].astype(np.int64) * NS + e["nsec"])
            for topic, parts in times.items():
                if parts:  # in log-time order, as rosbags merges a topic's connections
                    ns = np.sort(np.concatenate(parts), kind="stable")
                    steps[topic].push(ns / NS)
                    counts[topic] += len(ns)
        return [
            LogSource(t, t, counts[t], rate_of(steps[t]) if counts[t] > 1 else None, has_temp)
            for t in topics
        ]

    def select(self, chosen: dict[str, list[Connection]], joint: str | int = 0) -> None:
        """The connections to decode, by role (``imu``, ``temp``, ``table``); rosbags'
        deserialiser of the bag's own definitions of them."""
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        md5 = get_typestore(Stores.ROS1_NOETIC).generate_msgdef("sensor_msgs/msg/Imu")[1]
        own = get_typestore(Stores.EMPTY)
        for role, conns in chosen.items():
            for c in conns:
                self.roles[c.id], self.msgtypes[c.id] = role, c.msgtype
                try:
                    own.register(get_types_from_msg(c.msgdef, c.msgtype))
                except Exception as exc:  # rosbags' TypesysError on a damaged definition
                    raise self.error(
                        f"topic {c.topic}: its message definition does not parse "
                        f"({type(exc).__name__}: {exc})",
                        c.topic,
                    ) from None
            self.topics[role], self.read[role] = conns[0].topic, 0
        self.fast = all(c.digest == md5 for c in chosen["imu"])
        self.deserialize, self.joint = own.deserialize_ros1, joint

    # --- the pass ----------------------------------------------------------------

    def parts(self) -> Iterator[tuple[str, int, dict[str, np.ndarray]]]:
        """(role, the chunk's byte, its messages: ``log`` and ``stamp`` ns and the role's
        values) of every chunk in file order, from the start of the records to the index
        (or the cut)."""
        chunk: tuple[int, bytes] | None = None
        entries: dict[int, list[np.ndarray]] = defaultdict(list)
        with self.named():
            while (pos := self.f.tell()) < self.end:
                fields, length = self._record()
                op = fields.get_uint8("op")
                if op == OP_CHUNK:
                    if chunk is not None:
                        yield from self._decode(*chunk, entries)
                    chunk, entries = (pos, self._chunk(fields, length, pos)), defaultdict(list)
                    if self.rebuilt is not None:
                        entries.update((c, [e]) for c, e in self.rebuilt[pos].items())
                elif op == OP_IDXDATA and self.rebuilt is None:
                    conn, count = fields.get_uint32("conn"), fields.get_uint32("count")
                    if length != 12 * count:
                        raise self.error(
                            f"damaged index record at byte {pos}: {length} bytes for "
                            f"{count} messages"
                        )
                    if conn in self.roles:
                        entries[conn].append(np.frombuffer(self._bytes(length), INDEX_ENTRY))
                    else:
                        self.f.seek(length, 1)
                else:
                    self.f.seek(length, 1)  # connection records outside chunks, ...
            if self.f.tell() != self.end:
                raise self.error(f"damaged bag: a record runs past the index at byte {self.end}")
            if chunk is not None:
                yield from self._decode(*chunk, entries)

    def _chunk(self, fields: Any, length: int, pos: int) -> bytes:
        """A chunk record's data, decompressed."""
        size, compression = fields.get_uint32("size"), fields.get_string("compression")
        if size > self.max_chunk:
            raise self.error(
                f"chunk at byte {pos} holds {size} bytes uncompressed, more than the memory "
                f"limit allows ({self.max_chunk}); raise the memory limit"
            )
        if compression not in rb().decompressors:
            raise self.error(
                f"chunk at byte {pos} uses compression {compression!r}; expected none, bz2 or lz4"
            )
        raw = self._bytes(length)
        try:
            data = rb().decompressors[compression](raw)
        except Exception as exc:  # a damaged compressed block: bz2, lz4 raise their own
            raise self.error(
                f"damaged chunk at byte {pos}: it does not decompress ({type(exc).__name__}: {exc})"
            ) from None
        if len(data) != size:
            raise self.error(
                f"damaged chunk at byte {pos}: {len(data)} bytes decompressed, its header says "
                f"{size}"
            )
        return data

    def _decode(
        self, pos: int, buf: bytes, entries: dict[int, list[np.ndarray]]
    ) -> Iterator[tuple[str, int, dict[str, np.ndarray]]]:
        """The chunk's messages of each role, in log-time order."""
        by_role: dict[str, list[int]] = defaultdict(list)
        for conn in entries:
            if conn in self.roles:
                by_role[self.roles[conn]].append(conn)
        for role, conns in by_role.items():
            parts = [np.concatenate(entries[c]) for c in conns]
            index = np.concatenate(parts)
            conn = np.repeat(np.array(conns, np.uint32), [len(p) for p in parts])
            log = index["sec"].astype(np.int64) * NS + index["nsec"]
            order = np.lexsort((index["offset"], log))  # rosbags' merge by log time
            index, conn, log = index[order], conn[order], log[order]
            topic = self.topics[role]
            try:
                start, length = self._messages(buf, index, conn)
                if role == "imu" and self.fast:
                    part = self._imu(buf, start, length)
                else:
                    part = message_part(self.path, role, self._each(buf, start, length, conn))
            except BadMessageError as bad:
                raise self.error(
                    f"{topic} message {self.read[role] + bad.index}: cannot decode "
                    f"({bad.problem}; chunk at byte {pos})",
                    topic,
                ) from None
            part["log"] = log
            if self.stamp == "log":
                part["stamp"] = log
            self.read[role] += len(log)
            yield role, pos, part

    def _each(self, buf: bytes, start: np.ndarray, length: np.ndarray, conn: np.ndarray):
        """The messages decoded one at a time by rosbags."""
        assert self.deserialize is not None
        rows = zip(start.tolist(), length.tolist(), conn.tolist(), strict=True)
        for k, (s, n, c) in enumerate(rows):
            try:
                yield self.deserialize(buf[s : s + n], self.msgtypes[c])
            except Exception as exc:  # rosbags raises assorted errors on a bad message
                raise BadMessageError(k, f"{type(exc).__name__}: {exc}") from None

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
        where = field_offsets(buf, int(off[0]), int(head[0]))
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

    def _imu(self, buf: bytes, start: np.ndarray, length: np.ndarray) -> dict[str, np.ndarray]:
        """sensor_msgs/Imu messages decoded at once: stamp (ns, header), gyr, acc; the
        first one compared with rosbags' decoding by the bag's definition."""
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
        part["stamp"] = gather(arr, start + 4, "<u4").astype(np.int64) * NS + gather(
            arr, start + 8, "<u4"
        )
        imu = next(c for c, role in self.roles.items() if role == "imu")
        (msg,) = self._each(buf, start[:1], length[:1], np.array([imu]))
        first = message_part(self.path, "imu", [msg])
        same = all(np.array_equal(first[k][0], part[k][0], equal_nan=True) for k in first)
        if not same:
            raise BadMessageError(0, "its fields differ from rosbags' decoding of it")
        return part

    def check_counts(self) -> None:
        """The IMU messages read against the index's count (a damaged bag differs)."""
        topic = self.topics.get("imu", "?")
        want = sum(self.expected.get(c, 0) for c, role in self.roles.items() if role == "imu")
        if self.read.get("imu", 0) != want:
            raise self.error(
                f"{topic}: {self.read.get('imu', 0)} messages read but the bag's index counts "
                f"{want} (damaged bag?)",
                topic,
            )


def field_offsets(buf: bytes, pos: int, size: int) -> dict[str, int]:
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
