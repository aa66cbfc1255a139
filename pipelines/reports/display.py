"""Lab display units for reports: SI inside, deg/s, (deg/s)/g, ppm where labs expect them."""

from __future__ import annotations

from calib_core.params import UNITS
from calib_core.units import DEG, STANDARD_GRAVITY

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


def display(name: str, value: float | None) -> tuple[float | None, str]:
    """(value in display unit, display unit) of a canonical parameter value given in SI."""
    unit, factor = DISPLAY_UNITS[name.rsplit(".", 1)[0]]
    return (None if value is None else value * factor), unit


def tolerance(name: str, check: dict | None) -> tuple[str, float] | None:
    """(relation, limit in display unit) of a parameter check, or None without a limit.

    relation is "+-" for a symmetric bound and "<=" for an upper-only one (noise):
    check_parameters writes its bounds into the detail as "allowed LOW .. HIGH unit"
    or "allowed at most HIGH unit".
    """
    if check is None or check.get("limit") is None:
        return None
    # "allowed -inf .." is how archives before 2026-11-25 wrote an upper bound only.
    upper_only = check.get("detail", "").startswith(("allowed at most", "allowed -inf"))
    relation = "<=" if upper_only else "+-"
    return relation, display(name, check["limit"])[0]
