"""Centrifuge procedure, before and around the run: table rates for the g levels, zero drift.

Planning (docs/methods.md 2.8: steps 2 g .. 20 g, 5 min each). The input along the
radial axis is the procedure's

    a = R w (w + 2 Omega_V)

(R the equivalent radius from a near-1 g run, w the table rate signed about
up, Omega_V Earth rate's up component), so the rate for a = n g is the root
of w^2 + 2 Omega_V w - n g / R = 0 with the sign of the rotation sense:

    w = -Omega_V + sense * sqrt(Omega_V^2 + n g / R).

Omega_V changes w by 7e-5 rad/s at most (1e-5 of the rate at 2 g on a 1 m arm),
below any table's setting resolution, but it costs nothing to be exact.

Zero drift. The zero output of each mounting position is recorded at the four
table positions before the run and again after it (`<m>_zero_<deg>`,
`<m>_zero_after_<deg>`); the shift after - before is compared with a limit per
axis. The procedure uses the zero from before; a zero that moved during the
run moves every step's error and the radius.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib_core.params import AXES
from calib_core.solvers.centrifuge_model import DEFAULT_ZERO_SHIFT_LIMIT, vertical_earth_rate
from calib_core.units import STANDARD_GRAVITY

# docs/methods.md 2.8: 2 g .. 20 g; the paper's steps are every 2 g.
DEFAULT_G_LEVELS = tuple(float(n) for n in range(2, 21, 2))


@dataclass(frozen=True)
class PlannedStep:
    """One planned step: the table rate that gives `n_g` times g along the radial axis.

    rate : rad/s, signed about up (anticlockwise seen from above > 0).
    input : R w (w + 2 Omega_V) at that rate, m/s^2 (= n_g * gravity).
    """

    n_g: float
    rate: float
    input: float

    @property
    def rpm(self) -> float:
        return abs(self.rate) * 60.0 / (2.0 * math.pi)

    @property
    def deg_s(self) -> float:
        return math.degrees(self.rate)


def table_rate(n_g: float, radius: float, gravity: float, omega_v: float, sense: int) -> float:
    """Signed table rate (rad/s) for an input of n_g * gravity at `radius` (m); see module."""
    return -omega_v + sense * math.sqrt(omega_v**2 + n_g * gravity / radius)


def plan_rates(
    radius: float,
    g_levels: Sequence[float] = DEFAULT_G_LEVELS,
    *,
    gravity: float = STANDARD_GRAVITY,
    latitude_deg: float = 0.0,
    sense: int = 1,
    max_rate: float | None = None,
) -> list[PlannedStep]:
    """Table rates for the requested g levels.

    Parameters
    ----------
    radius : equivalent radius, m (> 0), e.g. from the near-1 g run.
    g_levels : inputs in units of `gravity` (> 0), e.g. 2 .. 20.
    gravity : local gravity, m/s^2.
    latitude_deg : site latitude (Earth rate's up component).
    sense : +1 anticlockwise seen from above, -1 clockwise.
    max_rate : the table's highest rate, rad/s; a level above it is refused.

    Returns
    -------
    one PlannedStep per level, in the order given.
    """
    if not (math.isfinite(radius) and radius > 0.0):
        raise ValueError(f"radius must be a positive number of metres, got {radius}")
    if sense not in (1, -1):
        raise ValueError(f"sense must be +1 (anticlockwise) or -1 (clockwise), got {sense}")
    bad = [n for n in g_levels if not (math.isfinite(n) and n > 0.0)]
    if bad or not g_levels:
        raise ValueError(f"g levels must be positive numbers, got {list(g_levels)}")
    omega_v = vertical_earth_rate(latitude_deg)
    points = []
    for n_g in g_levels:
        w = table_rate(n_g, radius, gravity, omega_v, sense)
        if max_rate is not None and abs(w) > max_rate:
            raise ValueError(
                f"{n_g:g} g at R = {radius:g} m needs {abs(w):.4g} rad/s "
                f"({abs(w) * 30 / math.pi:.1f} rpm), above the table's {max_rate:.4g} rad/s"
            )
        points.append(PlannedStep(float(n_g), w, radius * w * (w + 2.0 * omega_v)))
    return points


@dataclass(frozen=True)
class ZeroShift:
    """Zero output after the run minus before, one mounting position.

    shift, std : (3,) per sensor axis, m/s^2 (std from the two means' standard errors).
    limit : allowed |shift|, m/s^2.
    """

    mount: str
    shift: np.ndarray
    std: np.ndarray
    limit: float

    @property
    def passed(self) -> np.ndarray:
        """(3,) bool, |shift| <= limit per axis."""
        return np.abs(self.shift) <= self.limit

    def describe(self, axis: str) -> str:
        i = AXES.index(axis)
        verdict = "pass" if self.passed[i] else "FAIL"
        return (
            f"{self.mount} {axis}: zero after - before = {self.shift[i]:+.5f} "
            f"+- {self.std[i]:.2g} m/s^2, limit {self.limit:.4g}: {verdict}"
        )


def zero_shift(
    mount: str,
    before: tuple[np.ndarray, np.ndarray],
    after: tuple[np.ndarray, np.ndarray],
    limit: float = DEFAULT_ZERO_SHIFT_LIMIT,
) -> ZeroShift:
    """Compare the zero output recorded before and after a mounting position's run.

    before, after : (mean (3,), standard error (3,)) as `zero_output` gives them, m/s^2.
    """
    if not (math.isfinite(limit) and limit > 0.0):
        raise ValueError(f"zero_shift_limit must be a positive number (m/s^2), got {limit}")
    (b, ub), (a, ua) = before, after
    return ZeroShift(mount, np.asarray(a - b, dtype=float), np.hypot(ua, ub), float(limit))
