"""MCAP (ROS 2) reader -> Recording, with a vectorised CDR decoder for the IMU.

A ROS 2 lab log holds ``sensor_msgs/msg/Imu`` at 100 Hz .. 2 kHz, often for
hours, plus ``sensor_msgs/msg/Temperature`` and rate-table feedback
(``sensor_msgs/msg/JointState`` or a JSON channel). Decoding one Python object
per message (mcap-ros2-support) makes a 1 kHz hour-long log take minutes; so
this reader never builds a per-message object for the IMU:

1. Records are read straight from the file, one chunk at a time (bounded
   memory): a Python loop only hops from record header to record header
   inside a decompressed chunk; everything else is numpy over the chunk.
   (mcap's own record iterator builds a Python object per record and per
   message-index entry, which caps its speed.)
2. ``sensor_msgs/msg/Imu`` in CDR has a fixed layout once the header's
   variable-length ``frame_id`` is known, so every message of a chunk is decoded
   at once by numpy gathers (pipelines.ingest.cdr).
3. The low-rate channels (temperature is decoded the same way; JointState with
   mcap-ros2-support's decoder; JSON with the json module) are interpolated
   onto the IMU time base.

Times are Unix seconds (float64) from either the message header stamp or the
MCAP log time (``stamp``). Reference channels: JointState position -> ``table_angle``
(rad, unwrapped so a table that reports 0..2 pi gives a continuous angle) and
velocity -> ``table_rate`` (rad/s); a JSON channel gives the same from its
fields ``angle`` (rad) and ``rate`` (rad/s), stamped by its optional field
``stamp`` (Unix seconds) when ``stamp="header"``, else by the log time.
Outside a reference channel's time span the interpolation holds its first /
last value.

The module is ~650 lines because one class, `McapReader`, holds the chunk-by-chunk
state (channels, pending records, statistics) that its methods share; record-level
helpers are in pipelines.ingest.mcap_records, the CDR decoder in pipelines.ingest.cdr.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Unpack

import numpy as np

from calib_core.recording import Recording
from pipelines.ingest.cdr import (
    IMU_LAYOUT,
    NS,
    TEMPERATURE_LAYOUT,
    BadMessageError,
    decode_fixed_cdr,
    gather,
)
from pipelines.ingest.data_format import extra_keys
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import check_finite, cut_tail
from pipelines.ingest.mcap_records import (
    MESSAGE_FIXED,
    OP_CHANNEL,
    OP_CHUNK,
    OP_FOOTER,
    OP_MESSAGE,
    OP_SCHEMA,
    OP_STATISTICS,
    RECORD_HEADER,
    U64,
    Cursor,
    decompress,
    record_starts,
)
from pipelines.ingest.time_order import check_time_increases

if TYPE_CHECKING:
    from pipelines.ingest.data_format import FormatSpec
    from pipelines.ingest.streamed_pass import SampleSink, Streamed, StreamOptions

MAGIC = b"\x89MCAP0\r\n"
IMU_SCHEMA = "sensor_msgs/msg/Imu"
TEMPERATURE_SCHEMA = "sensor_msgs/msg/Temperature"
JOINT_STATE_SCHEMA = "sensor_msgs/msg/JointState"
KEYS = ("imu_topic", "temperature_topic", "table_topic", "table_joint", "stamp")  # [format]

_PENDING_FLUSH = 1 << 20  # bytes of unchunked message records decoded together
_MAX_CHUNK = 1 << 30  # writers use ~1-10 MiB chunks; more is a damaged length field


@dataclass
class McapChannel:
    id: int
    topic: str
    message_encoding: str
    schema_id: int
    schema_name: str = ""
    schema_encoding: str = ""
    schema_data: bytes = b""
    role: str | None = None  # "imu", "temp" or "table" once chosen for decoding
    parts: list[dict[str, np.ndarray]] = field(default_factory=list)
    count: int = 0
    decoder: Callable[[bytes], Any] | None = None
    full_size: bool = False  # parts is one set of arrays sized by the Statistics record


def read_mcap(
    path: str | os.PathLike[str],
    *,
    imu_topic: str | None = None,
    temperature_topic: str | None = None,
    table_topic: str | None = None,
    table_joint: str | int = 0,
    stamp: Literal["header", "log"] = "header",
) -> Recording:
    """Read a ROS 2 MCAP log into a Recording on the IMU's time base.

    Parameters
    ----------
    path : the .mcap file (chunked or not; none, zstd or lz4 compression).
    imu_topic : topic of ``sensor_msgs/msg/Imu`` messages; None picks the only
        channel with that schema (an error if there are several).
    temperature_topic : topic of ``sensor_msgs/msg/Temperature`` (deg C) or None.
    table_topic : rate-table feedback, ``sensor_msgs/msg/JointState`` or a JSON
        channel with fields angle (rad) / rate (rad/s), or None.
    table_joint : JointState joint, by name or index into the message's arrays.
    stamp : ``"header"`` (the message's header.stamp) or ``"log"`` (MCAP log time).

    Returns
    -------
    Recording: t (N,) Unix s; acc (N, 3) m/s^2; gyr (N, 3) rad/s; temp (N,) deg C
    or None; reference ``table_angle`` (N,) rad / ``table_rate`` (N,) rad/s when
    the table topic carries them.

    Raises
    ------
    IngestError
        Naming the file and the problem: not MCAP or truncated / damaged; a
        topic that is absent (listing the topics present), ambiguous or has no
        messages; a schema/encoding that cannot be decoded; NaN/inf; time stamps
        that are not strictly increasing (with the message index).
    """
    name = os.fspath(path)
    reader = McapReader(name, imu_topic, temperature_topic, table_topic, table_joint, stamp)
    try:
        with open(name, "rb") as f:
            reader.read(f, os.fstat(f.fileno()).st_size)
    except OSError as exc:
        raise IngestError(f"cannot read file: {exc.strerror or exc}", file=name) from exc
    return reader.recording()


class McapReader:
    """One pass over an MCAP file, decoding the chosen channels chunk by chunk.

    Each chunk's decoded messages of a channel are kept (`keep`): joined into the topic's
    arrays for `recording`, or, given a `sink` (the streamed route), the IMU topic's
    pushed to it as they come (a decompressed chunk above `max_chunk` bytes refused).
    The [format] keys that cannot be right are refused before any reading.
    """

    def __init__(
        self,
        name: str,
        imu_topic: str | None,
        temperature_topic: str | None,
        table_topic: str | None,
        table_joint: str | int,
        stamp: str,
        sink: SampleSink | None = None,
        max_chunk: int = _MAX_CHUNK,
    ) -> None:
        if stamp not in ("header", "log"):
            raise IngestError(
                f"stamp must be 'header' or 'log', got {stamp!r}", file=name, field="format.stamp"
            )
        requested = [t for t in (imu_topic, temperature_topic, table_topic) if t is not None]
        if len(set(requested)) != len(requested):
            raise IngestError(
                f"the same topic is named for two roles: imu={imu_topic!r}, "
                f"temperature={temperature_topic!r}, table={table_topic!r}",
                file=name,
            )
        if isinstance(table_joint, bool) or not isinstance(table_joint, (str, int)):
            raise IngestError(
                f"table_joint must be a joint name or index, got {table_joint!r}",
                file=name,
                field="format.table_joint",
            )
        self.name = name
        self.table_joint = table_joint
        self.topics = {"imu": imu_topic, "temp": temperature_topic, "table": table_topic}
        self.stamp = stamp
        self.sink, self.max_chunk = sink, max_chunk
        self.schemas: dict[int, tuple[str, str, bytes]] = {}
        self.counts: dict[int, int] | None = None  # messages per channel, from Statistics
        self.channels: dict[int, McapChannel] = {}
        self.findings: tuple[dict, ...] = ()  # `cut_tail` of a file cut while written

    # --- file structure ----------------------------------------------------------

    def read(self, f: Any, size: int) -> None:
        if f.read(8) != MAGIC:
            raise self.error("not an MCAP file (bad magic at offset 0)")
        self._summary_statistics(f, size)
        f.seek(8)
        pos = 8
        pending = bytearray()  # message records outside chunks, decoded in batches
        while True:
            head = f.read(RECORD_HEADER)
            if len(head) < RECORD_HEADER:
                self._cut(pos, size)  # a log cut while written: no footer, no summary
                break
            opcode = head[0]
            (length,) = U64.unpack_from(head, 1)
            if length > size - pos - RECORD_HEADER:
                if not (0x01 <= opcode <= 0x0F and length <= _MAX_CHUNK):
                    raise self.error(
                        f"damaged MCAP file: record at byte {pos} (opcode 0x{opcode:02x}) "
                        f"claims {length} bytes, only {size - pos - RECORD_HEADER} remain, "
                        "and is no record a writer makes"
                    )
                self._cut(pos, size)  # its last record cut short
                break
            if opcode == OP_MESSAGE:
                pending += head
                pending += f.read(length)
                if len(pending) >= _PENDING_FLUSH:
                    self._records(bytes(pending), pos)
                    pending.clear()
            elif opcode in (OP_CHUNK, OP_SCHEMA, OP_CHANNEL):
                if pending:
                    self._records(bytes(pending), pos)
                    pending.clear()
                body = f.read(length)
                if opcode == OP_CHUNK:
                    self._chunk(body, pos)
                else:
                    self._definition(opcode, body, pos)
            elif opcode == OP_FOOTER:
                f.seek(length, 1)
                if f.read(8) != MAGIC:
                    raise self.error(
                        "MCAP footer is not followed by the closing magic (damaged file)"
                    )
                break
            else:  # indexes, statistics, attachments, metadata: not needed
                f.seek(length, 1)
            pos += RECORD_HEADER + length
        if pending:
            self._records(bytes(pending), pos)

    def _cut(self, pos: int, size: int) -> None:
        """A file that ends without its Footer: read to its last whole record (at byte
        `pos`), the `cut_tail` finding noted (chunks carry their own CRC: damage inside
        is refused where it is read)."""
        self.findings = (cut_tail(Path(self.name), "MCAP file", pos, size - pos, size),)

    def _chunk(self, body: bytes, pos: int) -> None:
        if self.sink is not None:
            (size,) = struct.unpack_from("<Q", body, 16) if len(body) >= 24 else (0,)
            if size > self.max_chunk:
                raise self.error(
                    f"chunk at byte {pos} holds {size} bytes uncompressed, more than the "
                    f"memory limit allows ({self.max_chunk}); raise the memory limit"
                )
        try:
            uncompressed_size, crc = struct.unpack_from("<QI", body, 16)
            (comp_len,) = struct.unpack_from("<I", body, 28)
            compression = body[32 : 32 + comp_len].decode()
            (records_len,) = U64.unpack_from(body, 32 + comp_len)
        except (struct.error, UnicodeDecodeError):
            raise self.error(f"damaged chunk header at byte {pos}") from None
        start = 40 + comp_len
        if start + records_len > len(body):
            raise self.error(f"chunk at byte {pos} is shorter than it claims")
        if uncompressed_size > _MAX_CHUNK:
            raise self.error(
                f"chunk at byte {pos} claims {uncompressed_size} bytes uncompressed "
                f"(limit {_MAX_CHUNK}; damaged file?)"
            )
        data = decompress(
            self.name, pos, compression, body[start : start + records_len], uncompressed_size
        )
        if crc and zlib.crc32(data) != crc:
            raise self.error(f"chunk at byte {pos} fails its CRC check (damaged file)")
        self._records(data, pos)

    def _summary_statistics(self, f: Any, size: int) -> None:
        """Find the Statistics record through the Footer, before the data pass.

        Its per-channel message counts let the IMU arrays be allocated once at
        full size (no list of chunk parts to concatenate: half the peak memory)
        and check at the end that no chunk went missing. A file without a
        summary is read all the same; a damaged footer is left to the data pass.
        """
        footer = RECORD_HEADER + 20 + len(MAGIC)  # summary_start, offset_start u64; crc u32
        if size < 8 + footer:
            return
        f.seek(size - footer)
        tail = f.read(footer)
        if tail[0] != OP_FOOTER or tail[-8:] != MAGIC:
            return
        (start,) = U64.unpack_from(tail, RECORD_HEADER)
        end = size - footer
        if not 8 <= start < end:
            return
        f.seek(start)
        summary = f.read(end - start)
        pos = 0
        while pos + RECORD_HEADER <= len(summary):
            (length,) = U64.unpack_from(summary, pos + 1)
            if summary[pos] == OP_STATISTICS:
                body = summary[pos + RECORD_HEADER : pos + RECORD_HEADER + length]
                self._statistics(body, start + pos)
                return
            pos += RECORD_HEADER + length

    def _statistics(self, body: bytes, pos: int) -> None:
        """Messages per channel from the summary: a check that no chunk went missing."""
        try:
            (size,) = struct.unpack_from("<I", body, 42)
            entries = np.frombuffer(
                body, np.dtype([("id", "<u2"), ("n", "<u8")]), count=size // 10, offset=46
            )
        except (struct.error, ValueError):
            raise self.error(f"damaged statistics record at byte {pos}") from None
        self.counts = dict(zip(entries["id"].tolist(), entries["n"].tolist(), strict=True))

    def _definition(self, opcode: int, body: bytes, pos: int) -> None:
        try:
            cur = Cursor(body)
            if opcode == OP_SCHEMA:
                sid = cur.u16()
                self.schemas[sid] = (cur.string(), cur.string(), cur.blob())
                return
            cid, sid = cur.u16(), cur.u16()
            topic, encoding = cur.string(), cur.string()
        except (struct.error, UnicodeDecodeError, IndexError):
            kind = "schema" if opcode == OP_SCHEMA else "channel"
            raise self.error(f"damaged {kind} record near byte {pos}") from None
        if cid in self.channels:
            return
        channel = McapChannel(cid, topic, encoding, sid)
        if sid:
            if sid not in self.schemas:
                raise self.error(
                    f"channel {topic!r} refers to schema id {sid}, which is not defined before it"
                )
            channel.schema_name, channel.schema_encoding, channel.schema_data = self.schemas[sid]
        channel.role = self._role(channel)
        self.channels[cid] = channel
        if self.sink is not None and sum(c.role == "imu" for c in self.channels.values()) > 1:
            self.pick("imu")  # several Imu topics and none named: refused as soon as seen

    def _role(self, ch: McapChannel) -> str | None:
        for role, topic in self.topics.items():
            if topic == ch.topic:
                return role
        if self.topics["imu"] is None and ch.schema_name == IMU_SCHEMA:
            return "imu"  # a candidate; ambiguity is judged once the whole file is read
        return None

    # --- records inside a chunk ----------------------------------------------------

    def _records(self, buf: bytes, pos: int) -> None:
        """Decode the records of one (decompressed) chunk or batch of message records."""
        arr = np.frombuffer(buf, np.uint8)
        starts = record_starts(buf, arr)
        if starts is None:
            raise self.error(f"damaged records in the chunk at byte {pos}")
        ops = arr[starts]
        for i in np.flatnonzero((ops == OP_SCHEMA) | (ops == OP_CHANNEL)):
            s = int(starts[i])
            (length,) = U64.unpack_from(buf, s + 1)
            self._definition(int(ops[i]), buf[s + 9 : s + 9 + length], pos)
        msg = starts[ops == OP_MESSAGE]
        if msg.size == 0:
            return
        lengths = gather(arr, msg + 1, "<u8").astype(np.int64)
        if (lengths < MESSAGE_FIXED).any():
            raise self.error(f"message record too short in chunk at byte {pos}")
        chan = gather(arr, msg + 9, "<u2")
        for cid in np.unique(chan):
            channel = self.channels.get(int(cid))
            if channel is None:
                raise self.error(
                    f"message on channel id {cid}, which is not defined before it "
                    f"(chunk at byte {pos})"
                )
            if channel.role is None:
                continue
            sel = chan == cid
            rec = msg[sel]
            log_ns = gather(arr, rec + 15, "<u8").astype(np.int64)
            payload = rec + RECORD_HEADER + MESSAGE_FIXED
            plen = lengths[sel] - MESSAGE_FIXED
            part = self._decode(channel, buf, arr, payload, plen, log_ns)
            self._keep(channel, part, pos)

    def _keep(self, ch: McapChannel, part: dict[str, np.ndarray], pos: int) -> None:
        """Append one chunk's decoded messages to the channel's arrays, or push the IMU
        topic's to the sink (the first Imu channel defined: `pick`'s; any other is only
        counted, an ambiguous choice being refused as soon as it is seen)."""
        n = len(part["stamp"])
        if self.sink is not None:
            if ch is next(c for c in self.channels.values() if c.role == "imu"):
                self.sink.topic = ch.topic
                self.sink.push(part)
            ch.count += n
            return
        total = None if self.counts is None else self.counts.get(ch.id)
        if total is not None and not ch.parts and ch.count == 0:
            try:  # np.empty only reserves: a damaged count fails here or at the count check
                ch.parts.append(
                    {k: np.empty((total, *v.shape[1:]), v.dtype) for k, v in part.items()}
                )
                ch.full_size = True
            except (MemoryError, ValueError):
                ch.parts.clear()
        if ch.full_size:
            if ch.count + n > total:
                raise self.error(
                    f"topic {ch.topic!r}: more messages than the file's statistics record "
                    f"counts ({total}) by the chunk at byte {pos} (damaged file?)",
                    ch.topic,
                )
            for key, values in part.items():
                ch.parts[0][key][ch.count : ch.count + n] = values
        else:
            ch.parts.append(part)
        ch.count += n

    def _decode(
        self,
        ch: McapChannel,
        buf: bytes,
        arr: np.ndarray,
        start: np.ndarray,
        length: np.ndarray,
        log_ns: np.ndarray,
    ) -> dict[str, np.ndarray]:
        if ch.role in ("imu", "temp"):
            schema, layout = {
                "imu": (IMU_SCHEMA, IMU_LAYOUT),
                "temp": (TEMPERATURE_SCHEMA, TEMPERATURE_LAYOUT),
            }[ch.role]
            self._require(ch, schema)
            try:
                part = decode_fixed_cdr(arr, start, length, layout)
            except BadMessageError as exc:
                raise self.error(
                    f"message {ch.count + exc.index} (0-based) of topic {ch.topic!r} "
                    f"({ch.schema_name}): {exc.problem}",
                    ch.topic,
                ) from None
        elif ch.message_encoding == "json":
            part = self._decode_json(ch, buf, start, length)
        else:
            self._require(ch, JOINT_STATE_SCHEMA)
            part = self._decode_joint_state(ch, buf, start, length)
        if self.stamp == "log" or "stamp" not in part:
            part["stamp"] = log_ns
        return part

    def error(self, problem: str, field: str | None = None) -> IngestError:
        """The IngestError of `problem` in this file (at `field`: a topic, a manifest key)."""
        return IngestError(problem, file=self.name, field=field)

    def _require(self, ch: McapChannel, schema: str) -> None:
        if ch.schema_name != schema or ch.message_encoding != "cdr":
            raise self.error(
                f"cannot decode topic {ch.topic!r}: schema {ch.schema_name or '(none)'!r} with "
                f"message encoding {ch.message_encoding!r}; this role needs {schema} in 'cdr'",
                ch.topic,
            )

    def _decode_joint_state(
        self, ch: McapChannel, buf: bytes, start: np.ndarray, length: np.ndarray
    ) -> dict[str, np.ndarray]:
        """JointState is variable-length and low-rate: mcap-ros2-support decodes it."""
        if ch.decoder is None:
            from mcap.records import Schema
            from mcap_ros2.decoder import DecoderFactory

            schema = Schema(
                id=ch.schema_id,
                name=ch.schema_name,
                encoding=ch.schema_encoding,
                data=ch.schema_data,
            )
            try:
                # Its vendored parser prints each bad definition line to stderr before
                # raising; the IngestError below says it once, where the operator looks.
                with contextlib.redirect_stderr(io.StringIO()):
                    ch.decoder = DecoderFactory().decoder_for(ch.message_encoding, schema)
            except Exception as exc:  # a broken definition text raises assorted errors
                raise self.error(
                    f"cannot parse the message definition of topic {ch.topic!r}: {exc}", ch.topic
                ) from None
            if ch.decoder is None:
                raise self.error(
                    f"cannot decode topic {ch.topic!r}: schema encoding "
                    f"{ch.schema_encoding!r} is not ros2msg",
                    ch.topic,
                )
        n = len(start)
        out = {"stamp": np.empty(n, np.int64)}
        out["angle"], out["rate"] = np.full(n, np.nan), np.full(n, np.nan)
        for k, (s, size) in enumerate(zip(start.tolist(), length.tolist(), strict=True)):
            try:
                m = ch.decoder(buf[s : s + size])
                out["stamp"][k] = m.header.stamp.sec * NS + m.header.stamp.nanosec
                joints = list(m.name)
            except Exception as exc:  # the generated decoder raises assorted errors
                raise self.error(
                    f"cannot decode message {ch.count + k} (0-based) of topic {ch.topic!r}: {exc}",
                    ch.topic,
                ) from None
            if isinstance(self.table_joint, str):
                if self.table_joint not in joints:
                    raise self.error(
                        f"message {ch.count + k} of topic {ch.topic!r} has no joint "
                        f"{self.table_joint!r} (joints: {joints})",
                        "format.table_joint",
                    )
                idx = joints.index(self.table_joint)
            else:
                idx = self.table_joint
            # Labs' tables may publish only position or only velocity: absent -> NaN.
            if 0 <= idx < len(m.position):
                out["angle"][k] = m.position[idx]
            if 0 <= idx < len(m.velocity):
                out["rate"][k] = m.velocity[idx]
        return out

    def _decode_json(
        self, ch: McapChannel, buf: bytes, start: np.ndarray, length: np.ndarray
    ) -> dict[str, np.ndarray]:
        out: dict[str, list[float]] = {"stamp": [], "angle": [], "rate": []}
        for k, (s, n) in enumerate(zip(start.tolist(), length.tolist(), strict=True)):
            try:
                obj = json.loads(buf[s : s + n])
                if not isinstance(obj, dict):
                    raise ValueError("not a JSON object")
                for key in ("angle", "rate", "stamp"):
                    value = obj.get(key)
                    out[key].append(np.nan if value is None else float(value))
            except (ValueError, TypeError) as exc:
                raise self.error(
                    f"message {ch.count + k} (0-based) of JSON topic {ch.topic!r} is not an "
                    f"object with numeric fields angle/rate/stamp: {exc}",
                    ch.topic,
                ) from None
        part = {k: np.array(out[k], dtype=np.float64) for k in ("angle", "rate")}
        stamps = np.array(out["stamp"], dtype=np.float64)
        if np.isfinite(stamps).all() and (np.abs(stamps) < 9e9).all():
            part["stamp"] = np.round(stamps * NS).astype(np.int64)
        return part

    # --- assembling the Recording ------------------------------------------------

    def recording(self) -> Recording:
        imu = self.pick("imu")
        assert imu is not None  # pick raises for a missing IMU
        where = f"topic {imu.topic!r}"
        # One field at a time, dropping its parts: peak memory stays near the final arrays.
        stamp_ns = _concat(imu, "stamp")
        check_time_increases(
            stamp_ns, file=self.name, sample="message", unit="ns", prefix=f"{where}: "
        )
        acc = _concat(imu, "acc")
        check_finite(self.name, where, "linear_acceleration", acc)
        gyr = _concat(imu, "gyr")
        check_finite(self.name, where, "angular_velocity", gyr)
        imu.parts.clear()
        t0 = stamp_ns[0]
        stamp_ns -= t0  # exact integer offsets (in place), then one rounding to seconds
        rel = stamp_ns / NS
        del stamp_ns
        t = rel + t0 / NS

        temp = None
        ch = self.pick("temp")
        if ch is not None:
            values = _concat(ch, "temp")  # count 1: (n,)
            temp = self._onto(ch, _concat(ch, "stamp"), values, t0, rel, "temperature")

        reference: dict[str, np.ndarray] = {}
        ch = self.pick("table")
        if ch is not None:
            ref_ns = _concat(ch, "stamp")
            columns = {"angle": _concat(ch, "angle"), "rate": _concat(ch, "rate")}
            if all(np.isnan(v).all() for v in columns.values()):
                raise self.error(
                    f"topic {ch.topic!r} carries neither angle (position) nor rate (velocity)"
                    + ("" if ch.message_encoding == "json" else f" for joint {self.table_joint!r}"),
                    ch.topic,
                )
            for key, values in columns.items():
                if np.isnan(values).all():
                    continue  # the table does not report this quantity
                if key == "angle":
                    # Unwrap a table that reports 0..2 pi (an accumulating angle is unchanged).
                    values = np.unwrap(values)
                reference[f"table_{key}"] = self._onto(ch, ref_ns, values, t0, rel, key)
        return Recording(
            t=t,
            acc=acc,
            gyr=gyr,
            temp=temp,
            reference=reference,
            source=self.name,
            findings=self.findings,
        )

    def pick(self, role: str) -> McapChannel | None:
        topic = self.topics[role]
        chosen = [c for c in self.channels.values() if c.role == role]
        present = ", ".join(
            f"{c.topic} [{c.schema_name or c.message_encoding}]" for c in self.channels.values()
        )
        if role == "imu" and topic is None:
            if not chosen:
                raise self.error(
                    f"no channel with schema {IMU_SCHEMA}; topics present: {present or 'none'}"
                )
            if len(chosen) > 1:
                raise self.error(
                    f"several {IMU_SCHEMA} topics ({', '.join(c.topic for c in chosen)}); "
                    "name one as imu_topic in the manifest",
                    "format.imu_topic",
                )
        elif topic is None:
            return None
        elif not chosen:
            raise self.error(
                f"topic {topic!r} not found; topics present: {present or 'none'}", topic
            )
        ch = chosen[0]
        if ch.count == 0:
            raise self.error(f"topic {ch.topic!r} has no messages", ch.topic)
        expected = None if self.counts is None else self.counts.get(ch.id)
        if expected is not None and expected != ch.count:
            raise self.error(
                f"topic {ch.topic!r}: {ch.count} messages read but the file's statistics "
                f"record counts {expected} (damaged file?)",
                ch.topic,
            )
        return ch

    def _onto(
        self,
        ch: McapChannel,
        ref_ns: np.ndarray,
        values: np.ndarray,
        t0: np.int64,
        rel: np.ndarray,
        what: str,
    ) -> np.ndarray:
        """Interpolate a reference channel onto the IMU time base (relative seconds)."""
        where = f"topic {ch.topic!r}"
        check_time_increases(
            ref_ns, file=self.name, sample="message", unit="ns", prefix=f"{where}: "
        )
        check_finite(self.name, where, what, values)
        return np.interp(rel, (ref_ns - t0) / NS, values)


def _concat(ch: McapChannel, key: str) -> np.ndarray:
    """One field of all decoded parts, concatenated (the parts keep the others)."""
    if len(ch.parts) == 1:  # full-size arrays, or a single chunk: no copy
        return ch.parts[0].pop(key)[: ch.count]
    return np.concatenate([p.pop(key) for p in ch.parts])


def stream_mcap(
    path: Path,
    fmt: FormatSpec,
    samples: Path,
    **options: Unpack[StreamOptions],
) -> Streamed:
    """One pass of `McapReader` over a ROS 2 MCAP log, its IMU topic's messages to the
    samples' Parquet and the first-pass statistics (`streamed_pass`), the file's bytes
    hashed and copied as they are read.

    Parameters
    ----------
    path : the .mcap file (chunked or not; none, zstd or lz4 compression).
    fmt : the manifest's format section (kind mcap: ``imu_topic``, ``stamp`` as
        `read_mcap`; ``temperature_topic`` / ``table_topic``, interpolated onto the whole
        IMU time base, are refused with the reason).
    samples : the Parquet file to write (t in Unix s, the in-memory time base; temp NaN).
    options : `streamed_pass.StreamOptions` (raw copy, label, memory limit: the rows per
        batch and the largest chunk accepted, a quarter of it; progress, time window).

    Raises
    ------
    IngestError as `read_mcap`; a log cut while written (read in memory with its finding).
    """
    from pipelines.ingest.streamed_pass import streamed_pass

    keys = {"table_joint": 0, "stamp": "header", **extra_keys(fmt, "mcap", KEYS)}
    topics = {k: keys.get(k) for k in ("imu_topic", "temperature_topic", "table_topic")}
    name = str(path)
    McapReader(name, **topics, table_joint=keys["table_joint"], stamp=keys["stamp"])
    for key in ("temperature_topic", "table_topic"):
        if keys.get(key) is not None:
            raise IngestError(
                f"a record read in chunks gives its IMU topic only; {key} is interpolated "
                "onto the whole IMU time base (raise the memory limit to read it into memory)",
                file=path,
                field=f"format.{key}",
            )
    with streamed_pass(path, samples, tee=True, **options) as run:
        reader = McapReader(
            name, topics["imu_topic"], None, None, 0, keys["stamp"], run.sink, run.memory_limit // 4
        )
        reader.read(run.tee, run.size)
        if reader.findings:  # a cut log: the streamed route carries no findings
            reader.pick("imu")  # no IMU before the cut: the reader's own error
            raise IngestError(
                f"{reader.findings[0]['detail']}; a record streamed in chunks is "
                "not read cut (raise the memory limit to read it into memory, with "
                "the finding)",
                file=path,
            )
        run.sink.finish()
        run.tee.drain()
    reader.pick("imu")  # absent, ambiguous, empty or short of the statistics' count
    return run.result()
