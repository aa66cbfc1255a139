"""CDR decoding of ROS 2 messages with a fixed layout after their Header, vectorised.

``sensor_msgs/msg/Imu`` and ``sensor_msgs/msg/Temperature`` in CDR have a fixed layout
once the header's variable-length ``frame_id`` is known (`FixedLayout`), so for every
message of a chunk at once the string length is read, the offsets of the stamp and of
each float64 field computed, and those bytes gathered with one fancy-indexing
operation per field. The encapsulation header (first 4 bytes: 00 00 big-endian CDR,
00 01 little-endian CDR) gives the byte order; doubles are 8-byte aligned relative to
the end of that header. Used by pipelines.ingest.mcap_reader.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NS = 1_000_000_000  # nanoseconds per second


@dataclass(frozen=True)
class FixedLayout:
    """Where the float64 fields of a CDR message with a fixed layout after its Header lie.

    The message starts with std_msgs/Header: stamp.sec int32 @0, stamp.nanosec
    uint32 @4, frame_id length uint32 @8 (counting the NUL), the characters @12.
    The rest starts at ``align8(12 + length)``; `fields` gives each float64
    field's offset from there and its number of values, `size` the bytes of
    that rest.
    """

    fields: dict[str, tuple[int, int]]
    size: int


# sensor_msgs/msg/Imu after the Header: orientation (4 doubles) @0, its covariance
# (9) @32, angular_velocity (3) @104, covariance (9) @128, linear_acceleration (3)
# @200, covariance (9) @224; 37 doubles in all.
IMU_LAYOUT = FixedLayout({"gyr": (104, 3), "acc": (200, 3)}, 37 * 8)
# sensor_msgs/msg/Temperature after the Header: temperature @0, variance @8.
TEMPERATURE_LAYOUT = FixedLayout({"temp": (0, 1)}, 2 * 8)


def gather(arr: np.ndarray, offsets: np.ndarray, dtype: str, count: int = 1) -> np.ndarray:
    """Values of `dtype` (`count` per row) read at byte `offsets` of the uint8 array `arr`.

    Returns (n,) for count 1, else (n, count).
    """
    dt = np.dtype(dtype)
    # Rows of a sliding-window view: one copy of `width` bytes per offset (row-wise
    # take is several times faster than indexing every byte).
    windows = np.lib.stride_tricks.sliding_window_view(arr, dt.itemsize * count)
    values = windows[offsets].view(dt)
    return values[:, 0] if count == 1 else values


class BadMessageError(Exception):
    """A message of a chunk that does not fit its layout (index within the batch)."""

    def __init__(self, index: int, problem: str) -> None:
        super().__init__(problem)
        self.index, self.problem = index, problem


def decode_fixed_cdr(
    arr: np.ndarray, start: np.ndarray, length: np.ndarray, layout: FixedLayout
) -> dict[str, np.ndarray]:
    """Decode CDR messages with a Header and a fixed layout after it, all at once.

    Parameters
    ----------
    arr : (B,) uint8, the chunk's bytes.
    start, length : (n,) int64, byte offset and length of each message payload.
    layout : where the float64 fields lie after the Header.

    Returns
    -------
    dict with ``stamp`` (n,) int64 ns from header.stamp and each layout field
    as (n, count) float64.

    Raises
    ------
    BadMessageError
        For the first message that is too short, not plain CDR or has a
        frame_id without its terminating NUL.
    """

    def first(bad: np.ndarray) -> int:
        return int(np.flatnonzero(bad)[0])

    if (length < 16).any():
        k = first(length < 16)
        raise BadMessageError(k, f"payload of {length[k]} bytes is too short for a Header")
    kind = arr[start].astype(np.uint16) << 8 | arr[start + 1]
    if (kind > 1).any():
        k = first(kind > 1)
        raise BadMessageError(
            k,
            f"CDR encapsulation 0x{int(kind[k]):04x} is not plain CDR "
            "(0x0000 big-endian or 0x0001 little-endian)",
        )
    big = kind == 0
    base = start + 4  # CDR alignment counts from the end of the encapsulation header

    def num(offsets: np.ndarray, dtype: str, count: int = 1) -> np.ndarray:
        values = gather(arr, offsets, "<" + dtype, count)
        if big.any():
            values[big] = values[big].byteswap()
        return values

    strlen = num(base + 8, "u4").astype(np.int64)
    rest = (12 + strlen + 7) // 8 * 8  # the fixed part starts 8-byte aligned
    short = (strlen < 1) | (rest + layout.size > length - 4)
    if short.any():
        k = first(short)
        raise BadMessageError(
            k,
            f"payload of {length[k]} bytes does not hold the message "
            f"(frame_id length {strlen[k]}; needs {4 + rest[k] + layout.size} bytes)",
        )
    unterminated = arr[base + 11 + strlen] != 0
    if unterminated.any():
        raise BadMessageError(first(unterminated), "frame_id is not NUL-terminated")
    out = {"stamp": num(base, "i4").astype(np.int64) * NS + num(base + 4, "u4")}
    for key, (offset, count) in layout.fields.items():
        out[key] = num(base + rest + offset, "f8", count)
    return out
