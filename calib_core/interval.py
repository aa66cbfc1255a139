"""Recalibration intervals from measured drift, the science (variables-data method of NCSL
RP-1 and ILAC-G24: the interval is where the predicted parameter value stays inside its
tolerance with the target probability; docs/interval.md).

For one parameter of one unit the value drifts linearly, x(t) = a + b (t - t0). The units'
drift rates scatter about the fleet's mean m with a between-unit variance tau^2
(random-effects pooling of the units' own slopes, DerSimonian-Laird), which is the prior
of the unit's rate: b ~ N(m, tau^2 + u(m)^2). The unit's calibrations (values with their
standard uncertainties) update it: the line's posterior is the generalised least-squares
fit with that prior as one more observation of the slope (`predict_line`), so a unit with
one calibration takes the fleet's rate and a unit with a long history its own. The value
T days after the last calibration is then x_n + b T with the posterior (co)variances of
the line's value at t_n and of b (their correlation counted: the last calibration's noise
moves both), plus an optional random-walk term s^2 T, and

    R(T) = Phi((high - mu) / sd) - Phi((low - mu) / sd)

is the probability of being in tolerance at T. The interval is the largest T <= max_days
with R(T) >= the reliability target (0 when the unit is below it already).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib_core.distributions import norm_cdf

METHOD = "variables data (NCSL RP-1 / ILAC-G24), linear drift pooled with the model's fleet"


@dataclass(frozen=True)
class FleetDrift:
    """Drift rates of a model's units: mean m (SI / day), its variance, between-unit tau^2."""

    mean: float
    mean_var: float
    between_var: float
    units: int


def fleet_drift(slopes: Sequence[float], slope_vars: Sequence[float]) -> FleetDrift:
    """Random-effects pooling (DerSimonian-Laird) of per-unit drift rates.

    Parameters
    ----------
    slopes : (k,) each unit's trend slope, SI / day.
    slope_vars : (k,) their variances.

    Returns
    -------
    FleetDrift. Raises ValueError with fewer than 2 units or a variance <= 0.
    """
    b = np.asarray(slopes, dtype=float)
    v = np.asarray(slope_vars, dtype=float)
    if b.size < 2 or b.shape != v.shape:
        raise ValueError(f"fleet drift needs >= 2 units with a slope each, got {b.size}")
    if not np.all(np.isfinite(v)) or np.any(v <= 0):
        raise ValueError("every unit's slope needs a variance > 0")
    w = 1.0 / v
    mean_fixed = float(np.sum(w * b) / np.sum(w))
    q = float(np.sum(w * (b - mean_fixed) ** 2))
    tau2 = max(0.0, (q - (b.size - 1)) / (np.sum(w) - np.sum(w**2) / np.sum(w)))
    w_re = 1.0 / (v + tau2)
    return FleetDrift(
        float(np.sum(w_re * b) / np.sum(w_re)), float(1.0 / np.sum(w_re)), tau2, int(b.size)
    )


@dataclass(frozen=True)
class Prediction:
    """The line of one parameter of one unit, anchored at its last calibration.

    value : the line's value at t_last, SI; value_var its variance.
    rate : drift rate, SI / day; rate_var its variance; cov the covariance of value and rate.
    t_last : time of the last calibration, days.
    """

    value: float
    value_var: float
    rate: float
    rate_var: float
    cov: float
    t_last: float

    def mean(self, days: np.ndarray | float) -> np.ndarray:
        return self.value + self.rate * np.asarray(days, dtype=float)

    def var(self, days: np.ndarray | float) -> np.ndarray:
        t = np.asarray(days, dtype=float)
        return self.value_var + 2.0 * self.cov * t + self.rate_var * t**2


def predict_line(
    t_days: Sequence[float],
    values: Sequence[float],
    stds: Sequence[float],
    fleet: FleetDrift | None,
) -> Prediction:
    """The unit's line from its calibrations and its fleet's rates (module docstring).

    Raises ValueError when neither gives a rate (one calibration and no fleet) or a std
    is not > 0.
    """
    t = np.asarray(t_days, dtype=float)
    y = np.asarray(values, dtype=float)
    u = np.asarray(stds, dtype=float)
    if t.size == 0 or t.shape != y.shape or t.shape != u.shape:
        raise ValueError("t_days, values and stds must be non-empty and of equal length")
    if not np.all(u > 0):
        raise ValueError("every calibration needs a standard uncertainty > 0")
    t_last = float(t.max())
    X = np.column_stack([np.ones_like(t), t - t_last])  # intercept = value at t_last
    A = X.T @ (X / u[:, None] ** 2)
    r = X.T @ (y / u**2)
    if fleet is not None:
        prior_var = fleet.between_var + fleet.mean_var
        A[1, 1] += 1.0 / prior_var
        r[1] += fleet.mean / prior_var
    if np.linalg.cond(A) > 1e15:
        raise ValueError("no drift rate: one calibration date and no fleet of the model")
    C = np.linalg.inv(A)
    beta = C @ r
    return Prediction(
        float(beta[0]), float(C[0, 0]), float(beta[1]), float(C[1, 1]), float(C[0, 1]), t_last
    )


def in_tolerance_probability(
    line: Prediction,
    days: np.ndarray | float,
    low: float,
    high: float,
    walk_var_per_day: float = 0.0,
) -> np.ndarray:
    """R(T): probability that the value is in [low, high] `days` after the last calibration."""
    t = np.asarray(days, dtype=float)
    mu = line.mean(t)
    sd = np.sqrt(np.maximum(line.var(t) + walk_var_per_day * t, 1e-300))
    return norm_cdf((high - mu) / sd) - norm_cdf((low - mu) / sd)


@dataclass(frozen=True)
class RecalibrationInterval:
    """The recalibration interval of one parameter.

    days : the largest T (days) with R(T) >= reliability, capped at max_days.
    capped : True when R stays above the target up to max_days.
    probability : R at `days`.
    rate, rate_std : the drift rate used, SI / day.
    """

    days: float
    capped: bool
    probability: float
    rate: float
    rate_std: float
    reliability: float
    method: str = METHOD


def interval(
    line: Prediction,
    low: float,
    high: float,
    reliability: float,
    *,
    max_days: float = 1826.0,
    walk_var_per_day: float = 0.0,
) -> RecalibrationInterval:
    """The interval of one parameter (module docstring); a day grid, then bisection to
    0.01 day (R(T) falls monotonically once the predicted value heads out)."""
    if not 0.0 < reliability < 1.0:
        raise ValueError(f"reliability target must be between 0 and 1, got {reliability}")
    if not low < high:
        raise ValueError(f"tolerance must have low < high, got [{low}, {high}]")

    def r(t: float | np.ndarray) -> np.ndarray:
        return in_tolerance_probability(line, t, low, high, walk_var_per_day)

    rate = line.rate

    grid = np.arange(0.0, max_days + 1.0, 1.0)
    ok = r(grid) >= reliability
    rate_std = math.sqrt(max(line.rate_var, 0.0))
    if ok.all():
        return RecalibrationInterval(
            float(max_days), True, float(r(max_days)), rate, rate_std, reliability
        )
    first_bad = int(np.argmin(ok))
    if first_bad == 0:
        return RecalibrationInterval(0.0, False, float(r(0.0)), rate, rate_std, reliability)
    lo, hi = grid[first_bad - 1], grid[first_bad]
    while hi - lo > 0.01:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if r(mid) >= reliability else (lo, mid)
    return RecalibrationInterval(float(lo), False, float(r(lo)), rate, rate_std, reliability)
