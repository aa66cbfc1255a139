"""The six-position + integral procedure (the MPU-6000 program): the six statics plus n-turn
ccw/cw rotations about each axis -> adds gyro scale and misalignment by the integral method.

Segments: the six statics and x_ccw, x_cw, y_ccw, y_cw, z_ccw, z_cw (ccw = positive sense
about the upward axis). Settings: `SIX_POSITION_INTEGRAL.settings` (docs/procedures.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from calib_core.calibration import Calibration
from calib_core.procedures.base import ATTITUDES, ENVIRONMENT, Procedure, Settings
from calib_core.procedures.six_position import (
    ACCEL_MODEL,
    ACCEL_SOLVER,
    GYRO_RANGE_DPS,
    ROTATION_DIRECTIONS,
    TURNS,
    _acc_model,
    _require,
    _solve_statics,
)
from calib_core.recording import Recording
from calib_core.solvers.integral import ROTATION_LABELS, solve_integral
from calib_core.solvers.multi_position import segment_residual
from calib_core.solvers.six_position import STATIC_LABELS, axis_vector
from calib_core.uncertainty_sources import static_model
from calib_core.units import DEG

SETTINGS = Settings(TURNS, GYRO_RANGE_DPS, ACCEL_SOLVER, ACCEL_MODEL, ROTATION_DIRECTIONS)


def solve_six_position_integral(
    segments: dict[str, Recording], gravity: float, settings: dict[str, Any] | None = None
) -> Calibration:
    """Six static positions plus the integral method for gyro scale and misalignment.

    Parameters
    ----------
    segments : label -> Recording; the six statics and x_ccw, x_cw, y_ccw,
        y_cw, z_ccw, z_cw.
    gravity : local gravity, m/s^2.
    settings : `SIX_POSITION_INTEGRAL.settings`.
    """
    merged = SETTINGS.merged(settings)
    both = merged["rotation_directions"] == "both"
    _require(segments, STATIC_LABELS + (ROTATION_LABELS if both else ()), "six_position_integral")
    cal, gyr = _solve_statics(segments, gravity, merged, "six_position_integral")
    rotations = {label: segments[label] for label in ROTATION_LABELS if label in segments}
    integral = solve_integral(
        rotations,
        {label: s.mean for label, s in gyr.items()},
        {label: s.sem for label, s in gyr.items()},
        merged["gyro_range_dps"] * DEG,
        merged["turns"],
        # The static record of the same orientation gives the noise the integral collects.
        noise_std={label: s.std for label, s in gyr.items()},
        gravity=gravity,
        directions=merged["rotation_directions"],
    )
    cal = cal.merged(integral)
    # merged() takes the integral's info on top; keep this procedure's name.
    cal.procedure = "six_position_integral"
    # The accelerometer sees g along the rotation axis throughout a rotation.
    for label in rotations:
        rec = segments[label]
        f = axis_vector(label, gravity)  # constant over the rotation: a (3,) model
        cal.residuals.append(segment_residual(label, "acc", rec.acc, _acc_model(cal, f)))
        cal.info["sample_counts"][label] = len(rec)
    return cal


def missing_labels(labels: set[str], settings: Mapping[str, Any]) -> list[str]:
    """The statics and rotations the run lacks; with rotation_directions "any" one turn
    per axis suffices."""
    missing = [label for label in STATIC_LABELS if label not in labels]
    for axis in "xyz":
        turns = [f"{axis}_ccw", f"{axis}_cw"]
        if settings.get("rotation_directions") == "any":  # one sense per axis suffices
            if not labels.intersection(turns):
                missing.append(f"{axis}_ccw or {axis}_cw")
        else:
            missing += [label for label in turns if label not in labels]
    return missing


SIX_POSITION_INTEGRAL = Procedure(
    name="six_position_integral",
    summary="six statics plus n-turn ccw/cw rotations about each axis: the six-position "
    "parameters and gyro scale and misalignment by the integral method",
    segments="six statics x_up .. z_dn and the rotations x_ccw, x_cw, y_ccw, y_cw, z_ccw, z_cw "
    "(ccw = positive sense about the upward axis; the MPU-6000 folder's file names), listed "
    "by hand or cut by [run.settings.segmentation] (labels = \"faces\")",
    solver=solve_six_position_integral,
    settings=SETTINGS,
    conditions=ENVIRONMENT + ATTITUDES,
    reference="methods.md 2.1 and 6; MPU-6000 manual (stages 1 and 2)",
    labels=STATIC_LABELS + ROTATION_LABELS,
    required=STATIC_LABELS + ROTATION_LABELS,
    uncertainty=static_model,
    model_checks="the six-position checks; per rotation: saturation at gyro_range_dps, whole "
    "turns (inferred or given), the static reading from the same orientation",
    missing_rule=missing_labels,
)
