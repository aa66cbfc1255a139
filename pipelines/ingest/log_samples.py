"""Checks shared by the readers of binary logs (ULog, DataFlash, ROS bags), and the
choice among the sources of IMU samples a log holds.

A log has no lines: a bad sample is named by its topic or message type, its
record index (0-based, in the order the log holds them) and its field. The
policy is the one of every reader (docs/manifest.md, "Bad samples"): a
non-finite value, a value no IMU can read (a damaged record of a log without
checksum) or a time stamp that does not increase refuses the run with file,
record and field; nothing is dropped silently.

A log may hold the same IMU several times (PX4's ``sensor_combined`` beside
``sensor_accel`` / ``sensor_gyro`` logged at 1 Hz; ArduPilot's IMU instances;
several Imu topics of a bag). The default (``source = "auto"``) takes the one
logged at the highest rate (on a tie, the first the reader lists: the one with
its own temperature); a source below `MIN_RATE_HZ` (``format.min_rate_hz``) is
refused with every source's rate listed.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from calib_core.recording import Recording
from pipelines.ingest.errors import IngestError, file_head
from pipelines.ingest.time_order import check_time_increases


def checked_recording(
    path: Path,
    what: str,
    t: np.ndarray,
    channels: dict[str, np.ndarray],
    *,
    temp: np.ndarray | None = None,
    temp_field: str = "temperature",
    devices: dict[str, int] | None = None,
    findings: tuple[dict, ...] = (),
) -> Recording:
    """A Recording of `what` (``"sensor_combined"``, ``"IMU[0]"``, ``"/imu"``) after the checks.

    Parameters
    ----------
    path : the log file, for messages.
    what : the topic or message type the samples come from.
    t : (N,) s.
    channels : {"acc": (N, 3) m/s^2, "gyr": (N, 3) rad/s}.
    temp : (N,) deg C or None; `temp_field` names it in messages.
    devices : the sensors' firmware ids the log records (`Recording.devices`).
    findings : the reader's findings about the file (`cut_tail`).

    Raises
    ------
    IngestError naming the file, ``record <i>`` and the field of the first
    non-finite value, value beyond any IMU's range (`ACC_LIMIT`, `GYR_LIMIT`) or
    non-increasing time stamp, or an empty topic.
    """
    if len(t) == 0:
        raise IngestError(f"{what}: no samples", file=path, field=what)
    arrays = {"time": t, **channels} | ({} if temp is None else {temp_field: temp})
    check_samples(path, what, arrays)
    return Recording(
        t=t,
        acc=channels["acc"],
        gyr=channels["gyr"],
        temp=temp,
        source=str(path),
        devices=devices or {},
        findings=findings,
    )


def cut_tail(path: Path, kind: str, offset: int, dropped: int, size: int) -> dict:
    """The ``record:cut:<file>`` finding of a log read to its last whole record (CheckResult
    fields): `dropped` bytes from byte `offset` of a file of `size` bytes, the start of a
    record the file cuts short (a logger that lost power while writing)."""
    return {
        "name": f"record:cut:{path.name}",
        "value": float(dropped),
        "limit": 0.0,
        "passed": False,
        "detail": (
            f"{path}: {kind} cut while written: the last {dropped} byte(s) (from byte offset "
            f"{offset} of {size}, a record the file cuts short) were dropped; read to its "
            "last whole record"
        ),
    }


def check_samples(
    path: Path,
    what: str,
    arrays: dict[str, np.ndarray],
    *,
    offset: int = 0,
    last: float | None = None,
) -> None:
    """`checked_recording`'s checks of samples, which may be one chunk of a record.

    Parameters
    ----------
    path, what : as `checked_recording`.
    arrays : {"time": (N,) s, "acc": (N, 3) m/s^2, "gyr": (N, 3) rad/s}, and the
        temperature (N,) deg C under the field name messages give it, if any.
    offset : the record index of ``arrays["time"][0]`` (a chunk read after `offset` records).
    last : the previous chunk's last time, s (time must increase across chunks).

    Raises
    ------
    IngestError as `checked_recording`, records numbered in the whole record.
    """
    for name, values in arrays.items():
        rows = values.reshape(len(values), -1)
        bad = np.flatnonzero(~np.isfinite(rows).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise IngestError(
                f"{what} record {offset + i}: expected finite numbers, got {rows[i].tolist()}",
                file=path,
                field=f"{what}.{name}",
            )
    found = impossible_reading(arrays)
    if found is not None:
        name, i, text = found
        raise IngestError(f"{what} record {offset + i}: {text}", file=path, field=f"{what}.{name}")
    t = arrays["time"]
    ahead = t if last is None else np.concatenate([[last], t])
    check_time_increases(
        ahead,
        file=path,
        sample="record",
        field=f"{what}.time",
        prefix=f"{what}: ",
        offset=offset - (last is not None),
    )


def check_finite(name: str, where: str, what: str, values: np.ndarray, offset: int = 0) -> None:
    """IngestError at the first message with a non-finite value (`offset`: index of the
    first row of `values` in the topic, when it is checked in chunks)."""
    bad = ~np.isfinite(values)
    if bad.any():
        k = offset + int(np.flatnonzero(bad.reshape(len(values), -1).any(axis=1))[0])
        raise IngestError(f"{where}: non-finite {what} in message {k} (0-based)", file=name)


def impossible_reading(channels: dict[str, np.ndarray]) -> tuple[str, int, str] | None:
    """(channel, 0-based sample, description) of the first acc or gyr reading beyond what
    any IMU measures (`ACC_LIMIT`, `GYR_LIMIT`), or None."""
    for name, limit, unit, scale in (
        ("acc", ACC_LIMIT, "m/s^2", 1.0),
        ("gyr", GYR_LIMIT, "deg/s", 180.0 / np.pi),
    ):
        data = channels[name]
        if len(data) == 0 or (-limit <= data.min() and data.max() <= limit):
            continue
        i = int(np.flatnonzero(np.abs(data).max(axis=1) > limit)[0])
        shown = np.round(data[i] * scale, 6).tolist()
        text = (
            f"{name} {shown} {unit}, beyond what any IMU measures "
            f"({limit * scale:g} {unit}): a damaged value"
        )
        return name, i, text
    return None


def check_readings(rec: Recording, path: str) -> None:
    """Every reader's samples before any use: a non-finite value or a reading no IMU makes
    is refused naming the file (`path`), the channel and the 0-based sample index."""
    arrays = {"time": rec.t[:, None], "acc": rec.acc, "gyr": rec.gyr}
    if rec.temp is not None:
        arrays["temp"] = rec.temp[:, None]
    for name, values in arrays.items():
        if np.isfinite(values.sum()):  # one reduction; NaN or inf anywhere makes it non-finite
            continue
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise IngestError(
                f"sample {i} (0-based, t = {rec.t[i]!r}): {name} {values[i].tolist()}; "
                "expected finite numbers",
                file=path,
                field=name,
            )
    found = impossible_reading({"acc": rec.acc, "gyr": rec.gyr})
    if found is not None:
        name, i, text = found
        raise IngestError(
            f"sample {i} (0-based, t = {rec.t[i]:.6g} s): {text}", file=path, field=name
        )


# Beyond the range of any IMU (shock accelerometers reach 2000 g, gyros 20000 deg/s): a
# value of a damaged record, not a reading.
ACC_LIMIT = 2000.0 * 9.80665  # m/s^2
GYR_LIMIT = np.deg2rad(20000.0)  # rad/s

# No procedure turns 1 Hz samples into a calibration: a turn of a second is one sample, a
# static mean of 10 s ten. A log below this rate is refused unless format.min_rate_hz says.
MIN_RATE_HZ = 10.0
TIE = 0.99  # rates within 1 % are the same rate (the preference order decides)


@dataclass(frozen=True)
class LogSource:
    """One source of accelerometer + gyro samples in a log.

    Attributes
    ----------
    name : as the log names it (``"sensor_combined"``, ``"sensor_accel[0] + sensor_gyro[0]"``,
        ``"IMU[1]"``, ``"/imu/data"``).
    key : what selects it (format.source, format.instance or format.imu_topic).
    samples : how many samples it holds (the slower of accelerometer and gyro).
    rate_hz : samples per second (from the median time step; the slower of both), None
        with fewer than two samples.
    temperature : whether it carries a temperature of its own.
    """

    name: str
    key: str | int
    samples: int
    rate_hz: float | None
    temperature: bool

    def describe(self) -> str:
        rate = "rate unknown" if self.rate_hz is None else f"{self.rate_hz:.4g} Hz"
        return f"{self.name} {rate} ({self.samples} samples)"

    def summary(self) -> dict:
        """For `calib inspect`: name, rate, samples, temperature."""
        rate = None if self.rate_hz is None else round(self.rate_hz, 3)
        return {
            "source": self.name,
            "rate_hz": rate,
            "samples": self.samples,
            "temperature": "recorded" if self.temperature else "not recorded",
        }


def stamp_rate(t: np.ndarray) -> float | None:
    """Samples per second of time stamps `t` (s, any order) from the median step."""
    step = np.median(np.diff(np.sort(np.asarray(t, dtype=float)))) if len(t) > 1 else 0.0
    return float(1.0 / step) if step > 0 else None


def choose_source(
    path: Path,
    sources: list[LogSource],
    wanted: str | int | None = None,
    *,
    min_rate_hz: float = MIN_RATE_HZ,
    field: str = "format.source",
) -> LogSource:
    """The source to read: `wanted` (a key), else the highest-rate one.

    Raises
    ------
    IngestError naming the file and `field`, listing every source with its rate: no
    source, an unknown `wanted`, or the source's rate below `min_rate_hz`.
    """
    listed = "; ".join(s.describe() for s in sources) or "none"
    if wanted is not None:
        chosen = next((s for s in sources if s.key == wanted), None)
        if chosen is None:
            raise IngestError(
                f"no source {wanted!r} of accelerometer and gyro; the log's sources: {listed}",
                file=path,
                field=field,
            )
    elif not sources:
        raise IngestError(
            "no accelerometer and gyro samples (no IMU source)", file=path, field=field
        )
    else:
        best = max(s.rate_hz or 0.0 for s in sources)
        chosen = next(s for s in sources if (s.rate_hz or 0.0) >= TIE * best)
    if (chosen.rate_hz or 0.0) < min_rate_hz:
        raise IngestError(
            f"source {chosen.name} is logged at "
            f"{'an unknown rate' if chosen.rate_hz is None else f'{chosen.rate_hz:.4g} Hz'}, "
            f"below the {min_rate_hz:g} Hz a calibration needs; the log's sources: {listed}",
            file=path,
            field=field,
        )
    return chosen


def recorded_temperature(temp: np.ndarray | None) -> np.ndarray | None:
    """`temp` (deg C), or None when the log does not carry one: a field that is 0 or NaN in
    every record is a sensor without a thermometer, not a reading of 0 deg C."""
    if temp is None or not len(temp):
        return None
    if np.all(np.isnan(temp)) or not np.any(temp):
        return None
    return temp


Log = TypeVar("Log")


def read_log(
    path: Path, parse: Callable[[str], Log], *, magic: bytes, kind: str, expected: str
) -> Log:
    """``parse(str(path))`` (a log library's reader), its prints kept off stdout (`quiet`);
    IngestError naming the file if it cannot be read, does not start with `magic` ("not
    <expected> <magic>, found <bytes>") or is damaged ("damaged <kind> (<exception>)")."""
    head = file_head(path, len(magic))
    if head != magic:
        raise IngestError(f"not {expected} {magic.hex(' ')}, found {head.hex(' ')}", file=path)
    try:
        with quiet():
            return parse(str(path))
    except Exception as exc:  # the log libraries raise plain exceptions on damaged logs
        raise IngestError(f"damaged {kind} ({type(exc).__name__}: {exc})", file=path) from None


def quiet():
    """A context in which a log library's prints ("Skipped 12 bad bytes", "File corruption
    detected") do not reach stdout, which holds `calib process --json`'s document; what
    they report is refused by the record checks with the file and byte offset."""
    return contextlib.redirect_stdout(io.StringIO())
