"""The integral procedure (stage 2 of the MPU-6000 program alone): the six rotations ->
gyro scale and misalignment, each axis's static reading from its own ccw and cw records.

Its solver is in `six_position` (shared code); settings: `INTEGRAL.settings`.
"""

from __future__ import annotations

from calib_core.procedures.base import ENVIRONMENT, Procedure
from calib_core.procedures.six_position import INTEGRAL_ONLY_SETTINGS, solve_integral_procedure
from calib_core.solvers.integral import ROTATION_LABELS
from calib_core.solvers.six_position import STATIC_LABELS

INTEGRAL = Procedure(
    name="integral",
    summary="the six rotations alone: gyro scale and misalignment by the integral method",
    segments="x_ccw, x_cw, y_ccw, y_cw, z_ccw, z_cw (n whole turns each, axis vertical)",
    solver=solve_integral_procedure,
    settings=INTEGRAL_ONLY_SETTINGS,
    conditions=ENVIRONMENT,
    reference="docs/methods.md 2.6; MPU-6000 manual stage 2",
    labels=STATIC_LABELS + ROTATION_LABELS,
    required=ROTATION_LABELS,
    model_checks="per rotation: saturation at gyro_range_dps, whole turns (inferred or given)",
)
