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
takes the one of both logged at the higher rate (PX4 often logs
``sensor_accel`` / ``sensor_gyro`` at 1 Hz beside a fast ``sensor_combined``),
``sensor_accel`` + ``sensor_gyro`` on a tie (they carry temperature). A source
below ``min_rate_hz`` is refused with every source's rate
(pipelines.ingest.log_samples).
"""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np

from calib_core.recording import Recording
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import (
    MIN_RATE_HZ,
    LogSource,
    checked_recording,
    choose_source,
    cut_tail,
    read_log,
    recorded_temperature,
    stamp_rate,
)

SOURCES = ("auto", "sensor_accel", "sensor_combined")
ULOG_MAGIC = b"ULog\x01\x12\x35"
ULOG_HEADER_BYTES = 16  # magic, version, start timestamp
# The record types of the ULog format (flag bits, format, info, info multiple, parameter,
# parameter default, subscription, unsubscription, data, logging, tagged logging, sync,
# dropout).
RECORD_TYPES = frozenset(b"BFIMPQARDLCSO")
ADD_LOGGED = ord("A")  # record type of a subscription: uint8 multi_id, uint16 msg_id, name
TOPICS = ("sensor_combined", "sensor_accel", "sensor_gyro")


def load_ulog(path: Path):
    """(the pyulog.ULog of the IMU topics, the findings about the file: `cut_tail` of a log
    read to its last whole record); IngestError naming the file if it is not a ULog or is
    damaged inside."""
    from pyulog import ULog

    path = Path(path)
    ulog = read_log(
        path,
        lambda name: ULog(name, list(TOPICS)),
        magic=ULOG_MAGIC,
        kind="ULog",
        expected="a ULog file: expected the magic",
    )
    findings = check_records(path)
    if ulog.file_corruption:
        raise IngestError(
            "damaged ULog: records pyulog cannot parse (skipped bytes or an unknown message "
            "type); ULog carries no checksum, so no sample of it can be trusted",
            file=path,
        )
    return ulog, findings


def check_records(path: Path) -> tuple[dict, ...]:
    """Refuse a ULog whose records do not follow each other; find a cut last record.

    A ULog is a 16-byte header, then records of (uint16 size, uint8 type, size bytes);
    pyulog skips a record of a type it does not know (a damaged size or type byte then
    hides the samples it spans) and starts a topic afresh when its subscription comes
    twice (a chunk written twice): each is refused, naming the byte offset. A last record
    the file cuts short (a logger that lost power) is dropped, as pyulog does: the log is
    read to its last whole record, with the `cut_tail` finding returned.
    """
    with path.open("rb") as fh:
        data = fh.read()
    size, pos, start = len(data), ULOG_HEADER_BYTES, ULOG_HEADER_BYTES
    subscribed: dict[int, int] = {}  # msg_id -> byte offset of its subscription
    head = struct.Struct("<HB").unpack_from
    while pos + 3 <= size:
        start = pos
        length, kind = head(data, pos)
        pos += 3 + length
        if kind not in RECORD_TYPES:  # pyulog skips it, and the samples inside
            raise IngestError(
                f"damaged ULog: a record of unknown type 0x{kind:02x} at byte offset "
                f"{start} ({pos - start} bytes); ULog carries no checksum, so the records "
                "around it cannot be trusted",
                file=path,
            )
        if kind == ADD_LOGGED and pos <= size:
            msg_id = int.from_bytes(data[start + 4 : start + 6], "little")
            if msg_id in subscribed:  # pyulog would drop the samples logged before it
                raise IngestError(
                    f"damaged ULog: message id {msg_id} is subscribed at byte offset "
                    f"{subscribed[msg_id]} and again at byte offset {start} (a chunk of the "
                    "log written twice)",
                    file=path,
                )
            subscribed[msg_id] = start
    if pos == size:
        return ()
    cut = start if pos > size else pos  # a record's body, or its 3-byte head, cut short
    return (cut_tail(path, "ULog", cut, size - cut, size),)


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


def ulog_sources(ulog, instances: list[int] | None = None) -> list[LogSource]:
    """The sources of accelerometer + gyro samples in a loaded ULog, separate topics first.

    `instances` limits the ``sensor_accel`` / ``sensor_gyro`` pairs to those instances
    (None: every instance the log holds both of).
    """
    topics = {(d.name, d.multi_id): d for d in ulog.data_list}
    pairs = sorted(i for n, i in topics if n == "sensor_accel" and ("sensor_gyro", i) in topics)
    out = []
    for i in pairs if instances is None else [i for i in instances if i in pairs]:
        accel, gyro = topics["sensor_accel", i], topics["sensor_gyro", i]
        rates = [stamp_rate(_stamps(d)) for d in (accel, gyro)]
        out.append(
            LogSource(
                f"sensor_accel[{i}] + sensor_gyro[{i}]",
                "sensor_accel",
                min(len(_stamps(accel)), len(_stamps(gyro))),
                None if None in rates else min(rates),  # type: ignore[type-var]
                "temperature" in accel.data,
            )
        )
    if ("sensor_combined", 0) in topics:
        stamps = _stamps(topics["sensor_combined", 0])
        out.append(
            LogSource("sensor_combined", "sensor_combined", len(stamps), stamp_rate(stamps), False)
        )
    return out


def _stamps(data) -> np.ndarray:
    """A topic's time stamps in s (timestamp_sample when logged), for its rate."""
    stamp = "timestamp_sample" if "timestamp_sample" in data.data else "timestamp"
    return np.asarray(data.data.get(stamp, ()), dtype=float) * 1e-6


def read_ulog(
    path: Path, *, source: str = "auto", instance: int = 0, min_rate_hz: float = MIN_RATE_HZ
) -> Recording:
    """Read the IMU samples of a PX4 ULog.

    Parameters
    ----------
    path : a ``.ulg`` file.
    source : ``"auto"`` (the higher-rate one), ``"sensor_accel"`` (with ``sensor_gyro``)
        or ``"sensor_combined"``.
    instance : the IMU instance (ULog ``multi_id``) of sensor_accel / sensor_gyro.
    min_rate_hz : the slowest source accepted, Hz.

    Returns
    -------
    Recording with t (N,) s on the log's clock (us since boot), acc (N, 3) m/s^2,
    gyr (N, 3) rad/s, temp (N,) deg C when logged (None when not).

    Raises
    ------
    IngestError naming the file and the topic / field: not a ULog, damaged,
    a missing topic or field, a source below `min_rate_hz` (every source's rate
    listed), a non-finite sample, time not increasing.
    """
    path = Path(path)
    if source not in SOURCES:
        raise IngestError(
            f"unknown source {source!r}; expected one of {', '.join(SOURCES)}",
            field="format.source",
        )
    ulog, findings = load_ulog(path)
    sources = ulog_sources(ulog, [instance])
    if source != "auto" and source not in {s.key for s in sources}:
        # the missing topic, named as the log has it
        _topic(ulog, path, source, instance if source == "sensor_accel" else 0)
        _topic(ulog, path, "sensor_gyro", instance)
    chosen = choose_source(
        path, sources, None if source == "auto" else source, min_rate_hz=min_rate_hz
    )
    if chosen.key == "sensor_accel":
        rec = _separate(ulog, path, instance)
    else:
        rec = _combined(ulog, path, instance)
    return dataclasses.replace(rec, findings=findings)


def _separate(ulog, path: Path, instance: int) -> Recording:
    accel = _topic(ulog, path, "sensor_accel", instance)
    gyro = _topic(ulog, path, "sensor_gyro", instance)
    stamp = "timestamp_sample" if "timestamp_sample" in accel.data else "timestamp"
    t = _fields(accel, path, [stamp])[:, 0] * 1e-6
    t_gyr = _fields(gyro, path, [stamp])[:, 0] * 1e-6
    acc = _fields(accel, path, ["x", "y", "z"])
    gyr = _fields(gyro, path, ["x", "y", "z"])
    temp = _fields(accel, path, ["temperature"])[:, 0] if "temperature" in accel.data else None
    temp = recorded_temperature(temp)
    if len(t_gyr) != len(t) or not np.array_equal(t_gyr, t):
        # Accelerometer samples outside the gyro's span have no gyro value: left out.
        keep = (t >= t_gyr[0]) & (t <= t_gyr[-1]) if len(t_gyr) else np.zeros(len(t), bool)
        t, acc = t[keep], acc[keep]
        temp = None if temp is None else temp[keep]
        gyr = _onto(t, t_gyr, gyr, path, "sensor_gyro")
    what = f"sensor_accel[{instance}]"
    devices = {k: i for k, i in (("accel", _device_id(accel)), ("gyro", _device_id(gyro))) if i}
    return checked_recording(path, what, t, {"acc": acc, "gyr": gyr}, temp=temp, devices=devices)


def _device_id(data) -> int | None:  # noqa: ANN001 - a pyulog data set
    """The topic's ``device_id`` (the id PX4's CAL_* / TC_* parameters must name), None when
    the topic has none, it is 0 or it changes within the log (two sensors, no one id)."""
    ids = np.unique(np.asarray(data.data.get("device_id", ()), dtype=np.int64))
    return int(ids[0]) if len(ids) == 1 and ids[0] != 0 else None


def _combined(ulog, path: Path, instance: int) -> Recording:
    data = _topic(ulog, path, "sensor_combined", 0)
    t = _fields(data, path, ["timestamp"])[:, 0] * 1e-6
    gyr = _fields(data, path, [f"gyro_rad[{i}]" for i in range(3)])
    acc = _fields(data, path, [f"accelerometer_m_s2[{i}]" for i in range(3)])
    temp = None
    for d in ulog.data_list:
        if d.name == "sensor_accel" and d.multi_id == instance and "temperature" in d.data:
            t_temp = np.asarray(d.data["timestamp"], dtype=float) * 1e-6
            logged = recorded_temperature(np.asarray(d.data["temperature"], dtype=float))
            if logged is not None and len(t_temp) == len(logged):
                temp = np.interp(t, t_temp, logged)
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
