"""Firmware exports of a calibration and its thermal model (docs/exports.md).

- canonical JSON: the unit, the calibration document and the thermal model
  document, as archived (SI units, canonical names).
- PX4 thermal compensation (`TC_A*` / `TC_G*`), as a QGroundControl parameter
  file: offset(T) = X0 + X1 dT + X2 dT^2 + X3 dT^3, dT = clip(T, TMIN, TMAX) - TREF,
  and the firmware subtracts offset from the raw sensor value (m/s^2, rad/s).
- ArduPilot (`INS_TCAL<n>_*`), as a parameter file `NAME,VALUE`: a polynomial
  without constant term around the fixed 35 deg C, coefficients times 1e6; the
  firmware subtracts poly(T - 35) and adds back poly(T_cal - 35), T_cal being the
  temperature of its own offset calibration (so only the *change* with
  temperature is carried).

Only the bias curves map onto these formats; scale-factor, misalignment and
g-sensitivity curves have no place there and stay in the canonical JSON. The
exported numbers come from the model's coefficients by exact polynomial
re-expansion, no refit.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from calib_core import params
from calib_core.calibration import Calibration
from calib_core.thermal import ThermalModel, shift_polynomial

EXPORT_FORMAT = "imu-calib-export"
EXPORT_VERSION = 1
PX4_ORDER = 3
ARDUPILOT_TREF = 35.0  # deg C, TEMP_REFERENCE of AP_InertialSensor_tempcal.cpp
ARDUPILOT_SCALE = 1.0e6  # SCALE_FACTOR of AP_InertialSensor_tempcal.cpp
# MAVLink MAV_PARAM_TYPE codes used in QGroundControl parameter files.
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9
_PX4_SENSOR = {"acc": "A", "gyr": "G"}


def bias_polynomials(
    model: ThermalModel, calibration: Calibration | None, sensor: str, order: int
) -> np.ndarray:
    """(3, order + 1) bias polynomial per axis around model.t_ref, SI.

    Axes without a curve get a constant: the calibration's bias (0 without one).
    Raises ValueError if a curve's order exceeds `order`.
    """
    out = np.zeros((3, order + 1))
    for i, a in enumerate(params.AXES):
        name = params.bias(sensor, a)
        curve = model.curves.get(name)
        if curve is None:
            out[i, 0] = calibration.value(name) if calibration is not None else 0.0
            continue
        if curve.order > order:
            raise ValueError(
                f"{name}: thermal curve of order {curve.order} does not fit this format "
                f"(at most order {order}); refit with max_order={order}"
            )
        out[i, : curve.order + 1] = curve.coef
    return out


# --- canonical JSON ---------------------------------------------------------


def canonical_json(
    model: ThermalModel, calibration: dict[str, Any] | None, unit: dict[str, Any]
) -> dict[str, Any]:
    """The export document: unit, calibration (archive export) and thermal model, SI."""
    return {
        "format": EXPORT_FORMAT,
        "format_version": EXPORT_VERSION,
        "unit": unit,
        "calibration": calibration,
        "thermal_model": model.to_dict(),
    }


def write_json(path: Path, doc: dict[str, Any]) -> Path:
    Path(path).write_text(json.dumps(doc, indent=2, sort_keys=True, default=str) + "\n")
    return Path(path)


# --- PX4 --------------------------------------------------------------------


def px4_parameters(
    model: ThermalModel,
    calibration: Calibration | None = None,
    *,
    instance: int = 0,
    accel_id: int = 0,
    gyro_id: int = 0,
    legacy_scale: bool = False,
) -> list[tuple[str, float | int, int]]:
    """PX4 TC_A<i>_* and TC_G<i>_* parameters: (name, value, MAV_PARAM_TYPE).

    X<k>_<axis> = k-th coefficient of the bias curve in (T - TREF), axis 0/1/2 =
    x/y/z, m/s^2 / deg C^k and rad/s / deg C^k; TREF = model.t_ref, TMIN/TMAX = the
    fitted range. `accel_id` / `gyro_id` are the firmware's device ids (TC_*_ID).
    `legacy_scale` adds TC_A<i>_SCL_<axis> = 1 / (1 + scale at TREF) for firmware
    that still multiplies (raw - offset) by SCL (PX4 before v1.11).
    """
    rows: list[tuple[str, float | int, int]] = []
    for sensor, dev_id in (("acc", accel_id), ("gyr", gyro_id)):
        p = f"TC_{_PX4_SENSOR[sensor]}"
        rows.append((f"{p}_ENABLE", 1, MAV_PARAM_TYPE_INT32))
        rows.append((f"{p}{instance}_ID", int(dev_id), MAV_PARAM_TYPE_INT32))
        poly = bias_polynomials(model, calibration, sensor, PX4_ORDER)
        for k in range(PX4_ORDER, -1, -1):
            for axis in range(3):
                rows.append(
                    (f"{p}{instance}_X{k}_{axis}", float(poly[axis, k]), MAV_PARAM_TYPE_REAL32)
                )
        if legacy_scale and sensor == "acc":
            for axis, a in enumerate(params.AXES):
                name = f"acc.scale.{a}"
                s = (
                    float(model.value(name, model.t_ref))
                    if name in model.curves
                    else (calibration.value(name) if calibration is not None else 0.0)
                )
                rows.append((f"{p}{instance}_SCL_{axis}", 1.0 / (1.0 + s), MAV_PARAM_TYPE_REAL32))
        rows.append((f"{p}{instance}_TREF", float(model.t_ref), MAV_PARAM_TYPE_REAL32))
        rows.append((f"{p}{instance}_TMIN", float(model.t_min), MAV_PARAM_TYPE_REAL32))
        rows.append((f"{p}{instance}_TMAX", float(model.t_max), MAV_PARAM_TYPE_REAL32))
    return rows


def write_px4_params(
    path: Path, rows: list[tuple[str, float | int, int]], *, header: str = ""
) -> Path:
    """QGroundControl parameter file: tab-separated vehicle id, component id, name, value, type."""
    lines = ["# Onboard parameters for Vehicle 1", f"# {header}".rstrip(), "#",
             "# Vehicle-Id Component-Id Name Value Type"]  # fmt: skip
    for name, value, kind in rows:
        text = str(int(value)) if kind == MAV_PARAM_TYPE_INT32 else f"{value:.9g}"
        lines.append(f"1\t1\t{name}\t{text}\t{kind}")
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")
    return Path(path)


def read_px4_params(path: Path) -> dict[str, float]:
    """Name -> value of a QGroundControl parameter file (comments skipped)."""
    out: dict[str, float] = {}
    for n, line in enumerate(Path(path).read_text(encoding="ascii").splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        fields = line.split("\t")
        if len(fields) != 5:
            raise ValueError(f"{path}:{n}: expected 5 tab-separated fields, got {len(fields)}")
        out[fields[2]] = float(fields[3])
    return out


# --- ArduPilot ----------------------------------------------------------------


def ardupilot_parameters(
    model: ThermalModel, calibration: Calibration | None = None, *, imu: int = 1
) -> list[tuple[str, float]]:
    """ArduPilot INS_TCAL<imu>_* parameters: (name, value).

    ACC<k>_<X|Y|Z> / GYR<k>_<X|Y|Z> = 1e6 x the k-th coefficient (k = 1..3) of
    the bias curve re-expanded in (T - 35 deg C), m/s^2 and rad/s per deg C^k.
    The constant term has no parameter: ArduPilot takes offsets from its own
    accelerometer / gyro calibration at INS_ACC<n>_CALTEMP / INS_GYR<n>_CALTEMP.
    """
    rows: list[tuple[str, float]] = [
        (f"INS_TCAL{imu}_ENABLE", 1),
        (f"INS_TCAL{imu}_TMIN", float(model.t_min)),
        (f"INS_TCAL{imu}_TMAX", float(model.t_max)),
    ]
    polys = {
        s: np.array(
            [
                shift_polynomial(c, model.t_ref, ARDUPILOT_TREF)
                for c in bias_polynomials(model, calibration, s, 3)
            ]  # fmt: skip
        )
        for s in ("acc", "gyr")
    }
    for k in (1, 2, 3):
        for s, tag in (("acc", "ACC"), ("gyr", "GYR")):
            for axis, a in enumerate("XYZ"):
                rows.append(
                    (f"INS_TCAL{imu}_{tag}{k}_{a}", float(polys[s][axis, k] * ARDUPILOT_SCALE))
                )
    return rows


def write_ardupilot_params(path: Path, rows: list[tuple[str, float]], *, header: str = "") -> Path:
    """ArduPilot parameter file (Mission Planner / MAVProxy): one `NAME,VALUE` per line."""
    lines = [f"# {header}".rstrip()] if header else []
    lines += [f"{name},{value:.9g}" for name, value in rows]
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")
    return Path(path)


def read_ardupilot_params(path: Path) -> dict[str, float]:
    """Name -> value of an ArduPilot parameter file (`NAME,VALUE` or `NAME VALUE`)."""
    out: dict[str, float] = {}
    for n, line in enumerate(Path(path).read_text(encoding="ascii").splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != 2:
            raise ValueError(f"{path}:{n}: expected NAME,VALUE, got {line!r}")
        out[fields[0]] = float(fields[1])
    return out
