"""The equipment-free procedure: one hand-held session of rests between rotations -> the
accelerometer model from |f| = g at every rest, gyro parameters from the rotations between
them (docs/methods.md 2.3; Tedaldi et al., imu_tk).

The solver is calib_core.solvers.equipment_free. Settings: `EQUIPMENT_FREE.settings`.
"""

from __future__ import annotations

from calib_core.procedures.base import ATTITUDES, ENVIRONMENT, Procedure
from calib_core.solvers.equipment_free import SETTINGS, solve_equipment_free

EQUIPMENT_FREE = Procedure(
    name="equipment_free",
    summary="a hand-held session of rests and rotations, no known attitudes: accelerometer "
    "from |f| = g at every rest, gyro from the rotations between rests",
    segments="one continuous segment (any label; or settings.segment), cut into rests by the "
    "solver's own static detector",
    solver=solve_equipment_free,
    settings=SETTINGS,
    conditions=ENVIRONMENT + ATTITUDES,
    reference="docs/methods.md 2.3; Tedaldi et al. 2014 (imu_tk)",
    model_checks="number of rests (threshold search when too few); accelerometer condition "
    "number; residual scale; transport residual of the rotations",
)
