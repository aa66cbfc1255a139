"""Ingest, the pipeline glue: the one check every reader makes on its time stamps.

Time must increase from one sample to the next (docs/manifest.md, "Bad samples"):
the first sample that is not after the previous one refuses the run. Each reader
names that sample its own way (a CSV or text line, a MAT variable, an MCAP
message, a log record), so it passes how to locate it; the message itself is
the same for every format.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from pipelines.ingest.errors import IngestError


def check_time_increases(
    t: np.ndarray,
    *,
    file: str | Path,
    sample: str = "sample",
    unit: str = "s",
    line_of: Callable[[int], int] | None = None,
    field: str | None = None,
    prefix: str = "",
    restarts: np.ndarray | None = None,
    offset: int = 0,
) -> None:
    """Raise IngestError at the first sample whose time is not after the previous one.

    Parameters
    ----------
    t : (N,) time stamps in `unit`, float or integer (nanosecond stamps stay exact).
    file : the file, for the message.
    sample : what one sample is called in this format (``"row"``, ``"sample index"``,
        ``"message"``, ``"record"``); the message names it with its 0-based index.
    unit : unit of `t` as printed (``"s"``, ``"ms"``, ``"ns"``).
    line_of : 0-based sample index -> 1-based line of `file`, for text formats.
    field : the column, variable or topic field holding the time.
    prefix : what the samples are (``"topic '/imu': "``), put before the message.
    restarts : (N,) bool, True where a new block of samples begins whose time starts
        afresh (a CSV section whose sample counter restarts): time is checked within
        each block, not across the boundary.
    offset : the index of ``t[0]`` in the record, for a record checked in chunks (each
        chunk with the previous one's last stamp in front: ``offset`` is then its index).

    Raises
    ------
    IngestError : ``"time not strictly increasing at <sample> <i> (0-based; duplicated
        | going back: <t[i-1]> <unit> then <t[i]> <unit>; time must increase)"``
        with the file, the line (when `line_of` is given) and the field.
    """
    back = t[1:] <= t[:-1]
    if restarts is not None:
        back &= ~restarts[1:]
    bad = np.flatnonzero(back)
    if not bad.size:
        return
    i = int(bad[0]) + 1
    how = "duplicated" if t[i] == t[i - 1] else "going back"
    raise IngestError(
        f"{prefix}time not strictly increasing at {sample} {offset + i} (0-based; {how}: "
        f"{_number(t[i - 1])} {unit} then {_number(t[i])} {unit}; time must increase)",
        file=file,
        line=None if line_of is None else line_of(offset + i),
        field=field,
    )


def _number(value: np.generic) -> str:
    """Exact for integer stamps, shortest round-trip form for floats."""
    if isinstance(value, np.integer):
        return str(int(value))
    return repr(float(value))
