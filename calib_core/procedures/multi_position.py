"""The multi-position procedure: statics at known table attitudes -> the accelerometer model
of the chosen order, gyro bias and g-sensitivity, noise (docs/methods.md 2.2).

The solver is calib_core.solvers.multi_position. Settings: `MULTI_POSITION.settings`.
"""

from __future__ import annotations

from calib_core.procedures.base import (
    ATTITUDES,
    ENVIRONMENT,
    EQUIPMENT_PRECHECK,
    TABLE_POSITION,
    Procedure,
)
from calib_core.solvers.multi_position import SETTINGS, solve_multi_position

MULTI_POSITION = Procedure(
    name="multi_position",
    summary="statics at known table attitudes: accelerometer model of the chosen order, gyro "
    "bias and g-sensitivity, noise",
    segments="one static segment per table position (>= 4; any label), its attitude from "
    "settings.attitudes, the reference channels or a face label (x_up ...); rotations "
    "(*_cw, *_ccw) are ignored",
    solver=solve_multi_position,
    settings=SETTINGS,
    conditions=ENVIRONMENT + ATTITUDES + (TABLE_POSITION, *EQUIPMENT_PRECHECK),
    reference="docs/methods.md 2.2",
    bounds_hint=(
        "check the table's attitude convention (settings.attitude_convention: 'project' "
        "a_x = -g sin(pitch), 'rate_table_procedure' a_x = +g sin(pitch)), settings.table_axes "
        "and settings.mount"
    ),
    model_checks="condition number and chi2 of the fit; parameters the attitudes cannot "
    "separate (not_separable); axes never seen in both senses; duplicate attitudes",
    static_segments="all but turns",
)
