"""Input format detection by content, never by file suffix.

Labs rename files freely (``run1.dat`` may be a .mat, ``imu.log`` an MCAP), so
the reader is chosen from the first bytes:

- MCAP: the 8-byte magic ``\\x89MCAP0\\r\\n`` at offset 0.
- MATLAB v7.3: an HDF5 file. MATLAB writes a 512-byte MAT header ("userblock")
  first, so the HDF5 signature ``\\x89HDF\\r\\n\\x1a\\n`` sits at offset 512;
  plain HDF5 writers put it at 0.
- MATLAB v5 (also what v6/v7 write): a 128-byte header of 116 bytes of text
  starting ``MATLAB 5.0 MAT-file``, 8 bytes of subsystem offset, the version
  0x0100 and the endian indicator ``IM`` (little-endian) or ``MI`` (big-endian).
- text: the first 64 KiB decode as UTF-8 and hold no NUL byte.
"""

from __future__ import annotations

import os
from typing import Literal

from pipelines.ingest.errors import IngestError, file_head

Format = Literal["mcap", "mat5", "mat73", "text"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
MAT5_TEXT = b"MATLAB 5.0 MAT-file"
MAT73_TEXT = b"MATLAB 7.3 MAT-file"
MAT73_USERBLOCK = 512  # bytes of MAT header before the HDF5 superblock
TEXT_PROBE = 64 * 1024  # bytes examined to call a file text


def detect_format(path: str | os.PathLike[str]) -> Format:
    """Return the format of the file at `path`, judged by its content.

    Parameters
    ----------
    path : file to examine.

    Returns
    -------
    ``"mcap"``, ``"mat5"``, ``"mat73"`` or ``"text"``.

    Raises
    ------
    IngestError
        If the file cannot be read, is empty, or matches none of the formats; the
        message names the file and shows its first bytes in hex.
    """
    name = os.fspath(path)
    head = file_head(name, TEXT_PROBE)
    if not head:
        raise IngestError("file is empty; expected MCAP, MATLAB .mat or text data", file=name)

    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(HDF5_SIGNATURE) or head[MAT73_USERBLOCK:].startswith(HDF5_SIGNATURE):
        return "mat73"
    if head.startswith(MAT73_TEXT):
        raise IngestError(
            "MATLAB 7.3 header but no HDF5 signature at byte 512 (file truncated or damaged?)",
            file=name,
        )
    if head.startswith(MAT5_TEXT):
        _check_mat5_header(name, head)
        return "mat5"
    if _is_text(head):
        return "text"
    raise IngestError(
        "unknown file format: not MCAP (magic 89 4d 43 41 50 30 0d 0a), not a MATLAB v5 or "
        "v7.3 MAT-file, not UTF-8 text; first bytes: " + head[:16].hex(" "),
        file=name,
    )


def _check_mat5_header(name: str, head: bytes) -> None:
    """Raise IngestError unless the 128-byte MAT v5 header is complete and consistent."""
    if len(head) < 128:
        raise IngestError(
            f"MATLAB 5.0 header is truncated: {len(head)} bytes, expected at least 128",
            file=name,
        )
    endian = head[126:128]
    version = head[124:126]
    # The version is written in the file's own byte order, so IM pairs with 00 01, MI with 01 00.
    expected = {b"IM": b"\x00\x01", b"MI": b"\x01\x00"}.get(endian)
    if expected is None or version != expected:
        raise IngestError(
            "MATLAB 5.0 header with bad version/endian bytes "
            f"{head[124:128].hex(' ')} at offset 124; expected '00 01 49 4d' or '01 00 4d 49'",
            file=name,
        )


def _is_text(head: bytes) -> bool:
    """True if `head` holds no NUL and decodes as UTF-8 (a character cut at the end is allowed)."""
    if b"\x00" in head:
        return False
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        # The probe may cut a multi-byte character in two: only its last <= 3 bytes may be bad.
        return exc.reason == "unexpected end of data" and exc.start >= len(head) - 3
    return True
