"""Exports of a calibration and its thermal model (docs/exports.md).

- a calibration's offsets and scales for PX4 (`CAL_ACC*` / `CAL_GYRO*`) and
  ArduPilot (`INS_ACCOFFS` / `INS_ACCSCAL` / `INS_GYROFFS`), with what the
  firmware cannot carry listed (`px4_calibration_parameters`,
  `ardupilot_calibration_parameters`); every parameter as CSV or MATLAB
  variables (`parameter_rows`, `mat_variables`). `calib export RUN` uses these
  (pipelines/run_export.py).

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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from calib_core import params
from calib_core.calibration import Calibration
from calib_core.thermal import ThermalModel, shift_polynomial
from calib_core.units import STANDARD_GRAVITY
from pipelines.autopilot import Rotation, rotated_scales
from pipelines.reports.display import quantity, shown

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
    rot: Rotation | None = None,
) -> list[tuple[str, float | int, int]]:
    """PX4 TC_A<i>_* and TC_G<i>_* parameters: (name, value, MAV_PARAM_TYPE).

    X<k>_<axis> = k-th coefficient of the bias curve in (T - TREF), axis 0/1/2 =
    x/y/z, m/s^2 / deg C^k and rad/s / deg C^k; TREF = model.t_ref, TMIN/TMAX = the
    fitted range. `accel_id` / `gyro_id` are the firmware's device ids (TC_*_ID).
    `legacy_scale` adds TC_A<i>_SCL_<axis> = 1 / (1 + scale at TREF) for firmware
    that still multiplies (raw - offset) by SCL (PX4 before v1.11). `rot`: the firmware's
    rotation of the calibrated axes (`pipelines.autopilot`); the curves are written rotated.
    """
    rows: list[tuple[str, float | int, int]] = []
    for sensor, dev_id in (("acc", accel_id), ("gyr", gyro_id)):
        p = f"TC_{_PX4_SENSOR[sensor]}"
        rows.append((f"{p}_ENABLE", 1, MAV_PARAM_TYPE_INT32))
        rows.append((f"{p}{instance}_ID", int(dev_id), MAV_PARAM_TYPE_INT32))
        poly = _turned(rot, bias_polynomials(model, calibration, sensor, PX4_ORDER))
        for k in range(PX4_ORDER, -1, -1):
            for axis in range(3):
                rows.append(
                    (f"{p}{instance}_X{k}_{axis}", float(poly[axis, k]), MAV_PARAM_TYPE_REAL32)
                )
        if legacy_scale and sensor == "acc":
            scale = [
                float(model.value(n, model.t_ref))
                if n in model.curves
                else (calibration.value(n) if calibration else 0.0)
                for n in (f"acc.scale.{a}" for a in params.AXES)
            ]
            scl = 1.0 / (1.0 + np.array(scale))
            scl = scl if rot is None else rotated_scales(rot, scl, "PX4")
            for axis in range(3):
                rows.append((f"{p}{instance}_SCL_{axis}", float(scl[axis]), MAV_PARAM_TYPE_REAL32))
        rows.append((f"{p}{instance}_TREF", float(model.t_ref), MAV_PARAM_TYPE_REAL32))
        rows.append((f"{p}{instance}_TMIN", float(model.t_min), MAV_PARAM_TYPE_REAL32))
        rows.append((f"{p}{instance}_TMAX", float(model.t_max), MAV_PARAM_TYPE_REAL32))
    return rows


def _turned(rot: Rotation | None, vectors: np.ndarray) -> np.ndarray:
    """(3,) or (3, k) per-axis values in the firmware's axes (`rot` None: as calibrated)."""
    return vectors if rot is None else rot.matrix @ vectors


def _comment(header: str) -> list[str]:
    """`# `-prefixed comment lines of a (multi-line) header; none for an empty header."""
    return [f"# {line}".rstrip() for line in header.splitlines()]


def px4_params_text(
    rows: list[tuple[str, float | int, int]], *, header: str = "", vehicle_id: int = 1
) -> str:
    """QGroundControl parameter file: tab-separated vehicle id, component id, name, value, type.

    QGroundControl loads a file only onto the vehicle (MAV_SYS_ID) its rows name."""
    if not 1 <= vehicle_id <= 255:
        raise ValueError(f"--vehicle-id {vehicle_id}: expected a MAVLink system id 1 .. 255")
    lines = [
        f"# Onboard parameters for Vehicle {vehicle_id}",
        *(_comment(header) or ["#"]),
        "#",
        "# Vehicle-Id Component-Id Name Value Type",
    ]
    for name, value, kind in rows:
        text = str(int(value)) if kind == MAV_PARAM_TYPE_INT32 else f"{value:.9g}"
        lines.append(f"{vehicle_id}\t1\t{name}\t{text}\t{kind}")
    return "\n".join(lines) + "\n"


def write_px4_params(
    path: Path, rows: list[tuple[str, float | int, int]], *, header: str = "", vehicle_id: int = 1
) -> Path:
    """`px4_params_text` written to `path` (ASCII)."""
    return _write_ascii(path, px4_params_text(rows, header=header, vehicle_id=vehicle_id))


def read_px4_params(path: Path) -> dict[str, float]:
    """Name -> value of a QGroundControl parameter file (comments skipped)."""
    out: dict[str, float] = {}
    for n, line in _param_lines(path):
        fields = line.split("\t")
        if len(fields) != 5:
            raise ValueError(f"{path}:{n}: expected 5 tab-separated fields, got {len(fields)}")
        out[fields[2]] = float(fields[3])
    return out


# --- ArduPilot ----------------------------------------------------------------


def ardupilot_parameters(
    model: ThermalModel,
    calibration: Calibration | None = None,
    *,
    imu: int = 1,
    rot: Rotation | None = None,
) -> list[tuple[str, float]]:
    """ArduPilot INS_TCAL<imu>_* parameters: (name, value).

    ACC<k>_<X|Y|Z> / GYR<k>_<X|Y|Z> = 1e6 x the k-th coefficient (k = 1..3) of
    the bias curve re-expanded in (T - 35 deg C), m/s^2 and rad/s per deg C^k.
    The constant term has no parameter: ArduPilot takes offsets from its own
    accelerometer / gyro calibration at INS_ACC<n>_CALTEMP / INS_GYR<n>_CALTEMP.
    `rot`: the firmware's rotation of the calibrated axes; the curves are written rotated.
    """
    rows: list[tuple[str, float]] = [
        (f"INS_TCAL{imu}_ENABLE", 1),
        (f"INS_TCAL{imu}_TMIN", float(model.t_min)),
        (f"INS_TCAL{imu}_TMAX", float(model.t_max)),
    ]
    polys = {
        s: _turned(
            rot,
            np.array(
                [
                    shift_polynomial(c, model.t_ref, ARDUPILOT_TREF)
                    for c in bias_polynomials(model, calibration, s, 3)
                ]
            ),
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


def ardupilot_params_text(rows: list[tuple[str, float]], *, header: str = "") -> str:
    """ArduPilot parameter file (Mission Planner / MAVProxy): one `NAME,VALUE` per line."""
    lines = _comment(header) + [f"{name},{value:.9g}" for name, value in rows]
    return "\n".join(lines) + "\n"


def write_ardupilot_params(path: Path, rows: list[tuple[str, float]], *, header: str = "") -> Path:
    """`ardupilot_params_text` written to `path` (ASCII)."""
    return _write_ascii(path, ardupilot_params_text(rows, header=header))


def read_ardupilot_params(path: Path) -> dict[str, float]:
    """Name -> value of an ArduPilot parameter file (`NAME,VALUE` or `NAME VALUE`)."""
    out: dict[str, float] = {}
    for n, line in _param_lines(path):
        fields = line.replace(",", " ").split()
        if len(fields) != 2:
            raise ValueError(f"{path}:{n}: expected NAME,VALUE, got {line!r}")
        out[fields[0]] = float(fields[1])
    return out


def _write_ascii(path: Path, text: str) -> Path:
    Path(path).write_text(text, encoding="ascii")
    return Path(path)


def _param_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(1-based line number, line) of a parameter file, blank and ``#`` comment lines skipped."""
    for n, line in enumerate(Path(path).read_text(encoding="ascii").splitlines(), 1):
        if line.strip() and not line.startswith("#"):
            yield n, line


# --- a calibration's offsets and scales (CAL_* / INS_*OFFS) --------------------

# Firmware limits of the mapped values (their parameter metadata): outside them the
# firmware refuses or resets the value, so the export is refused.
PX4_SCALE_RANGE = (0.0, 1.5)  # CAL_ACC*_xSCALE: > 0 (Accelerometer::set_scale), @max 1.5
ARDUPILOT_SCALE_RANGE = (0.8, 1.2)  # INS_ACCSCAL_*: @Range 0.8 1.2
ARDUPILOT_OFFSET_MAX = 3.5  # INS_ACCOFFS_*: @Range -3.5 3.5 m/s/s
ARDUPILOT_PREFIX = {
    1: ("INS_ACC", "INS_GYR"),
    2: ("INS_ACC2", "INS_GYR2"),
    3: ("INS_ACC3", "INS_GYR3"),
}


def unrepresented(
    cal: Calibration, mapped: set[str], model: ThermalModel | None, firmware: str
) -> list[str]:
    """One line per parameter family that `firmware`'s file cannot carry, with its values.

    Noise densities are listed too: they describe the unit, they are not corrections.
    """
    notes = []
    families: dict[str, list[str]] = {}
    for name in sorted(set(cal.parameters) - mapped):
        families.setdefault(name.rsplit(".", 1)[0], []).append(name)
    for family, names in families.items():
        # the values as people read them (pipelines.reports.display): a comment, no number
        # a firmware loads
        values = ", ".join(f"{n.rsplit('.', 1)[1]} {shown(n, cal.value(n)).value}" for n in names)
        why = "not a correction" if family.endswith(".noise") else f"no {firmware} parameter"
        notes.append(
            f"not exported ({why}): {family} [{shown(names[0], 0.0).unit}]: {values}"
            + _left_over(family, max(abs(cal.value(n)) for n in names))
        )
    if model is not None:
        curves = sorted(n for n in model.curves if ".bias." not in n)
        if curves:
            notes.append(
                f"not exported (no {firmware} parameter): thermal curves of {', '.join(curves)}; "
                "the calibration's values are used at every temperature"
            )
    return notes


def _left_over(family: str, largest: float) -> str:
    """What the largest term of a family leaves uncorrected, in words, or ''."""
    kind = family.split(".")[1]
    if kind in ("scale", "misalign"):  # dimensionless: a share of the input
        return f" (up to {100 * largest:.2g} % of the input left uncorrected)"
    if kind == "gsens":  # (rad/s)/(m/s^2): a rate error under 1 g
        rate = quantity("gyr.bias.x", largest * STANDARD_GRAVITY, 2)
        return f" (up to {rate} {shown('gyr.bias.x', 0.0).unit} left uncorrected at 1 g)"
    return ""


def _scales(
    cal: Calibration, lo_hi: tuple[float, float], firmware: str, rot: Rotation | None = None
) -> np.ndarray:
    """(3,) accelerometer scales 1 / (1 + s): (raw - offset) * scale undoes raw = (1 + s) f;
    in the firmware's axes when `rot` is given."""
    k = 1.0 / (1.0 + cal.vector("acc", "scale"))
    for a, v in zip(params.AXES, k, strict=True):
        if not lo_hi[0] < v <= lo_hi[1]:
            raise ValueError(
                f"acc.scale.{a} = {shown(f'acc.scale.{a}', cal.value(f'acc.scale.{a}')).value} "
                f"gives a {firmware} scale of "
                f"{v:.6g}, outside the firmware's range {lo_hi[0]:g} .. {lo_hi[1]:g}"
            )
    return k if rot is None else rotated_scales(rot, k, firmware)


def px4_calibration_parameters(
    cal: Calibration,
    *,
    instance: int = 0,
    accel_id: int = 0,
    gyro_id: int = 0,
    model: ThermalModel | None = None,
    cal_temp: float | None = None,
    rot: Rotation | None = None,
) -> tuple[list[tuple[str, float | int, int]], list[str]]:
    """PX4 CAL_ACC<i>_* / CAL_GYRO<i>_* (+ TC_* with a thermal model): (rows, notes).

    PX4 (src/lib/sensor_calibration/Accelerometer.hpp, Gyroscope.hpp) corrects
    ``acc = (raw - thermal_offset - CAL_ACC_OFF) * CAL_ACC_SCALE`` and
    ``gyr = raw - thermal_offset - CAL_GYRO_OFF``, in the sensor frame, so
    xOFF = bias (m/s^2, rad/s) and xSCALE = 1 / (1 + acc.scale). With a thermal
    model the bias curves go to TC_A/TC_G (`px4_parameters`), anchored at the
    calibration's bias at `cal_temp` when it is known, and the CAL offsets are 0
    (the bias would be removed twice). Without a model TC_A_ENABLE and
    TC_G_ENABLE are 0: the offsets are the whole bias at the run's temperature,
    and thermal offsets the vehicle already has would remove it twice. `notes`
    lists what PX4 cannot carry (misalignment, gyro scale, g-sensitivity, ...) and the
    thermal compensation switched off. `rot`: the firmware's rotation of the calibrated axes
    (`pipelines.autopilot`): offsets, scales and curves are written in the rotated axes.
    """
    rows: list[tuple[str, float | int, int]] = []
    notes = []
    if model is not None:
        m = model if cal_temp is None else model.anchored(cal, cal_temp)
        rows += px4_parameters(
            m, cal, instance=instance, accel_id=accel_id, gyro_id=gyro_id, rot=rot
        )
    else:
        rows += [("TC_A_ENABLE", 0, MAV_PARAM_TYPE_INT32), ("TC_G_ENABLE", 0, MAV_PARAM_TYPE_INT32)]
        notes.append(
            "no thermal model: TC_A_ENABLE and TC_G_ENABLE set to 0 (the offsets are the whole "
            "bias at the run's temperature; the vehicle's thermal offsets would remove it twice)"
        )
    mapped = {params.bias(s, a) for s in ("acc", "gyr") for a in params.AXES}
    mapped |= {f"acc.scale.{a}" for a in params.AXES}
    scale = _scales(cal, PX4_SCALE_RANGE, "PX4", rot)
    for sensor, tag, dev in (("acc", "ACC", accel_id), ("gyr", "GYRO", gyro_id)):
        p = f"CAL_{tag}{instance}"
        rows.append((f"{p}_ID", int(dev), MAV_PARAM_TYPE_INT32))
        # with a model the bias is in TC_*: 0 here, else it would be removed twice
        offsets = np.zeros(3) if model is not None else _turned(rot, cal.vector(sensor, "bias"))
        for i, a in enumerate(params.AXES):
            rows.append((f"{p}_{a.upper()}OFF", float(offsets[i]), MAV_PARAM_TYPE_REAL32))
            if sensor == "acc":
                rows.append((f"{p}_{a.upper()}SCALE", float(scale[i]), MAV_PARAM_TYPE_REAL32))
    notes = unrepresented(cal, mapped, model, "PX4") + notes
    if model is not None and cal_temp is None:
        notes.append("calibration temperature unknown: thermal offsets from the model's curves")
    return rows, notes


def ardupilot_calibration_parameters(
    cal: Calibration,
    *,
    imu: int = 1,
    model: ThermalModel | None = None,
    cal_temp: float | None = None,
    rot: Rotation | None = None,
) -> tuple[list[tuple[str, float]], list[str]]:
    """ArduPilot INS_ACCOFFS / INS_ACCSCAL / INS_GYROFFS of IMU `imu` (+ INS_TCAL): (rows, notes).

    ArduPilot (AP_InertialSensor_Backend::_rotate_and_correct_accel / _gyro)
    corrects ``acc = (raw - INS_ACCOFFS) * INS_ACCSCAL`` and ``gyr = raw -
    INS_GYROFFS`` in the sensor frame, after its temperature correction
    ``v -= poly(T - 35) - poly(CALTEMP - 35)``. So OFFS = bias (m/s^2, rad/s) at
    CALTEMP, SCAL = 1 / (1 + acc.scale). With a thermal model, CALTEMP =
    `cal_temp` (the model's t_ref when unknown: the offsets then come from the
    model's curves) and INS_TCAL<imu>_* from `ardupilot_parameters`; without a
    model CALTEMP = `cal_temp` when known (as ArduPilot's own accelerometer
    calibration stores it), so a vehicle's own INS_TCAL stays consistent. IMUs 2
    and 3 use INS_ACC2OFFS, INS_GYR2OFFS, ... `rot`: the firmware's rotation of the
    calibrated axes (`pipelines.autopilot`): offsets, scales and curves written rotated.
    """
    if imu not in ARDUPILOT_PREFIX:
        raise ValueError(f"ArduPilot IMU {imu}: expected 1, 2 or 3")
    acc_p, gyr_p = ARDUPILOT_PREFIX[imu]
    names = {
        "acc": (f"{acc_p}OFFS" if imu > 1 else "INS_ACCOFFS"),
        "gyr": (f"{gyr_p}OFFS" if imu > 1 else "INS_GYROFFS"),
    }
    t0 = cal_temp if model is None or cal_temp is not None else model.t_ref
    m = None if model is None else (model if cal_temp is None else model.anchored(cal, cal_temp))
    rows: list[tuple[str, float]] = []
    for sensor in ("acc", "gyr"):
        at_t0 = []
        for a in params.AXES:
            name = params.bias(sensor, a)
            curve = m is not None and name in m.curves
            value = float(m.value(name, t0)) if curve else cal.value(name)
            if sensor == "acc" and abs(value) > ARDUPILOT_OFFSET_MAX:
                raise ValueError(
                    f"{name} = {shown(name, value).value} m/s^2 at the calibration "
                    "temperature: outside ArduPilot's INS_ACCOFFS range "
                    f"+-{ARDUPILOT_OFFSET_MAX:g} m/s^2"
                )
            at_t0.append(value)
        turned = _turned(rot, np.array(at_t0))
        rows += [(f"{names[sensor]}_{a.upper()}", float(turned[i])) for i, a in enumerate("xyz")]
    scale = _scales(cal, ARDUPILOT_SCALE_RANGE, "ArduPilot", rot)
    scal = f"{acc_p}SCAL" if imu > 1 else "INS_ACCSCAL"
    rows += [(f"{scal}_{a.upper()}", float(k)) for a, k in zip(params.AXES, scale, strict=True)]
    if t0 is not None:  # as ArduPilot's own calibration stores it with the offsets
        rows += [(f"INS_ACC{imu}_CALTEMP", float(t0)), (f"INS_GYR{imu}_CALTEMP", float(t0))]
    if model is not None:
        rows += ardupilot_parameters(model, cal, imu=imu, rot=rot)
    mapped = {params.bias(s, a) for s in ("acc", "gyr") for a in params.AXES}
    mapped |= {f"acc.scale.{a}" for a in params.AXES}
    notes = unrepresented(cal, mapped, model, "ArduPilot")
    if t0 is None:
        notes.append(
            f"run temperature unknown: INS_ACC{imu}_CALTEMP / INS_GYR{imu}_CALTEMP not written "
            "(with INS_TCAL enabled the vehicle would refer these offsets to its old CALTEMP)"
        )
    if model is not None and cal_temp is None:
        notes.append(
            f"calibration temperature unknown: offsets from the model's curves at T_ref "
            f"{model.t_ref:g} deg C (CALTEMP)"
        )
    return rows, notes


# --- every parameter: CSV and MATLAB -----------------------------------------

CSV_COLUMNS = ("name", "value", "std", "unit")


def parameter_rows(
    cal: Calibration, model: ThermalModel | None = None
) -> list[tuple[str, float, float | None, str]]:
    """(name, value, std, unit) of every parameter, then the thermal model's terms.

    Thermal rows: ``thermal:t_ref`` / ``t_min`` / ``t_max`` (degC) and
    ``thermal:<parameter>:c<k>``, the coefficient of (T - t_ref)^k with its
    standard uncertainty, unit ``<unit>/degC^k``.
    """
    rows = [(n, p.value, p.std, p.unit) for n, p in sorted(cal.parameters.items())]
    if model is None:
        return rows
    rows += [
        (f"thermal:{k}", float(getattr(model, k)), None, "degC")
        for k in ("t_ref", "t_min", "t_max")
    ]
    for name, curve in sorted(model.curves.items()):
        unit = params.unit_of(name)
        for k, c in enumerate(curve.coef):
            per = "" if k == 0 else ("/degC" if k == 1 else f"/degC^{k}")
            std = float(np.sqrt(curve.cov[k, k]))
            rows.append((f"thermal:{name}:c{k}", float(c), std, f"{unit}{per}"))
    return rows


def csv_text(rows: list[tuple[str, float, float | None, str]]) -> str:
    """CSV with the header name,value,std,unit; an empty std where there is none."""
    import csv
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for name, value, std, unit in rows:
        w.writerow((name, repr(float(value)), "" if std is None else repr(float(std)), unit))
    return buf.getvalue()


def mat_variables(
    cal: Calibration, meta: dict[str, Any], model: ThermalModel | None = None
) -> dict[str, Any]:
    """The MATLAB variables of docs/exports.md (`--format mat`), ready for scipy.io.savemat."""
    names = sorted(cal.parameters)
    ps = [cal.parameters[n] for n in names]

    def column(values: list[Any], dtype: Any = float) -> np.ndarray:  # noqa: ANN401
        return np.array(values, dtype=dtype).reshape(-1, 1)

    out: dict[str, Any] = {
        **{k: ("" if v is None else v) for k, v in meta.items()},
        "procedure": cal.procedure,
        "gravity": float(cal.gravity),
        "parameter_names": column(names, object),
        "parameter_values": column([p.value for p in ps]),
        "parameter_std": column([np.nan if p.std is None else p.std for p in ps]),
        "parameter_units": column([p.unit for p in ps], object),
        "parameter_cov_index": column([0 if p.cov_index is None else p.cov_index + 1 for p in ps]),
        "covariance": cal.covariance,
        "acc_bias": cal.vector("acc", "bias").reshape(3, 1),
        "acc_M": cal.matrix("acc"),
        "gyr_bias": cal.vector("gyr", "bias").reshape(3, 1),
        "gyr_M": cal.matrix("gyr"),
        "gyr_G": cal.gsens(),
    }
    if model is not None:
        curves = sorted(model.curves)
        coef = np.zeros((len(curves), max((model.curves[n].order for n in curves), default=0) + 1))
        for i, n in enumerate(curves):
            coef[i, : model.curves[n].order + 1] = model.curves[n].coef
        out |= {
            "thermal_t_ref": float(model.t_ref),
            "thermal_t_min": float(model.t_min),
            "thermal_t_max": float(model.t_max),
            "thermal_names": np.array(curves, dtype=object).reshape(-1, 1),
            "thermal_coef": coef,
        }
    return out


def mat_bytes(variables: dict[str, Any]) -> bytes:
    """A MATLAB v5 .mat file (scipy.io.savemat) of `variables`."""
    import io

    from scipy.io import savemat

    buf = io.BytesIO()
    savemat(buf, variables, format="5", oned_as="column", do_compression=True)
    return buf.getvalue()
