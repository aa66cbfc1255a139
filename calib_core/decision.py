"""Decision rules for statements of conformity (ILAC-G8:09/2019; ISO/IEC 17025:2017 7.8.6).

A tolerance profile names its rule: "simple" (simple acceptance, shared risk, w = 0),
"guard_band" (guarded acceptance, w = U) or "guard_band_r" (w = r * U). The acceptance limit is
the tolerance limit moved inwards by w. Four outcomes (ILAC-G8 non-binary):

- pass: inside the acceptance limits (limits included);
- conditional pass: inside the tolerance but within w of a limit;
- conditional fail: outside the tolerance but within w of a limit;
- fail: more than w outside the tolerance.

Under simple acceptance w = 0 and the verdict is pass or fail only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from calib_core.distributions import norm_sf

RULES = ("simple", "guard_band", "guard_band_r")
PASS, COND_PASS, COND_FAIL, FAIL = "pass", "conditional pass", "conditional fail", "fail"


@dataclass(frozen=True)
class DecisionRule:
    """A named ILAC-G8 decision rule: guard band w = r * U (r = 0 for simple acceptance)."""

    name: str = "simple"
    r: float = 1.0

    def __post_init__(self) -> None:
        if self.name not in RULES:
            raise ValueError(f"decision rule {self.name!r}: expected one of {RULES}")
        if self.name == "guard_band_r" and not (self.r > 0 and math.isfinite(self.r)):
            raise ValueError(f"decision rule guard_band_r: r must be > 0, got {self.r}")

    @property
    def factor(self) -> float:
        """r in w = r * U (0 for simple acceptance, 1 for w = U)."""
        return {"simple": 0.0, "guard_band": 1.0}.get(self.name, self.r)

    def guard_band(self, U: float) -> float:
        """w (same unit as U)."""
        return self.factor * U

    def statement(self, k: float = 2.0) -> str:
        """The rule and its risk, for the protocol and the certificate."""
        if self.name == "simple":
            return (
                "Decision rule: simple acceptance (ILAC-G8:2019 4.2.1, shared risk, w = 0); "
                "a value at a tolerance limit has up to 50 % probability of false accept."
            )
        pfa = 100.0 * norm_sf(self.factor * k)
        return (
            f"Decision rule: guarded acceptance (ILAC-G8:2019 4.2.2), guard band w = "
            f"{self.factor:g} U; probability of false accept at the acceptance limit "
            f"<= {pfa:.2g} % (normal, k = {k:g})."
        )


def decide(value: float, U: float, lower: float, upper: float, rule: DecisionRule) -> str:
    """One of pass / conditional pass / conditional fail / fail.

    Parameters
    ----------
    value : measured value; U : its expanded uncertainty (same unit, >= 0).
    lower, upper : tolerance limits (lower <= upper; -inf/inf for one-sided).
    rule : the profile's decision rule.
    """
    if not U >= 0:
        raise ValueError(f"expanded uncertainty must be >= 0, got {U}")
    if lower > upper:
        raise ValueError(f"tolerance lower limit {lower} above upper limit {upper}")
    w = rule.guard_band(U)
    inside = lower <= value <= upper
    if inside:
        return PASS if lower + w <= value <= upper - w else COND_PASS
    return COND_FAIL if lower - w <= value <= upper + w else FAIL
