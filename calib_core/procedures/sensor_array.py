"""The sensor-array procedure: several IMUs on one cube, each with a static and ccw/cw
turns -> each sensor's accelerometer and gyro parameters (docs/methods.md 2.7).

The solver is calib_core.solvers.sensor_array. Settings: `SENSOR_ARRAY.settings`.
"""

from __future__ import annotations

from calib_core.procedures.base import ATTITUDES, ENVIRONMENT, Procedure, Setting, Settings
from calib_core.procedures.six_position import TURNS
from calib_core.solvers.sensor_array import solve_sensor_array

SETTINGS = Settings(
    Setting("mounts", ("text", "table"), "1", "cube6",
            "\"cube6\" (the patent's six-IMU cube) or {sensor = 3x3 cube-to-sensor rotation}",
            choices=("cube6",)),
    TURNS,
)  # fmt: skip

SENSOR_ARRAY = Procedure(
    name="sensor_array",
    summary="several IMUs on one cube: each sensor's accelerometer and gyro parameters from "
    "one static and a ccw and cw turn per sensor",
    segments="<sensor>_static, <sensor>_ccw, <sensor>_cw per sensor, listed by hand or cut by "
    '[run.settings.segmentation] with labels = "array"',
    solver=solve_sensor_array,
    settings=SETTINGS,
    conditions=ENVIRONMENT + ATTITUDES,
    reference="docs/methods.md 2.7",
    model_checks="whole turns per sensor (inferred or given); residuals per sensor",
    static_segments="all but turns",
)
