"""ArduPilot DataFlash (.bin) reader (pymavlink's DFReader) -> Recording.

ArduPilot logs each IMU as ``IMU`` records: ``TimeUS`` (us since boot),
``GyrX..Z`` (rad/s), ``AccX..Z`` (m/s^2), ``T`` (deg C). Since 4.1 one ``IMU``
message carries the instance in field ``I``; older logs write ``IMU``,
``IMU2``, ``IMU3``. ``instance`` (0-based) picks one IMU in either layout.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib_core.recording import Recording
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import checked_recording

FIELDS = ("TimeUS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ", "T")
DF_HEAD = b"\xa3\x95"


def open_dataflash(path: Path):
    """pymavlink's DFReader_binary of `path`; IngestError naming the file if it is not one."""
    from pymavlink.DFReader import DFReader_binary

    path = Path(path)
    try:
        with path.open("rb") as fh:
            head = fh.read(3)
    except OSError as exc:
        raise IngestError(f"cannot read file: {exc.strerror or exc}", file=path) from None
    if head[:2] != DF_HEAD:
        raise IngestError(
            "not an ArduPilot DataFlash log: expected the record head a3 95, found "
            + head.hex(" "),
            file=path,
        )
    try:
        return DFReader_binary(str(path), zero_time_base=False)
    except Exception as exc:  # pymavlink raises plain exceptions on damaged logs
        problem = f"damaged DataFlash log ({type(exc).__name__}: {exc})"
        raise IngestError(problem, file=path) from None


def imu_rows(reader, path: Path, instance: int) -> tuple[list[tuple], str]:
    """The FIELDS of every IMU record of `instance` and the message name they came from."""
    names = [f"IMU{instance + 1}" if instance else "IMU"]
    rows: list[tuple] = []
    name = "IMU"
    try:
        while True:
            m = reader.recv_match(type=["IMU", names[0]])
            if m is None:
                break
            mtype = m.get_type()
            if mtype == "IMU" and hasattr(m, "I"):
                if instance != m.I:
                    continue
            elif mtype != names[0]:
                continue
            name = mtype
            rows.append(tuple(getattr(m, f) for f in FIELDS))
    except AttributeError as exc:
        raise IngestError(f"IMU record lacks a field: {exc}", file=path, field="IMU") from None
    except Exception as exc:
        raise IngestError(
            f"damaged DataFlash log after {len(rows)} IMU records ({type(exc).__name__}: {exc})",
            file=path,
        ) from None
    return rows, name


def read_dataflash(path: Path, *, instance: int = 0) -> Recording:
    """Read one IMU of an ArduPilot DataFlash log.

    Parameters
    ----------
    path : a ``.bin`` log.
    instance : 0-based IMU instance (field ``I``, or message IMU2 for 1, ...).

    Returns
    -------
    Recording with t (N,) s since boot, acc (N, 3) m/s^2, gyr (N, 3) rad/s, temp (N,) deg C.

    Raises
    ------
    IngestError naming the file and message/field: not a DataFlash log, no IMU
    records of that instance, a non-finite value, time not increasing.
    """
    path = Path(path)
    reader = open_dataflash(path)
    rows, name = imu_rows(reader, path, instance)
    if not rows:
        raise IngestError(
            f"no IMU records of instance {instance} (messages IMU with I = {instance}"
            + (f", or IMU{instance + 1}" if instance else "")
            + ")",
            file=path,
            field="format.instance" if instance else "IMU",
        )
    data = np.array(rows, dtype=float)
    what = f"{name}[{instance}]" if name == "IMU" else name
    return checked_recording(
        path, what, data[:, 0] * 1e-6, {"gyr": data[:, 1:4], "acc": data[:, 4:7]},
        temp=data[:, 7], temp_field="T",
    )  # fmt: skip
