"""Drift of calibration parameters over months, and fleet statistics per temperature.

Trend: a parameter of one unit against calibration date, fitted as a straight
line value = a + b (t - t0) by weighted least squares (weights 1 / std when
every point has a standard uncertainty; the scale of the weights estimated from
the residuals as in calib_core.significance.fit_ols). The forecast says when
the line leaves the tolerance band [low, high]: the central estimate where the
fitted line crosses, and the earliest date at which the one-sided upper
confidence bound of the line (t quantile at `confidence`) crosses, the date a
cautious lab would plan the next calibration by.

Times are in days (float) from any origin the caller chooses; the pipeline uses
days since 1970-01-01 UTC.

Shared references (`fit_trend_shared`): runs made on the same reference share its
systematic error, so their Type B parts are one draw, not independent ones. The trend
is then a generalised least-squares fit with the covariance
V = diag(u_A^2) + (u_B u_B^T on every pair of runs with the same reference): a common
error moves every point alike and cancels in the slope (it stays in the intercept and
does not shrink with more runs); a change of reference between runs enters the slope
with its full size. Fitting as if independent gives slope intervals that cover the true
slope far less often than stated when the reference changed (tests/test_drift.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib_core.distributions import t_ppf
from calib_core.significance import fit_ols


@dataclass(frozen=True, eq=False)
class Trend:
    """Straight-line trend of one parameter.

    Attributes
    ----------
    t0 : reference time, days (the mean of the points' times: decorrelates a and b).
    intercept : value at t0, SI.
    slope : change per day, SI / day.
    cov : (2, 2) covariance of (intercept, slope).
    dof : residual degrees of freedom (n - 2).
    sigma : residual scale (weighted fits: factor on the given stds).
    n : points.
    t_first, t_last : time span of the points, days.
    """

    t0: float
    intercept: float
    slope: float
    cov: np.ndarray
    dof: int
    sigma: float
    n: int
    t_first: float
    t_last: float

    @property
    def slope_std(self) -> float:
        return float(np.sqrt(self.cov[1, 1]))

    def value(self, t: np.ndarray | float) -> np.ndarray:
        """Fitted value at t (days)."""
        return self.intercept + self.slope * (np.asarray(t, dtype=float) - self.t0)

    def std(self, t: np.ndarray | float) -> np.ndarray:
        """Standard uncertainty of the fitted line at t (days)."""
        dt = np.asarray(t, dtype=float) - self.t0
        return np.sqrt(self.cov[0, 0] + 2.0 * dt * self.cov[0, 1] + dt**2 * self.cov[1, 1])


def _trend_points(
    t_days: Sequence[float], values: Sequence[float]
) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) as float arrays; ValueError unless 1-D, equal length, >= 3 points on >= 2 dates."""
    t = np.asarray(t_days, dtype=float)
    y = np.asarray(values, dtype=float)
    if t.shape != y.shape or t.ndim != 1:
        raise ValueError(f"t_days and values must be 1-D of equal length, got {t.shape}, {y.shape}")
    if t.size < 3 or np.unique(t).size < 2:
        raise ValueError(
            f"a trend needs at least 3 calibrations on 2 or more dates, got {t.size} "
            f"on {np.unique(t).size} date(s)"
        )
    return t, y


def fit_trend(
    t_days: Sequence[float], values: Sequence[float], stds: Sequence[float | None] | None = None
) -> Trend:
    """Weighted straight-line fit of values (SI) against time (days).

    Raises ValueError with fewer than 3 points or fewer than 2 distinct times.
    """
    t, y = _trend_points(t_days, values)
    weighted = stds is not None and all(s is not None and s > 0 for s in stds)
    w = 1.0 / np.asarray(stds, dtype=float) if weighted else np.ones_like(y)
    t0 = float(np.average(t, weights=w**2))
    X = np.column_stack([np.ones_like(t), t - t0]) * w[:, None]
    # Weighted columns are not constant, so the intercept is an ordinary regressor here.
    fit = fit_ols(X, y * w, ["intercept", "slope"])
    return Trend(
        t0=t0,
        intercept=float(fit.coef[0]),
        slope=float(fit.coef[1]),
        cov=fit.cov,
        dof=fit.dof,
        sigma=fit.sigma,
        n=int(t.size),
        t_first=float(t.min()),
        t_last=float(t.max()),
    )


def shared_covariance(
    stds_a: Sequence[float], stds_b: Sequence[float], references: Sequence[str | None]
) -> np.ndarray:
    """Covariance of values whose Type B parts are shared by runs on the same reference.

    Parameters
    ----------
    stds_a : (n,) run-specific (Type A) standard uncertainties, SI.
    stds_b : (n,) the reference's (Type B) standard uncertainty in each value, SI.
    references : (n,) an identity of the reference each run used (e.g. its equipment
        serials); None: a reference shared with no other run.

    Returns
    -------
    (n, n) V = diag(u_A^2) + u_B,i u_B,j for i, j on the same reference (and i = j).
    """
    a = np.asarray(stds_a, dtype=float)
    b = np.asarray(stds_b, dtype=float)
    if a.shape != b.shape or a.ndim != 1 or len(references) != a.size:
        raise ValueError(
            f"stds_a, stds_b and references must be 1-D of equal length, got {a.shape}, "
            f"{b.shape}, {len(references)}"
        )
    if not (
        np.all(np.isfinite(a)) and np.all(a >= 0) and np.all(np.isfinite(b)) and np.all(b >= 0)
    ):
        raise ValueError("standard uncertainties must be finite and >= 0")
    ref = list(references)
    same = np.array(
        [
            [i == j or (ri is not None and ri == rj) for j, rj in enumerate(ref)]
            for i, ri in enumerate(ref)
        ]
    )
    return np.diag(a**2) + np.outer(b, b) * same


def fit_trend_shared(
    t_days: Sequence[float],
    values: Sequence[float],
    stds_a: Sequence[float],
    stds_b: Sequence[float],
    references: Sequence[str | None],
) -> Trend:
    """Straight-line trend by generalised least squares with shared Type B (module docstring).

    The covariance of (intercept, slope) is (X^T V^-1 X)^-1, V from `shared_covariance`:
    the uncertainties are taken as known, not rescaled by the residuals (a reference
    error shared by all runs leaves no scatter to see it by). ``sigma`` is the Birge
    ratio sqrt(chi2 / dof) of the residuals: well above 1, the points scatter more than
    their uncertainties say. Raises ValueError as `fit_trend`, and for a singular V
    (a run with neither Type A nor Type B uncertainty).
    """
    t, y = _trend_points(t_days, values)
    V = shared_covariance(stds_a, stds_b, references)
    if np.any(np.diag(V) <= 0):
        raise ValueError("every point needs a Type A or Type B uncertainty > 0")
    Vi = np.linalg.inv(V)
    t0 = float(np.sum(Vi @ t) / np.sum(Vi))  # decorrelates intercept and slope
    X = np.column_stack([np.ones_like(t), t - t0])
    cov = np.linalg.inv(X.T @ Vi @ X)
    beta = cov @ X.T @ Vi @ y
    r = y - X @ beta
    dof = int(t.size - 2)
    return Trend(
        t0=t0,
        intercept=float(beta[0]),
        slope=float(beta[1]),
        cov=cov,
        dof=dof,
        sigma=float(math.sqrt(max(float(r @ Vi @ r), 0.0) / dof)) if dof > 0 else math.nan,
        n=int(t.size),
        t_first=float(t.min()),
        t_last=float(t.max()),
    )


@dataclass(frozen=True)
class Forecast:
    """When a trend leaves the tolerance band, in days (same origin as the trend).

    crossing : where the fitted line leaves [low, high] after the last point;
        None if it never does within the horizon (or the slope points inwards).
    earliest : where the upper confidence bound of the line first leaves the
        band after the last point (<= crossing); None if not within the horizon.
    out_now : the fitted value at the last point is already outside.
    """

    crossing: float | None
    earliest: float | None
    out_now: bool
    low: float
    high: float
    confidence: float


def forecast_exit(
    trend: Trend,
    low: float,
    high: float,
    *,
    confidence: float = 0.95,
    horizon_days: float = 3650.0,
    step_days: float = 1.0,
) -> Forecast:
    """When the trend leaves [low, high] (module docstring). low may be -inf, high inf."""
    if not low < high:
        raise ValueError(f"tolerance band must have low < high, got [{low}, {high}]")
    now = trend.t_last
    out_now = not low <= float(trend.value(now)) <= high
    crossing = None
    if trend.slope > 0 and math.isfinite(high):
        crossing = now + max(0.0, (high - float(trend.value(now))) / trend.slope)
    elif trend.slope < 0 and math.isfinite(low):
        crossing = now + max(0.0, (low - float(trend.value(now))) / trend.slope)
    if crossing is not None and crossing - now > horizon_days:
        crossing = None
    # Confidence band on a day grid: closed forms exist, a grid is plainer and exact enough.
    grid = now + np.arange(0.0, horizon_days + step_days, step_days)
    k = t_ppf(confidence, trend.dof)
    centre, half = trend.value(grid), k * trend.std(grid)
    outside = (centre + half > high) | (centre - half < low)
    earliest = float(grid[np.argmax(outside)]) if outside.any() else None
    return Forecast(crossing, earliest, out_now, float(low), float(high), confidence)


@dataclass(frozen=True)
class FleetBin:
    """Distribution of one parameter across units in one temperature bin (SI)."""

    temperature: float  # bin centre, deg C
    n: int  # calibrations
    units: int  # distinct units
    mean: float
    std: float  # sample std (ddof 1), nan for n == 1
    median: float
    p05: float
    p95: float
    low: float
    high: float


def fleet_statistics(
    values: Sequence[float],
    temperatures: Sequence[float],
    units: Sequence[str] | None = None,
    *,
    bin_c: float = 5.0,
) -> list[FleetBin]:
    """Distribution of a parameter over a fleet, per temperature bin of width bin_c deg C.

    Bins are centred on multiples of bin_c (20 deg C points land in the 20 bin).
    Points without a temperature (nan) are binned as their own group with
    temperature nan.
    """
    v = np.asarray(values, dtype=float)
    temp = np.asarray(temperatures, dtype=float)
    if v.shape != temp.shape:
        raise ValueError(f"values and temperatures differ in length: {v.shape} vs {temp.shape}")
    u = np.asarray(units if units is not None else np.arange(v.size).astype(str), dtype=object)
    centre = np.round(temp / bin_c) * bin_c
    out = []
    keys = sorted(set(centre[np.isfinite(centre)].tolist())) + (
        [math.nan] if np.isnan(centre).any() else []
    )
    for c in keys:
        sel = np.isnan(centre) if math.isnan(c) else centre == c
        x = v[sel]
        out.append(
            FleetBin(
                temperature=float(c),
                n=int(x.size),
                units=len(set(u[sel].tolist())),
                mean=float(x.mean()),
                std=float(x.std(ddof=1)) if x.size > 1 else math.nan,
                median=float(np.median(x)),
                p05=float(np.percentile(x, 5)),
                p95=float(np.percentile(x, 95)),
                low=float(x.min()),
                high=float(x.max()),
            )
        )
    return out
