"""The integral procedure (stage 2 of the MPU-6000 program alone): the six rotations ->
gyro scale and misalignment, each axis's static reading from its own ccw and cw records.

Settings: `INTEGRAL.settings` (docs/procedures.md).
"""

from __future__ import annotations

from typing import Any

from calib_core.calibration import Calibration
from calib_core.procedures.base import ENVIRONMENT, Procedure, Settings
from calib_core.procedures.six_position import GYRO_RANGE_DPS, TURNS, _require
from calib_core.recording import Recording
from calib_core.solvers.integral import ROTATION_LABELS, rotation_static_means, solve_integral
from calib_core.solvers.six_position import STATIC_LABELS
from calib_core.units import DEG

SETTINGS = Settings(TURNS, GYRO_RANGE_DPS)


def solve_integral_procedure(
    segments: dict[str, Recording], gravity: float, settings: dict[str, Any] | None = None
) -> Calibration:
    """Stage 2 of the MPU-6000 program alone: the six rotations, no orientations.

    Gyro scale and misalignment by the integral method, each axis's static reading taken
    from its own ccw and cw rotations (`rotation_static_means`); no biases, g-sensitivity,
    accelerometer or noise (those are stage 1, procedure six_position).

    settings : `INTEGRAL.settings`.
    """
    merged = SETTINGS.merged(settings)
    _require(segments, ROTATION_LABELS, "integral")
    rotations = {label: segments[label] for label in ROTATION_LABELS}
    means, sems = rotation_static_means(rotations)
    cal = solve_integral(
        rotations, means, sems, merged["gyro_range_dps"] * DEG, merged["turns"], gravity=gravity
    )
    cal.info["static_reading_from"] = "rotations (stage 2 alone)"
    cal.info["sample_counts"] = {label: len(rec) for label, rec in rotations.items()}
    return cal


INTEGRAL = Procedure(
    name="integral",
    summary="the six rotations alone: gyro scale and misalignment by the integral method",
    segments="x_ccw, x_cw, y_ccw, y_cw, z_ccw, z_cw (n whole turns each, axis vertical)",
    solver=solve_integral_procedure,
    settings=SETTINGS,
    conditions=ENVIRONMENT,
    reference="methods.md 6; MPU-6000 manual stage 2",
    labels=STATIC_LABELS + ROTATION_LABELS,
    required=ROTATION_LABELS,
    model_checks="per rotation: saturation at gyro_range_dps, whole turns (inferred or given)",
)
