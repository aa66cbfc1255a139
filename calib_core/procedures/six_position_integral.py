"""The six-position + integral procedure (the MPU-6000 program): the six statics plus n-turn
ccw/cw rotations about each axis -> adds gyro scale and misalignment by the integral method.

Segments: the six statics and x_ccw, x_cw, y_ccw, y_cw, z_ccw, z_cw (ccw = positive sense
about the upward axis). Its solver shares the statics' code in `six_position`; settings:
`SIX_POSITION_INTEGRAL.settings` (docs/procedures.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from calib_core.procedures.six_position import (
    INTEGRAL_SETTINGS,
    SIX_POSITION,
    solve_six_position_integral,
)
from calib_core.solvers.integral import ROTATION_LABELS
from calib_core.solvers.six_position import STATIC_LABELS


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


# The six-position procedure (conditions, labels, Type B model, stillness) with its
# rotations required and solved.
SIX_POSITION_INTEGRAL = replace(
    SIX_POSITION,
    name="six_position_integral",
    summary="six statics plus n-turn ccw/cw rotations about each axis: the six-position "
    "parameters and gyro scale and misalignment by the integral method",
    segments="six statics x_up .. z_dn and the rotations x_ccw, x_cw, y_ccw, y_cw, z_ccw, z_cw "
    "(ccw = positive sense about the upward axis; the MPU-6000 folder's file names), listed "
    'by hand or cut by [run.settings.segmentation] (labels = "faces")',
    solver=solve_six_position_integral,
    settings=INTEGRAL_SETTINGS,
    reference="docs/methods.md 2.1 and 2.6; MPU-6000 manual (stages 1 and 2)",
    required=STATIC_LABELS + ROTATION_LABELS,
    model_checks="the six-position checks; per rotation: saturation at gyro_range_dps, whole "
    "turns (inferred or given), the static reading from the same orientation",
    missing_rule=missing_labels,
)
