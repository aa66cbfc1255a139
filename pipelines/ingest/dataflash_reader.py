"""ArduPilot DataFlash (.bin) reader (pymavlink's DFReader) -> Recording.

ArduPilot logs each IMU as ``IMU`` records: ``TimeUS`` (us since boot),
``GyrX..Z`` (rad/s), ``AccX..Z`` (m/s^2), ``T`` (deg C). Since 4.1 one ``IMU``
message carries the instance in field ``I``; older logs write ``IMU``,
``IMU2``, ``IMU3``. ``instance`` (0-based) picks one IMU in either layout; left
out, the IMU logged at the highest rate (the first on a tie; a rate below
``min_rate_hz`` is refused with every IMU's rate, pipelines.ingest.log_samples).
A ``T`` of 0 in every record is a sensor without a thermometer: no temperature.
"""

from __future__ import annotations

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
    quiet,
    read_log,
    recorded_temperature,
    stamp_rate,
)

FIELDS = ("TimeUS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ", "T")
DF_HEAD = b"\xa3\x95"


def open_dataflash(path: Path):
    """pymavlink's DFReader_binary of `path`; IngestError naming the file if it is not one."""
    from pymavlink.DFReader import DFReader_binary

    path = Path(path)
    reader = read_log(
        path,
        lambda name: DFReader_binary(name, zero_time_base=False),
        magic=DF_HEAD,
        kind="DataFlash log",
        expected="an ArduPilot DataFlash log: expected the record head",
    )
    findings = check_records(path, {t: f.len for t, f in reader.formats.items()})
    return reader, findings


def check_records(path: Path, lengths: dict[int, int]) -> tuple[dict, ...]:
    """Refuse a log whose records do not follow each other; find a cut last record.

    Every record is the head a3 95, a type byte and the body its FMT gives; pymavlink
    skips bytes it cannot parse (refused here, naming the byte offset) and stops at a
    record the file cuts short (a logger that lost power): the log is read to its last
    whole record, with the `cut_tail` finding returned. `lengths` : record type -> record
    length in bytes (head included).
    """
    with path.open("rb") as fh:
        data = fh.read()
    size, pos = len(data), 0
    while pos < size:
        head = data[pos : pos + 3]
        length = lengths.get(head[2]) if len(head) == 3 else None
        if len(head) < 3 and head == DF_HEAD[: len(head)]:  # a record head cut short
            return (cut_tail(path, "DataFlash log", pos, size - pos, size),)
        if head[:2] != DF_HEAD or length is None:
            raise IngestError(
                "damaged DataFlash log: expected a record head a3 95 and a type with a FMT "
                f"at byte offset {pos}, found {head.hex(' ')}",
                file=path,
            )
        if pos + length > size:  # the last record cut short
            return (cut_tail(path, "DataFlash log", pos, size - pos, size),)
        pos += length
    return ()


def imu_rows(reader, path: Path) -> dict[int, tuple[list[tuple], str]]:
    """instance -> (the FIELDS of each of its IMU records, the message name they came from)."""
    by_instance: dict[int, tuple[list[tuple], str]] = {}
    count = 0
    try:
        while True:
            with quiet():
                m = reader.recv_match(type=["IMU", "IMU2", "IMU3"])
            if m is None:
                break
            mtype = m.get_type()
            if mtype == "IMU" and hasattr(m, "I"):
                instance = int(m.I)
            else:
                instance = 0 if mtype == "IMU" else int(mtype[3:]) - 1
            rows = by_instance.setdefault(instance, ([], mtype))[0]
            rows.append(tuple(getattr(m, f) for f in FIELDS))
            count += 1
    except AttributeError as exc:
        raise IngestError(f"IMU record lacks a field: {exc}", file=path, field="IMU") from None
    except Exception as exc:
        raise IngestError(
            f"damaged DataFlash log after {count} IMU records ({type(exc).__name__}: {exc})",
            file=path,
        ) from None
    return by_instance


def dataflash_sources(by_instance: dict[int, tuple[list[tuple], str]]) -> list[LogSource]:
    """One source per IMU instance, in instance order."""
    out = []
    for instance in sorted(by_instance):
        rows, name = by_instance[instance]
        t = np.array([r[0] for r in rows], dtype=float) * 1e-6
        temp = recorded_temperature(np.array([r[7] for r in rows], dtype=float))
        label = f"{name}[{instance}]" if name == "IMU" else name
        out.append(LogSource(label, instance, len(rows), stamp_rate(t), temp is not None))
    return out


def read_dataflash(
    path: Path, *, instance: int | None = None, min_rate_hz: float = MIN_RATE_HZ
) -> Recording:
    """Read one IMU of an ArduPilot DataFlash log.

    Parameters
    ----------
    path : a ``.bin`` log.
    instance : 0-based IMU instance (field ``I``, or message IMU2 for 1, ...); None: the
        one logged at the highest rate.
    min_rate_hz : the slowest IMU accepted, Hz.

    Returns
    -------
    Recording with t (N,) s since boot, acc (N, 3) m/s^2, gyr (N, 3) rad/s, temp (N,)
    deg C (None when the log carries none).

    Raises
    ------
    IngestError naming the file and message/field: not a DataFlash log, no IMU
    records of that instance, an IMU below `min_rate_hz` (every IMU's rate listed),
    a non-finite value, time not increasing.
    """
    path = Path(path)
    reader, findings = open_dataflash(path)
    by_instance = imu_rows(reader, path)
    if instance is not None and instance not in by_instance:
        raise IngestError(
            f"no IMU records of instance {instance} (messages IMU with I = {instance}"
            + (f", or IMU{instance + 1}" if instance else "")
            + ")",
            file=path,
            field="format.instance" if instance else "IMU",
        )
    chosen = choose_source(
        path,
        dataflash_sources(by_instance),
        instance,
        min_rate_hz=min_rate_hz,
        field="format.instance",
    )
    rows, name = by_instance[int(chosen.key)]
    data = np.array(rows, dtype=float)
    what = chosen.name
    return checked_recording(
        path,
        what,
        data[:, 0] * 1e-6,
        {"gyr": data[:, 1:4], "acc": data[:, 4:7]},
        temp=recorded_temperature(data[:, 7]),
        temp_field="T",
        devices={"imu": int(chosen.key)},
        findings=findings,
    )
