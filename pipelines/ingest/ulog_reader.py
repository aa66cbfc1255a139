"""PX4 ULog reader (pyulog) -> Recording.

PX4 logs its IMUs as ``sensor_combined`` (gyro and accelerometer on one time
base: the gyro's ``timestamp``; the accelerometer's own offset
``accelerometer_timestamp_relative``, under one sample step, is not applied:
static means do not depend on it and the gyro, whose integral does, keeps its
own time; no temperature) and, per IMU instance, as
``sensor_accel`` / ``sensor_gyro`` (``x, y, z`` in m/s^2 and rad/s, with
``temperature`` in deg C, ``timestamp_sample`` in us).

Topic choice (``source``): ``"sensor_accel"`` takes ``sensor_accel`` and
``sensor_gyro`` of one ``instance`` (their temperature too); the gyro must be
sampled at the accelerometer's time stamps or is linearly interpolated onto
them (a rotation's integral is kept to the interpolation error of one sample
step); ``"sensor_combined"`` takes that topic, with the temperature of
``sensor_accel`` interpolated onto its time when logged; ``"auto"`` (default)
prefers ``sensor_accel`` + ``sensor_gyro`` (they carry temperature) and falls
back to ``sensor_combined``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib_core.recording import Recording
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import checked_recording

SOURCES = ("auto", "sensor_accel", "sensor_combined")
ULOG_MAGIC = b"ULog\x01\x12\x35"
TOPICS = ("sensor_combined", "sensor_accel", "sensor_gyro")


def load_ulog(path: Path):
    """The pyulog.ULog of the IMU topics; IngestError naming the file if it is not a ULog."""
    from pyulog import ULog

    path = Path(path)
    try:
        with path.open("rb") as fh:
            head = fh.read(len(ULOG_MAGIC))
    except OSError as exc:
        raise IngestError(f"cannot read file: {exc.strerror or exc}", file=path) from None
    if head != ULOG_MAGIC:
        raise IngestError(
            f"not a ULog file: expected the magic {ULOG_MAGIC.hex(' ')}, found {head.hex(' ')}",
            file=path,
        )
    try:
        return ULog(str(path), list(TOPICS))
    except Exception as exc:  # pyulog raises plain exceptions on damaged logs
        raise IngestError(f"damaged ULog ({type(exc).__name__}: {exc})", file=path) from None


def _topic(ulog, path: Path, name: str, instance: int):
    for data in ulog.data_list:
        if data.name == name and data.multi_id == instance:
            return data
    found = sorted({f"{d.name}[{d.multi_id}]" for d in ulog.data_list}) or ["none"]
    raise IngestError(
        f"no topic {name}[{instance}] in the log; IMU topics found: {', '.join(found)}",
        file=path,
        field="format.instance" if instance else "format.source",
    )


def _fields(data, path: Path, names: list[str]) -> np.ndarray:
    missing = [n for n in names if n not in data.data]
    if missing:
        raise IngestError(
            f"topic {data.name} lacks field {missing[0]!r}; it has {', '.join(data.data)}",
            file=path,
            field=f"{data.name}.{missing[0]}",
        )
    return np.column_stack([np.asarray(data.data[n], dtype=float) for n in names])


def read_ulog(path: Path, *, source: str = "auto", instance: int = 0) -> Recording:
    """Read the IMU samples of a PX4 ULog.

    Parameters
    ----------
    path : a ``.ulg`` file.
    source : ``"auto"``, ``"sensor_accel"`` (with ``sensor_gyro``) or ``"sensor_combined"``.
    instance : the IMU instance (ULog ``multi_id``) of sensor_accel / sensor_gyro.

    Returns
    -------
    Recording with t (N,) s on the log's clock (us since boot), acc (N, 3) m/s^2,
    gyr (N, 3) rad/s, temp (N,) deg C when logged.

    Raises
    ------
    IngestError naming the file and the topic / field: not a ULog, damaged,
    a missing topic or field, a non-finite sample, time not increasing.
    """
    path = Path(path)
    if source not in SOURCES:
        raise IngestError(
            f"unknown source {source!r}; expected one of {', '.join(SOURCES)}",
            field="format.source",
        )
    ulog = load_ulog(path)
    names = {(d.name, d.multi_id) for d in ulog.data_list}
    separate = ("sensor_accel", instance) in names and ("sensor_gyro", instance) in names
    if source == "sensor_accel" or (source == "auto" and separate):
        return _separate(ulog, path, instance)
    return _combined(ulog, path, instance)


def _separate(ulog, path: Path, instance: int) -> Recording:
    accel = _topic(ulog, path, "sensor_accel", instance)
    gyro = _topic(ulog, path, "sensor_gyro", instance)
    stamp = "timestamp_sample" if "timestamp_sample" in accel.data else "timestamp"
    t = _fields(accel, path, [stamp])[:, 0] * 1e-6
    t_gyr = _fields(gyro, path, [stamp])[:, 0] * 1e-6
    acc = _fields(accel, path, ["x", "y", "z"])
    gyr = _fields(gyro, path, ["x", "y", "z"])
    temp = _fields(accel, path, ["temperature"])[:, 0] if "temperature" in accel.data else None
    if len(t_gyr) != len(t) or not np.array_equal(t_gyr, t):
        # Accelerometer samples outside the gyro's span have no gyro value: left out.
        keep = (t >= t_gyr[0]) & (t <= t_gyr[-1]) if len(t_gyr) else np.zeros(len(t), bool)
        t, acc = t[keep], acc[keep]
        temp = None if temp is None else temp[keep]
        gyr = _onto(t, t_gyr, gyr, path, "sensor_gyro")
    what = f"sensor_accel[{instance}]"
    return checked_recording(path, what, t, {"acc": acc, "gyr": gyr}, temp=temp)


def _combined(ulog, path: Path, instance: int) -> Recording:
    data = _topic(ulog, path, "sensor_combined", 0)
    t = _fields(data, path, ["timestamp"])[:, 0] * 1e-6
    gyr = _fields(data, path, [f"gyro_rad[{i}]" for i in range(3)])
    acc = _fields(data, path, [f"accelerometer_m_s2[{i}]" for i in range(3)])
    temp = None
    for d in ulog.data_list:
        if d.name == "sensor_accel" and d.multi_id == instance and "temperature" in d.data:
            t_temp = np.asarray(d.data["timestamp"], dtype=float) * 1e-6
            temp = np.interp(t, t_temp, np.asarray(d.data["temperature"], dtype=float))
    return checked_recording(path, "sensor_combined", t, {"acc": acc, "gyr": gyr}, temp=temp)


def _onto(t: np.ndarray, t_src: np.ndarray, values: np.ndarray, path: Path, what: str):
    """`values` sampled at `t_src` linearly interpolated onto `t` (which they must span)."""
    if len(t_src) < 2 or len(t) == 0 or np.any(np.diff(t_src) <= 0):
        raise IngestError(
            f"{what}: its time stamps do not overlap the accelerometer's or do not increase; "
            "cannot put both on one time base",
            file=path,
            field=what,
        )
    return np.column_stack([np.interp(t, t_src, values[:, k]) for k in range(3)])
