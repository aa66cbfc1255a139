"""Checks shared by the readers of binary logs (ULog, DataFlash, ROS bags).

A log has no lines: a bad sample is named by its topic or message type, its
record index (0-based, in the order the log holds them) and its field. The
policy is the one of every reader (docs/manifest.md, "Bad samples"): a
non-finite value or a time stamp that does not increase refuses the run with
file, record and field; nothing is dropped silently.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib_core.recording import Recording
from pipelines.ingest.errors import IngestError
from pipelines.ingest.time_order import check_time_increases


def checked_recording(
    path: Path,
    what: str,
    t: np.ndarray,
    channels: dict[str, np.ndarray],
    *,
    temp: np.ndarray | None = None,
    temp_field: str = "temperature",
) -> Recording:
    """A Recording of `what` (``"sensor_combined"``, ``"IMU[0]"``, ``"/imu"``) after the checks.

    Parameters
    ----------
    path : the log file, for messages.
    what : the topic or message type the samples come from.
    t : (N,) s.
    channels : {"acc": (N, 3) m/s^2, "gyr": (N, 3) rad/s} with the field names
        to report as keys ``"acc:<field>"`` optional (see `fields`).
    temp : (N,) deg C or None.

    Raises
    ------
    IngestError naming the file, ``record <i>`` and the field of the first
    non-finite value or non-increasing time stamp, or an empty topic.
    """
    if len(t) == 0:
        raise IngestError(f"{what}: no samples", file=path, field=what)
    arrays = {"time": t[:, None], **channels}
    if temp is not None:
        arrays[temp_field] = temp[:, None]
    for name, values in arrays.items():
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise IngestError(
                f"{what} record {i}: expected finite numbers, got {values[i].tolist()}",
                file=path,
                field=f"{what}.{name}",
            )
    check_time_increases(t, file=path, sample="record", field=f"{what}.time", prefix=f"{what}: ")
    return Recording(t=t, acc=channels["acc"], gyr=channels["gyr"], temp=temp, source=str(path))
