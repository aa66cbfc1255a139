"""The centrifuge procedure: zero, 1 g and high-g steps per mount -> the accelerometer's
high-order model, reduced by t / F tests (docs/centrifuge.md).

The solver is calib_core.solvers.centrifuge_segments. Settings: `CENTRIFUGE.settings`.
"""

from __future__ import annotations

from calib_core.condition_rules import ConditionUse
from calib_core.procedures.base import ENVIRONMENT, RATE_PLATEAUS, Procedure, Setting, Settings
from calib_core.significance import STEERING, T_TESTS
from calib_core.solvers.centrifuge_model import DEFAULT_STEER, DEFAULT_ZERO_SHIFT_LIMIT
from calib_core.solvers.centrifuge_segments import solve_centrifuge_segments

SETTINGS = Settings(
    Setting("latitude_deg", "number", "deg", None,
            "site latitude (Earth rate); required, the pipeline takes [site] latitude_deg",
            low=-90.0, high=90.0),
    Setting("alpha", "number", "1", 0.05, "significance level of the t and F tests",
            low=0.0, high=1.0, low_open=True),
    Setting("t_test", "text", "", "two-sided", "t test of each term", choices=T_TESTS),
    Setting("steer", "text", "", DEFAULT_STEER,
            "how the stepwise reduction decides: the model F test then the t tests (the "
            "paper's), the t tests alone, or the largest model F", choices=STEERING),
    Setting("scale_1g", "table", "1", {},
            "per table axis x, y, z the 1 g scale error K - 1 of a static calibration"),
    Setting("common_radius", "bool", "", True, "one effective radius for all positions"),
    Setting("iterations", "integer", "1", 4, "radius / phi_h / model passes", low=1),
    Setting("scale_instability", ("number", "table"), "1", None,
            "relative scale instability from step to step, one value or per axis (absent: "
            "estimated)", low=0.0),
    Setting("zero_shift_limit", "number", "m/s^2", DEFAULT_ZERO_SHIFT_LIMIT,
            "allowed change of a position's zero output before / after its run", low=0.0,
            low_open=True),
)  # fmt: skip

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
