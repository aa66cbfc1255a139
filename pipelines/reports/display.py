"""How a number is shown to people, in one place: per parameter family the display unit
(SI inside; deg/s, (deg/s)/g where labs expect them), the digits (the uncertainty to two
significant digits, the value to the same place), the uncertainty's wording ("u" for the
standard uncertainty, "U (k=2)" for an expanded one) and how checks are counted.

The CLI, the web pages, the protocol, the certificate and the exports' human parts
use it; JSON documents and Python values stay SI with their units named."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from calib_core.params import UNITS
from calib_core.units import DEG, STANDARD_GRAVITY

if TYPE_CHECKING:  # numpy: not for the views that only format
    from calib_core.calibration import CheckResult
    from storage.queries.records import Revision

# Parameter family -> (display unit, factor that turns SI into the display unit), where
# labs read another unit than SI; every other family of calib_core.params.UNITS shows
# in its SI unit (`display_unit`), so a family added there cannot be forgotten here.
LAB_UNITS: dict[str, tuple[str, float]] = {
    "acc.bias": ("m/s^2", 1.0),
    "acc.noise": ("m/s^2", 1.0),
    "acc.scale": ("1", 1.0),
    "acc.misalign": ("1", 1.0),
    "acc.k2": ("1/(m/s^2)", 1.0),
    "acc.k3": ("1/(m/s^2)^2", 1.0),
    "gyr.bias": ("deg/s", 1.0 / DEG),
    "gyr.noise": ("deg/s", 1.0 / DEG),
    "gyr.scale": ("1", 1.0),
    "gyr.misalign": ("1", 1.0),
    "gyr.gsens": ("(deg/s)/g", STANDARD_GRAVITY / DEG),
}
DISPLAY_UNITS: dict[str, tuple[str, float]] = {
    family: LAB_UNITS.get(family, (si, 1.0)) for family, si in UNITS.items()
}
# Residuals and verification errors of a sensor (measured - model): (unit, factor from SI).
MG = 1e-3 * STANDARD_GRAVITY  # m/s^2 per mg
RESIDUAL_UNITS: dict[str, tuple[str, float]] = {
    "acc": ("mg", 1.0 / MG),
    "gyr": ("deg/s", 1.0 / DEG),
}


def display(name: str, value: float | None) -> tuple[float | None, str]:
    """(value in display unit, display unit) of a canonical parameter value given in SI."""
    unit, factor = DISPLAY_UNITS[name.rsplit(".", 1)[0]]
    return (None if value is None else value * factor), unit


def tolerance(name: str, check: CheckResult | None) -> tuple[str, float] | None:
    """(relation, limit in display unit) of a parameter check, or None without a limit.

    relation is "+-" for a symmetric bound and "<=" for an upper-only one (noise):
    check_parameters writes its bounds into the detail as "allowed LOW .. HIGH unit"
    or "allowed at most HIGH unit".
    """
    if check is None or check.limit is None:
        return None
    # "allowed -inf .." is how archives before 2026-11-25 wrote an upper bound only.
    upper_only = (check.detail or "").startswith(("allowed at most", "allowed -inf"))
    relation = "<=" if upper_only else "+-"
    return relation, display(name, check.limit)[0]


# --- one presentation of a number --------------------------------------------------------

STANDARD_U = "u"  # the standard uncertainty (k = 1), as every table heads it
STANDARD_U_MEANING = "u: standard uncertainty (k = 1)"
# a value archived without a standard uncertainty (a noise term: the value is itself a spread)
NO_STANDARD_U = "not evaluated"
U_DIGITS = 2  # significant digits of an uncertainty (GUM 7.2.6); the value to the same place
VALUE_DIGITS = 6  # significant digits of a value without an uncertainty
LIMIT_DIGITS = 4  # significant digits of a tolerance limit
ERROR_DIGITS = 3  # significant digits of a difference judged against a tolerance (as found)


def expanded_u(k: float) -> str:
    """The heading of an expanded uncertainty: "U (k=2)"."""
    return f"U (k={k:.3g})"


@dataclass(frozen=True)
class Shown:
    """A parameter as people read it: value and uncertainty in the display unit, as text."""

    value: str
    u: str  # "" without an uncertainty
    unit: str

    @property
    def signed(self) -> str:
        """The value with its sign, "+" too (the protocol's columns, as the MPU-6000
        manual prints them); "-" without a value."""
        return self.value if self.value.startswith(("-", "+")) else "+" + self.value


def number(value: float | None) -> str:
    """A quantity that is no parameter (a condition, a check statistic) to VALUE_DIGITS
    significant digits; None and NaN as "-"."""
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value:.{VALUE_DIGITS}g}"


def quantity(
    name: str, value: float | None, digits: int = VALUE_DIGITS, signed: bool = False
) -> str:
    """`name`'s SI `value` in its display unit to `digits` significant digits, where no
    uncertainty sets the place (as found, an error, an expanded U: `U_DIGITS`); "-"
    without a value."""
    v, _ = display(name, value)
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:{'+' if signed else ''}.{digits}g}"


def uncertainty(name: str, u: float | None) -> str:
    """An uncertainty of `name` alone (SI in), as `shown` writes one: two significant
    digits, fixed point, display unit; "-" without one."""
    return shown(name, 0.0, u).u or "-"


def with_unit(text: str, unit: str) -> str:
    """A number's text followed by its display unit ("0.0040 deg/s"); a ratio's ("1")
    and a missing value ("-") stand alone."""
    return text if unit == "1" or text == "-" else f"{text} {unit}"


def limit_text(limit: float) -> str:
    """A tolerance limit (already in its display unit) to LIMIT_DIGITS significant digits."""
    return f"{limit:.{LIMIT_DIGITS}g}"


def tolerance_text(name: str, check: CheckResult | None, plus_minus: str = "+-") -> str:
    """A parameter check's limit as people read it: "+- 0.05", "<= 0.02" (display unit);
    "" without a limit. `plus_minus` is "±" where the medium has it (HTML)."""
    tol = tolerance(name, check)
    if tol is None:
        return ""
    relation = plus_minus if tol[0] == "+-" else tol[0]
    return f"{relation} {limit_text(tol[1])}"


def _decimals(u: float) -> int:
    """Decimal places that give `u` U_DIGITS significant digits (negative: tens, ...)."""
    return U_DIGITS - 1 - math.floor(math.log10(abs(u)))


def shown(name: str, value: float | None, std: float | None = None) -> Shown:
    """`name`'s SI `value` and standard uncertainty `std` in its display unit: the
    uncertainty to two significant digits, the value to the same decimal place (6
    significant digits without an uncertainty). None and NaN show as "-"."""
    v, unit = display(name, value)
    u, _ = display(name, std)
    if v is None or not math.isfinite(v):
        return Shown("-", "", unit)
    if u is None or not math.isfinite(u) or u <= 0:
        return Shown(number(v), "", unit)
    places = _decimals(u)
    if places > 0:
        return Shown(f"{v:.{places}f}", f"{u:.{places}f}", unit)
    return Shown(f"{round(v, places):.0f}", f"{round(u, places):.0f}", unit)


@dataclass(frozen=True)
class CheckCounts:
    """A calibration's checks counted one way everywhere: the tolerance checks (parameters,
    residuals, verification, repeatability) and the lab conditions, apart."""

    tolerance: int
    tolerance_failed: int
    conditions: int
    conditions_failed: int
    warnings: int
    not_recorded: int

    @property
    def failed(self) -> int:
        """Failed checks that count against the verdict."""
        return self.tolerance_failed + self.conditions_failed

    def sentence(self) -> str:
        """e.g. "0 of 75 tolerance checks failed; 12 conditions: 0 failed, 2 warnings,
        3 not recorded"."""
        text = f"{self.tolerance_failed} of {self.tolerance} tolerance checks failed"
        if self.conditions:
            plural = "" if self.warnings == 1 else "s"
            text += (
                f"; {self.conditions} conditions: {self.conditions_failed} failed, "
                f"{self.warnings} warning{plural}, {self.not_recorded} not recorded"
            )
        return text


def check_counts(checks: Iterable[CheckResult]) -> CheckCounts:
    """Count a calibration's checks."""
    from calib_core.condition_rules import CONDITION_PREFIX, NOT_RECORDED, WARNING, status

    states = [(c.name.startswith(CONDITION_PREFIX), status(c)) for c in checks]
    conditions = [s for is_condition, s in states if is_condition]
    tolerance = [s for is_condition, s in states if not is_condition]
    return CheckCounts(
        len(tolerance),
        tolerance.count("fail"),
        len(conditions),
        conditions.count("fail"),
        conditions.count(WARNING),
        conditions.count(NOT_RECORDED),
    )


def record_notes(
    checks: Iterable[CheckResult], warnings: list[str] | tuple[str, ...] = ()
) -> list[tuple[str, str]]:
    """What every view shows beside the verdict about the record rather than the unit, as
    (name, text): each ``record:`` finding (a log read to its last whole record, a turn
    not quite at rest, a threshold raised, a held-out static record that moved), each
    ``model:replaced:`` count of samples a step altered (passed ones too: the count is
    shown whatever it is), then the solve's `warnings` ("solve warning")."""
    from calib_core.check_names import RECORD_PREFIX, REPLACED_PREFIX

    prefixes = (RECORD_PREFIX, REPLACED_PREFIX)
    notes = [(c.name, c.detail or "") for c in checks if c.name.startswith(prefixes)]
    return notes + [("solve warning", str(w)) for w in warnings]


def solve_warnings(cal: Revision) -> list[str]:
    """The warnings an archived revision's solve step holds."""
    return [str(w) for w in cal.step_statistics("solve").get("warnings", [])]
