"""The multi-position procedure: statics at known table attitudes -> the accelerometer model
of the chosen order, gyro bias and g-sensitivity, noise (docs/methods.md 2.2).

The solver is calib_core.solvers.multi_position. Settings: `MULTI_POSITION.settings`.
"""

from __future__ import annotations

from calib_core.attitude import ATTITUDE_CONVENTIONS, TABLE_AXES
from calib_core.procedures.base import (
    ATTITUDES,
    ENVIRONMENT,
    EQUIPMENT_PRECHECK,
    TABLE_POSITION,
    Procedure,
    Setting,
    Settings,
)
from calib_core.solvers.accel_models import ACCEL_MODELS
from calib_core.solvers.multi_position import solve_multi_position

SETTINGS = Settings(
    Setting("model", "text", "", "full",
            "accelerometer model: full (12), reduced (bias and scale per axis), quadratic, "
            "nonlinear", choices=ACCEL_MODELS),
    Setting("table_axes", "text", "", "pitch_roll",
            "the table's two axes the attitudes are given in", choices=TABLE_AXES),
    Setting("attitude_convention", "text", "", "project",
            "sign of the table's pitch: project a_x = -g sin(pitch), rate_table_procedure "
            "a_x = +g sin(pitch)", choices=ATTITUDE_CONVENTIONS),
    Setting("attitudes", "table", "deg", {},
            "per label the table angles {pitch_deg, roll_deg} (or azimuth_deg, pitch_deg); "
            "absent: reference channels or a face label"),
    Setting("mount", "list", "1", None,
            "3x3 body-to-table rotation (rows of numbers; absent: identity)"),
    Setting("gyro_gsens", "bool", "", True,
            "fit gyro bias and g-sensitivity from the same statics"),
)  # fmt: skip

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
