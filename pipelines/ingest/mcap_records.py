"""MCAP record-level helpers: a byte cursor over a record's fields, the record starts
inside a decompressed chunk (vectorised), chunk decompression with its size checked.

Used by pipelines.ingest.mcap_reader; see its docstring for why records are read
by hand rather than through mcap's record iterator.
"""

from __future__ import annotations

import struct

import numpy as np

from pipelines.ingest.cdr import (
    gather,
)
from pipelines.ingest.errors import IngestError

# Record opcodes and sizes of the MCAP format (mcap.dev/spec).
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
OP_STATISTICS = 0x0B
RECORD_HEADER = 9  # opcode u8 + length u64
MESSAGE_FIXED = 22  # channel_id u16, sequence u32, log_time u64, publish_time u64
U64 = struct.Struct("<Q")


class Cursor:
    """Little-endian reader for the few variable-length MCAP records (schema, channel)."""

    def __init__(self, buf: bytes) -> None:
        self.buf, self.pos = buf, 0

    def _take(self, n: int) -> bytes:
        if self.pos + n > len(self.buf):
            raise IndexError("record ends early")
        out = self.buf[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return int.from_bytes(self._take(2), "little")

    def blob(self) -> bytes:
        return self._take(int.from_bytes(self._take(4), "little"))

    def string(self) -> str:
        return self.blob().decode()


def record_starts(buf: bytes, arr: np.ndarray) -> np.ndarray | None:
    """Offsets of the records in `buf` (opcode u8 + length u64 + body), or None if they overrun.

    A Python loop hops from header to header. The usual chunk of an IMU log is,
    after its first message, nothing but messages of one size (one topic, one
    frame_id): that case is recognised once and checked with numpy instead.
    """
    starts: list[int] = []
    append = starts.append
    unpack = U64.unpack_from
    end = len(buf) - RECORD_HEADER
    pos = 0
    tried = False
    while pos <= end:
        append(pos)
        step = RECORD_HEADER + unpack(buf, pos + 1)[0]
        if not tried and buf[pos] == OP_MESSAGE:
            tried = True
            rest = len(buf) - pos
            if rest % step == 0:
                regular = pos + step * np.arange(rest // step, dtype=np.int64)
                if (arr[regular] == OP_MESSAGE).all() and (
                    gather(arr, regular + 1, "<u8") == step - RECORD_HEADER
                ).all():
                    return np.concatenate([np.array(starts[:-1], dtype=np.int64), regular])
        pos += step
    if pos != len(buf):
        return None
    return np.array(starts, dtype=np.int64)


def decompress(name: str, pos: int, compression: str, data: bytes, size: int) -> bytes:
    try:
        if compression == "":
            out = data
        elif compression == "zstd":
            import zstandard

            out = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        elif compression == "lz4":
            import lz4.frame

            out = lz4.frame.decompress(data)
        else:
            raise IngestError(
                f"chunk at byte {pos} uses compression {compression!r}; expected none, zstd or lz4",
                file=name,
            )
    except IngestError:
        raise
    except Exception as exc:  # zstandard.ZstdError, RuntimeError from lz4, ...
        raise IngestError(f"cannot decompress chunk at byte {pos}: {exc}", file=name) from None
    if len(out) != size:
        raise IngestError(
            f"chunk at byte {pos} decompresses to {len(out)} bytes, expected {size}", file=name
        )
    return out
