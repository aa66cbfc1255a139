"""The equipment-free procedure: one hand-held session of rests between rotations -> the
accelerometer model from |f| = g at every rest, gyro parameters from the rotations between
them (docs/methods.md 2.3; Tedaldi et al., imu_tk).

The solver is calib_core.solvers.equipment_free. Settings: `EQUIPMENT_FREE.settings`.
"""

from __future__ import annotations

from calib_core.procedures.base import ATTITUDES, ENVIRONMENT, Procedure, Setting, Settings
from calib_core.solvers.equipment_free import solve_equipment_free

SETTINGS = Settings(
    Setting("window_s", "number", "s", 1.0, "static detector's variance window", low=0.0,
            low_open=True),
    Setting("init_static_s", "number", "s", 10.0,
            "initial rest the threshold is scaled from", low=0.0, low_open=True),
    Setting("k", "number", "1", 6.0,
            "static threshold as a multiple of the initial rest's variance", low=0.0,
            low_open=True),
    Setting("min_duration_s", "number", "s", 1.0, "shortest rest kept", low=0.0,
            low_open=True),
    Setting("settle_s", "number", "s", 0.5, "time dropped at each end of a rest", low=0.0),
    Setting("min_keep_s", "number", "s", 0.5, "shortest part of a rest left after the settle",
            low=0.0),
    Setting("min_intervals", "integer", "1", 9,
            "fewest rests for the fit (fewer: the threshold is searched)", low=1),
    Setting("segment", "text", "", None,
            "the segment that holds the session (absent: the run's only segment)"),
)  # fmt: skip

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
