"""The sensor-array procedure: several IMUs on one cube, each with a static and ccw/cw
turns -> each sensor's accelerometer and gyro parameters (docs/methods.md 2.7).

The solver is calib_core.solvers.sensor_array. Settings: `SENSOR_ARRAY.settings`.
"""

from __future__ import annotations

from calib_core.procedures.base import ATTITUDES, ENVIRONMENT, Procedure
from calib_core.solvers.sensor_array import SETTINGS, solve_sensor_array

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
