"""What an autopilot file needs beyond the numbers: the sensor's device id, the IMU's mounting
(the firmware's own rotation names) and the header that tells a user what to set.

Both firmwares rotate the IMU chip's axes into the board frame *before* they subtract the
offsets and apply the scales (PX4: the driver's rotation, then
``(data - thermal_offset - CAL_*_OFF) * CAL_*_SCALE``; ArduPilot
``AP_InertialSensor_Backend::_rotate_and_correct_accel``: the sensor orientation, the
temperature correction, ``INS_ACCOFFS`` / ``INS_ACCSCAL``). A calibration is solved in the
axes of the unit as it sat in the lab; `rotation` is the firmware's rotation from those axes to
its own (the enumeration of PX4's ``SENS_BOARD_ROT`` and ArduPilot's ``AHRS_ORIENTATION``), and
the offsets, scales and thermal coefficients are written in the rotated axes: offset' = R b,
scale'[i] = scale[j] where axis j turns into axis i. A rotation that is not a multiple of 90
degrees mixes the axes, which per-axis scales cannot carry: refused where scales are written.

Device ids: PX4 applies ``CAL_ACC<i>_*`` / ``TC_A<i>_*`` only to the sensor whose device id
matches ``*_ID``; a ULog records it (``sensor_accel`` / ``sensor_gyro`` ``device_id``), kept at
ingest in the ingest step's ``devices`` (`recorded_devices`). ArduPilot numbers its IMUs
(``INS_TCAL1`` is IMU instance 0); a DataFlash log records the instance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

FIRMWARES = ("px4", "ardupilot")
# (roll, pitch, yaw) in degrees of each rotation, as PX4's rot_lookup
# (src/lib/conversion/rotation.h); ArduPilot's enum (libraries/AP_Math/rotations.h) has the
# same names and numbers up to 40.
_SHARED = [
    ("NONE", (0, 0, 0)),
    ("YAW_45", (0, 0, 45)),
    ("YAW_90", (0, 0, 90)),
    ("YAW_135", (0, 0, 135)),
    ("YAW_180", (0, 0, 180)),
    ("YAW_225", (0, 0, 225)),
    ("YAW_270", (0, 0, 270)),
    ("YAW_315", (0, 0, 315)),
    ("ROLL_180", (180, 0, 0)),
    ("ROLL_180_YAW_45", (180, 0, 45)),
    ("ROLL_180_YAW_90", (180, 0, 90)),
    ("ROLL_180_YAW_135", (180, 0, 135)),
    ("PITCH_180", (0, 180, 0)),
    ("ROLL_180_YAW_225", (180, 0, 225)),
    ("ROLL_180_YAW_270", (180, 0, 270)),
    ("ROLL_180_YAW_315", (180, 0, 315)),
    ("ROLL_90", (90, 0, 0)),
    ("ROLL_90_YAW_45", (90, 0, 45)),
    ("ROLL_90_YAW_90", (90, 0, 90)),
    ("ROLL_90_YAW_135", (90, 0, 135)),
    ("ROLL_270", (270, 0, 0)),
    ("ROLL_270_YAW_45", (270, 0, 45)),
    ("ROLL_270_YAW_90", (270, 0, 90)),
    ("ROLL_270_YAW_135", (270, 0, 135)),
    ("PITCH_90", (0, 90, 0)),
    ("PITCH_270", (0, 270, 0)),
    ("PITCH_180_YAW_90", (0, 180, 90)),
    ("PITCH_180_YAW_270", (0, 180, 270)),
    ("ROLL_90_PITCH_90", (90, 90, 0)),
    ("ROLL_180_PITCH_90", (180, 90, 0)),
    ("ROLL_270_PITCH_90", (270, 90, 0)),
    ("ROLL_90_PITCH_180", (90, 180, 0)),
    ("ROLL_270_PITCH_180", (270, 180, 0)),
    ("ROLL_90_PITCH_270", (90, 270, 0)),
    ("ROLL_180_PITCH_270", (180, 270, 0)),
    ("ROLL_270_PITCH_270", (270, 270, 0)),
    ("ROLL_90_PITCH_180_YAW_90", (90, 180, 90)),
    ("ROLL_90_YAW_270", (90, 0, 270)),
]
# 38 (ROLL_90_PITCH_68_YAW_293) is left out: ArduPilot applies a matrix of its own for it;
# 39 and 40 are shared again, the numbers from 41 on are each firmware's own.
_SHARED_LATER = [("PITCH_315", 39, (0, 315, 0)), ("ROLL_90_PITCH_315", 40, (90, 315, 0))]
_LATER = {
    "px4": [
        *_SHARED_LATER,
        ("ROLL_270_YAW_180", 41, (270, 0, 180)),
        ("ROLL_270_YAW_270", 42, (270, 0, 270)),
        ("PITCH_90_YAW_180", 43, (0, 90, 180)),
        ("PITCH_9_YAW_180", 44, (0, 9, 180)),
        ("PITCH_45", 45, (0, 45, 0)),
        ("ROLL_270_YAW_225", 46, (270, 0, 225)),
        ("ROLL_270_YAW_315", 47, (270, 0, 315)),
    ],
    "ardupilot": [
        *_SHARED_LATER,
        ("PITCH_7", 41, (0, 7, 0)),
        ("ROLL_45", 42, (45, 0, 0)),
        ("ROLL_315", 43, (315, 0, 0)),
    ],
}
PARAMETER = {"px4": "SENS_BOARD_ROT", "ardupilot": "AHRS_ORIENTATION"}


@dataclass(frozen=True)
class Rotation:
    """One rotation of a firmware's enumeration: its name, number and matrix (3, 3), which
    turns a vector in the calibrated axes into the firmware's axes."""

    name: str
    number: int
    matrix: np.ndarray

    @property
    def right_angled(self) -> bool:
        """True when it only permutes and flips axes (every angle a multiple of 90 deg)."""
        return bool(np.all(np.isclose(np.abs(self.matrix), np.round(np.abs(self.matrix)))))


def rotation_names(firmware: str) -> dict[str, tuple[int, tuple[int, int, int]]]:
    """{name: (number, (roll, pitch, yaw) deg)} of the rotations `firmware` knows."""
    out = {name: (n, rpy) for n, (name, rpy) in enumerate(_SHARED)}
    out |= {name: (n, rpy) for name, n, rpy in _LATER[firmware]}
    return out


def rotation(name: str | None, firmware: str) -> Rotation:
    """The rotation called `name` (``YAW_90``, ``ROTATION_YAW_90`` or its number) in
    `firmware`'s enumeration; None is ``NONE``. Raises ValueError listing the names."""
    known = rotation_names(firmware)
    key = "NONE" if name is None else str(name).strip().upper().removeprefix("ROTATION_")
    by_number = {str(n): k for k, (n, _) in known.items()}
    key = by_number.get(key, key)
    if key not in known:
        raise ValueError(
            f"--rotation {name!r}: not a rotation of {firmware} ({PARAMETER[firmware]}); "
            f"expected one of {', '.join(known)} (or its number)"
        )
    number, (roll, pitch, yaw) = known[key]
    return Rotation(key, number, _euler_matrix(roll, pitch, yaw))


def _euler_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), degrees: the direction cosines of PX4's
    ``Dcmf{Eulerf{roll, pitch, yaw}}``; exact zeros and ones at right angles."""
    r, p, y = (math.radians(a) for a in (roll, pitch, yaw))

    def rounded(m: np.ndarray) -> np.ndarray:
        near = np.round(m)
        return np.where(np.isclose(m, near, atol=1e-12), near, m)

    cx, sx, cy, sy, cz, sz = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rounded(rz @ ry @ rx)


def rotated_scales(rot: Rotation, scales: np.ndarray, firmware: str) -> np.ndarray:
    """(3,) per-axis scales in the firmware's axes: axis i takes the scale of the calibrated
    axis that turns into it. Raises ValueError for a rotation that mixes axes."""
    if not rot.right_angled:
        raise ValueError(
            f"--rotation {rot.name}: not a multiple of 90 deg; {firmware}'s per-axis "
            "accelerometer scales cannot carry a scale factor turned between two axes"
        )
    return np.abs(rot.matrix) @ np.asarray(scales, dtype=float)


# --- device ids ---------------------------------------------------------------------------


def recorded_devices(ingest: dict[str, Any]) -> dict[str, int]:
    """The device ids the run's logs recorded ({"accel": id, "gyro": id} from a ULog,
    {"imu": instance} from a DataFlash log), from the ingest step's statistics `ingest`;
    {} when none did.

    Raises ValueError when the segments name different sensors (one export, one sensor).
    """
    found: dict[str, int] = {}
    for label, devices in (ingest.get("devices") or {}).items():
        for kind, value in devices.items():
            if found.setdefault(kind, int(value)) != int(value):
                raise ValueError(
                    f"the run's segments were recorded by different sensors ({kind} "
                    f"{found[kind]} and {value} in segment {label}); one file sets one sensor"
                )
    return found


def px4_device_ids(
    recorded: dict[str, int], accel_id: int | None, gyro_id: int | None
) -> tuple[int, int, str]:
    """(accel id, gyro id, where they came from): the options first, else the log's.

    Raises ValueError naming ``--device-id`` when neither gives an id: PX4 applies the
    values only to the sensor whose id matches, so 0 would silently correct nothing."""
    accel = accel_id if accel_id is not None else recorded.get("accel")
    gyro = gyro_id if gyro_id is not None else recorded.get("gyro")
    if accel is None or gyro is None:
        missing = [k for k, v in (("accelerometer", accel), ("gyro", gyro)) if v is None]
        raise ValueError(
            f"no PX4 device id of the {' and '.join(missing)}: the run's data do not record "
            "it (a ULog's sensor_accel / sensor_gyro device_id does); give --device-id "
            "(or --accel-id / --gyro-id), the value of the vehicle's CAL_ACC0_ID / "
            "CAL_GYRO0_ID (QGroundControl: Parameters)"
        )
    if 0 in (accel, gyro):
        raise ValueError(
            "device id 0 matches no PX4 sensor: give the vehicle's CAL_ACC0_ID / CAL_GYRO0_ID"
        )
    said = "from the run's log" if (accel_id, gyro_id) == (None, None) else "given"
    return int(accel), int(gyro), said


# --- the header ---------------------------------------------------------------------------


def header_lines(
    firmware: str,
    *,
    unit: str,
    run: str,
    model_range: tuple[float, float] | None,
    rot: Rotation,
    settings: list[str],
) -> list[str]:
    """The file's first comment lines: what it is for, what to set and that a reboot is
    needed before the firmware uses it."""
    loader = (
        "QGroundControl: Vehicle Setup > Parameters > Tools > Load from file"
        if firmware == "px4"
        else "Mission Planner: Config > Full Parameter List > Load from file (or MAVProxy "
        "`param load FILE`)"
    )
    span = (
        "no thermal model"
        if model_range is None
        else f"thermal model valid {model_range[0]:g} .. {model_range[1]:g} deg C "
        "(outside it the firmware holds the curve at the nearer end)"
    )
    return [
        f"unit {unit}, run {run}; {span}",
        f"axes: calibrated axes rotated by {rot.name} (number {rot.number} of "
        f"{PARAMETER[firmware]}'s enumeration) into the firmware's"
        + ("" if rot.number == 0 else "; WARNING lines give values in the calibrated axes"),
        *settings,
        f"load with {loader}; then REBOOT the vehicle: the firmware reads these at start-up",
    ]
