"""The centrifuge procedure: zero, 1 g and high-g steps per mount -> the accelerometer's
high-order model, reduced by t / F tests (docs/centrifuge.md).

The solver is calib_core.solvers.centrifuge_segments. Settings: `CENTRIFUGE.settings`.
"""

from __future__ import annotations

from calib_core.condition_rules import ConditionUse
from calib_core.procedures.base import ENVIRONMENT, RATE_PLATEAUS, Procedure
from calib_core.solvers.centrifuge_segments import SETTINGS, solve_centrifuge_segments

CENTRIFUGE = Procedure(
    name="centrifuge",
    summary="zero, 1 g and high-g steps per mount: the accelerometer's high-order model, "
    "reduced by t / F tests",
    segments="<axis><p|m>_zero_<table deg>, <axis><p|m>_zero_after_<table deg>, "
    "<axis><p|m>_1g, <axis><p|m>_step_<n>g (p: the axis points to the table axis), each "
    "with reference channels table_angle (rad) and table_rate (rad/s)",
    solver=solve_centrifuge_segments,
    settings=SETTINGS,
    # Its solver drops no settle from a step: no settle rule; each step's record is whole.
    conditions=ENVIRONMENT
    + tuple(c for c in RATE_PLATEAUS if c.key != "settle_rate_s")
    + (
        ConditionUse(
            "zero_position_min",
            "length of the shortest zero-output record (before or after the run)",
            "centrifuge paper (docs/methods.md 2.8)",
        ),
        ConditionUse(
            "g_step_min",
            "length of the shortest high-g step record",
            "centrifuge paper (docs/methods.md 2.8)",
        ),
    ),  # fmt: skip
    reference="docs/centrifuge.md",
    model_checks="t / F tests of each term; zero shift before / after each run; radius "
    "consistency across positions",
)
