"""Thermal compensation, the science: per-parameter polynomials in (T - T_ref), applied.

A thermal campaign calibrates one unit at several temperature points (or logs
a continuous static soak with its temperature channel). Every error-model
parameter p (biases, scale factors, misalignments, g-sensitivity) is then fitted
as

    p(T) = c_0 + c_1 (T - T_ref) + c_2 (T - T_ref)^2 + ...   T clipped to [T_min, T_max]

Order selection (docs/methods.md 3.9, "order chosen by significance"): start at the
highest order the data allow and lower it while the top coefficient fails the
two-sided t test at `alpha` (calib_core.significance.fit_ols). Going down
rather than up matters: a low-order fit of a cubic has a misfit-inflated
residual and a slope partly cancelled by the cubic term, so a forward search
stops too early (seen in simulation). The cap is `max_order`, (distinct
temperatures - 1), and at least one residual degree of freedom. Each step down
is one test, so over-fitting happens with probability about alpha per step.

Points are weighted by 1 / std (the calibration's standard uncertainty) when
every point has one; the scale of the weights is estimated from the residuals
(as fit_ols does), so coefficient uncertainties stay honest when the solver's
uncertainties are somewhat off.

Hysteresis: when a campaign has heating and cooling points, the fit gets one
more column, +1/2 for cooling and -1/2 for heating, so the curve is the
mid-line and the coefficient is (cooling - heating) at equal temperature, with
its own t test ("detected" when significant).

Compensation outside [T_min, T_max] is clipped (the fit says nothing there),
like PX4 and ArduPilot do. A range narrower than MIN_RANGE_C is refused.

Why one module of ~680 lines: the thermal model's fit (order selection by t tests),
its JSON form and its application share the polynomial conventions (T - T_ref,
clipping to the fitted range) that must not drift apart between files.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.ndimage import uniform_filter1d

from calib_core import __version__, params
from calib_core.calibration import Calibration
from calib_core.recording import Recording
from calib_core.significance import fit_ols

MODEL_NAME = "polynomial"
THERMAL_SCHEMA_VERSION = 1
MIN_RANGE_C = 10.0  # deg C, as ArduPilot's TEMP_RANGE_MIN: below this a slope is a guess
DEFAULT_MAX_ORDER = 3  # what PX4 TC_* and ArduPilot INS_TCAL* can carry
DEFAULT_ALPHA = 0.01  # per-step false-alarm rate of the order test (one test per step)
HEATING, COOLING = "heating", "cooling"
HYSTERESIS = "hysteresis"

# Parameters of the error model that a thermal model may carry (noise is not compensated).
_COMPENSABLE = ("bias", "scale", "misalign", "gsens", "k2", "k3")


class ThermalRangeError(ValueError):
    """The campaign's temperature range is too narrow for a compensation fit."""


def is_compensable(name: str) -> bool:
    """Whether a canonical parameter name belongs in a thermal model (not noise)."""
    return params.validate(name).split(".")[1] in _COMPENSABLE


@dataclass(frozen=True)
class ThermalPoint:
    """One estimate of one parameter at one temperature.

    temperature : deg C.
    value, std : the estimate and its standard uncertainty (SI), std may be None.
    direction : "heating", "cooling", or "" when unknown.
    """

    temperature: float
    value: float
    std: float | None = None
    direction: str = ""


@dataclass(frozen=True)
class Hysteresis:
    """Cooling minus heating at equal temperature, SI unit of the parameter."""

    value: float
    std: float
    t: float
    t_crit: float

    @property
    def detected(self) -> bool:
        return bool(abs(self.t) > self.t_crit)

    def to_dict(self) -> dict[str, float | bool]:
        return {
            "value": self.value,
            "std": self.std,
            "t": self.t,
            "t_crit": self.t_crit,
            "detected": self.detected,
        }


@dataclass(frozen=True, eq=False)
class ParameterCurve:
    """Polynomial p(T) of one parameter.

    Attributes
    ----------
    name : canonical parameter name.
    coef : (order + 1,) c_k of (T - t_ref)^k, unit of the parameter per deg C^k.
    cov : (order + 1, order + 1) covariance of coef.
    sigma : residual standard deviation of the points about the curve (weighted
        fits: of the normalised residuals, i.e. the factor on the given stds).
    n_points : points fitted.
    selection : one entry per order tried: order, t of its top coefficient, t_crit.
    hysteresis : None when the points have one direction only.
    """

    name: str
    coef: np.ndarray
    cov: np.ndarray
    sigma: float
    n_points: int
    selection: tuple[dict[str, float], ...] = ()
    hysteresis: Hysteresis | None = None

    @property
    def order(self) -> int:
        return int(self.coef.shape[0] - 1)

    def value(self, dt: np.ndarray | float) -> np.ndarray:
        """p at dt = T - t_ref (deg C, already clipped), same shape as dt."""
        return np.polynomial.polynomial.polyval(np.asarray(dt, dtype=float), self.coef)

    def std(self, dt: np.ndarray | float) -> np.ndarray:
        """Standard uncertainty of the fitted curve at dt: sqrt(x^T cov x), x = dt^k."""
        x = np.power.outer(np.asarray(dt, dtype=float), np.arange(self.order + 1))
        return np.sqrt(np.einsum("...i,ij,...j->...", x, self.cov, x))

    def to_dict(self) -> dict[str, Any]:
        return {
            "coef": self.coef.tolist(),
            "cov": self.cov.tolist(),
            "sigma": self.sigma,
            "n_points": self.n_points,
            "unit": params.unit_of(self.name),
            "selection": list(self.selection),
            "hysteresis": None if self.hysteresis is None else self.hysteresis.to_dict(),
        }

    @classmethod
    def from_dict(cls, name: str, doc: Mapping[str, Any]) -> ParameterCurve:
        h = doc.get("hysteresis")
        coef = np.asarray(doc["coef"], dtype=float)
        cov = np.asarray(doc["cov"], dtype=float)
        if coef.ndim != 1 or cov.shape != (coef.size, coef.size):
            raise ValueError(
                f"thermal curve {name}: coef must be (k,) and cov (k, k), got "
                f"{coef.shape} and {cov.shape}"
            )
        return cls(
            name=params.validate(name),
            coef=coef,
            cov=cov,
            sigma=float(doc["sigma"]),
            n_points=int(doc["n_points"]),
            selection=tuple(doc.get("selection", ())),
            hysteresis=None
            if h is None
            else Hysteresis(float(h["value"]), float(h["std"]), float(h["t"]), float(h["t_crit"])),
        )


def check_range(
    temperatures: Iterable[float], min_range: float = MIN_RANGE_C
) -> tuple[float, float]:
    """(T_min, T_max) of the points; ThermalRangeError when the span is below `min_range`."""
    t = np.asarray(list(temperatures), dtype=float)
    if t.size == 0 or not np.isfinite(t).all():
        raise ThermalRangeError(f"temperatures must be finite numbers, got {t.tolist()}")
    lo, hi = float(t.min()), float(t.max())
    if hi - lo < min_range:
        raise ThermalRangeError(
            f"temperature range {lo:.2f} .. {hi:.2f} deg C spans {hi - lo:.2f} deg C; a "
            f"compensation fit needs at least {min_range:g} deg C between the coldest and "
            f"the hottest point"
        )
    return lo, hi


def fit_curve(
    name: str,
    points: Sequence[ThermalPoint],
    t_ref: float,
    *,
    max_order: int = DEFAULT_MAX_ORDER,
    alpha: float = DEFAULT_ALPHA,
) -> ParameterCurve:
    """Fit p(T) with the order chosen by t tests of the top coefficient (module docstring).

    Parameters
    ----------
    name : canonical parameter name.
    points : (n,) estimates; n >= 2 distinct temperatures.
    t_ref : reference temperature, deg C.
    max_order : highest order tried.
    alpha : significance level of each order step (and the hysteresis test).

    Returns
    -------
    ParameterCurve
    """
    params.validate(name)
    if not points:
        raise ValueError(f"{name}: no points to fit")
    T = np.array([p.temperature for p in points], dtype=float)
    y = np.array([p.value for p in points], dtype=float)
    stds = [p.std for p in points]
    weighted = all(s is not None and s > 0 for s in stds)
    w = 1.0 / np.array(stds, dtype=float) if weighted else np.ones_like(y)
    directions = {p.direction for p in points}
    unknown = directions - {HEATING, COOLING, ""}
    if unknown:
        raise ValueError(f"{name}: direction must be 'heating', 'cooling' or '', got {unknown}")
    two_way = {HEATING, COOLING} <= directions
    if two_way and "" in directions:
        raise ValueError(f"{name}: some points have a direction and some not")
    extra = [np.array([0.5 if p.direction == COOLING else -0.5 for p in points])] if two_way else []
    n_distinct = np.unique(T).size
    cap = min(max_order, n_distinct - 1, len(points) - 2 - len(extra))
    if cap < 0:
        raise ValueError(
            f"{name}: {len(points)} points at {n_distinct} temperatures are too few for a fit"
        )

    def fit(order: int):
        cols = [(T - t_ref) ** k for k in range(order + 1)] + extra
        names = [f"c{k}" for k in range(order + 1)] + ([HYSTERESIS] if two_way else [])
        X = np.column_stack(cols)
        return fit_ols(X * w[:, None], y * w, names, alpha=alpha)

    selection = []
    for order in range(cap, -1, -1):
        best = fit(order)
        selection.append({"order": order, "t": float(best.t[order]), "t_crit": best.t_crit})
        if order == 0 or abs(best.t[order]) > best.t_crit:
            break
    hyst = None
    if two_way:
        j = best.names.index(HYSTERESIS)
        hyst = Hysteresis(
            float(best.coef[j]), float(best.std[j]), float(best.t[j]), float(best.t_crit)
        )
    k = order + 1
    return ParameterCurve(
        name=name,
        coef=best.coef[:k].copy(),
        cov=best.cov[:k, :k].copy(),
        sigma=best.sigma,
        n_points=len(points),
        selection=tuple(selection),
        hysteresis=hyst,
    )


@dataclass(frozen=True)
class CampaignPoint:
    """One calibration of a thermal campaign: its temperature (deg C) and direction."""

    temperature: float
    calibration: Calibration
    direction: str = ""


def directions_from_sequence(temperatures: Sequence[float], tol: float = 0.5) -> list[str]:
    """Heating / cooling label of each run of a campaign, in the order they were run.

    A run is "heating" when its temperature is above the previous run's by more
    than `tol` deg C, "cooling" when below; a run at (about) the same temperature
    keeps the previous label; the first run takes the label of the first change.
    """
    labels: list[str] = []
    for prev, cur in zip(temperatures[:-1], temperatures[1:], strict=True):
        step = cur - prev
        labels.append(
            HEATING if step > tol else COOLING if step < -tol else (labels[-1] if labels else "")
        )
    first = next((lab for lab in labels if lab), HEATING)
    labels = [first, *labels]
    for i in range(1, len(labels)):  # flat steps before the first change
        labels[i] = labels[i] or labels[i - 1]
    return labels


def campaign_points(
    campaign: Sequence[CampaignPoint], names: Iterable[str] | None = None
) -> dict[str, list[ThermalPoint]]:
    """Per-parameter points from the calibrations of a campaign.

    names : parameters to take; default every compensable parameter present in
        every calibration of the campaign.
    """
    if not campaign:
        raise ValueError("empty thermal campaign")
    if names is None:
        common = set.intersection(*(set(c.calibration.parameters) for c in campaign))
        names = sorted(n for n in common if is_compensable(n))
    out: dict[str, list[ThermalPoint]] = {}
    for name in names:
        pts = []
        for i, c in enumerate(campaign):
            p = c.calibration.parameters.get(name)
            if p is None:
                raise ValueError(f"campaign point {i} ({c.temperature} deg C) has no {name}")
            pts.append(ThermalPoint(c.temperature, p.value, p.std, c.direction))
        out[name] = pts
    return out


def fit_model(
    points: Mapping[str, Sequence[ThermalPoint]],
    *,
    t_ref: float | None = None,
    max_order: int = DEFAULT_MAX_ORDER,
    alpha: float = DEFAULT_ALPHA,
    min_range: float = MIN_RANGE_C,
    info: Mapping[str, Any] | None = None,
) -> ThermalModel:
    """Fit a ThermalModel: one curve per parameter.

    Parameters
    ----------
    points : parameter name -> its points (campaign_points or sweep_points).
    t_ref : reference temperature, deg C; default the middle of the range
        (rounded to 0.1 deg C), which keeps the polynomial columns well conditioned.
    max_order, alpha : as fit_curve.
    min_range : smallest accepted T_max - T_min, deg C.
    info : facts kept in the model's JSON (serial, run ids...).

    Raises
    ------
    ThermalRangeError when the temperatures span less than `min_range`.
    """
    if not points:
        raise ValueError("no parameters to fit")
    lo, hi = check_range((p.temperature for pts in points.values() for p in pts), min_range)
    ref = round((lo + hi) / 2.0, 1) if t_ref is None else float(t_ref)
    curves = {
        name: fit_curve(name, pts, ref, max_order=max_order, alpha=alpha)
        for name, pts in sorted(points.items())
    }
    settings = {"max_order": max_order, "alpha": alpha, "min_range_c": min_range}
    return ThermalModel(ref, lo, hi, curves, {**dict(info or {}), "fit": settings})


def fit_campaign(campaign: Sequence[CampaignPoint], **kwargs: Any) -> ThermalModel:
    """fit_model on the calibrations of a campaign (kwargs as fit_model)."""
    return fit_model(campaign_points(campaign), **kwargs)


@dataclass
class ThermalModel:
    """Temperature compensation of one unit: a curve per parameter over [t_min, t_max] deg C.

    Attributes
    ----------
    t_ref : reference temperature of the curves, deg C.
    t_min, t_max : the fitted range, deg C; temperatures outside are clipped.
    curves : canonical parameter name -> ParameterCurve (coefficients of T - t_ref).
    info : fit facts (serial, runs, benefit, order selection).
    """

    t_ref: float
    t_min: float
    t_max: float
    curves: dict[str, ParameterCurve]
    info: dict[str, Any] = field(default_factory=dict)
    name: str = MODEL_NAME
    version: int = THERMAL_SCHEMA_VERSION

    def __post_init__(self) -> None:
        if not self.t_max > self.t_min:
            raise ValueError(f"thermal model: t_max {self.t_max} must exceed t_min {self.t_min}")

    def clip(self, temperature: np.ndarray | float) -> np.ndarray:
        """Temperatures clipped into the fitted range (the model says nothing outside)."""
        return np.clip(np.asarray(temperature, dtype=float), self.t_min, self.t_max)

    def value(self, name: str, temperature: np.ndarray | float) -> np.ndarray:
        """p_name(T), T clipped; same shape as `temperature`."""
        return self.curves[name].value(self.clip(temperature) - self.t_ref)

    def std(self, name: str, temperature: np.ndarray | float) -> np.ndarray:
        """Standard uncertainty of the fitted p_name(T), T clipped."""
        return self.curves[name].std(self.clip(temperature) - self.t_ref)

    def parameters_at(self, temperature: float) -> dict[str, float]:
        """Every modelled parameter at one temperature (deg C), SI."""
        return {n: float(self.value(n, temperature)) for n in self.curves}

    def calibration_at(
        self, base: Calibration, temperature: float, base_temperature: float | None = None
    ) -> Calibration:
        """`base` moved to `temperature` (see `correct` for the meaning of base_temperature).

        Uncertainties: the curve's at `temperature` when the curve values are used
        as they are; base's own when only the curve's change is added (the
        uncertainty of that change is not included).
        """
        cal = Calibration(base.procedure, base.gravity, dict(base.parameters))
        for name, value in self._values(base, np.array([temperature]), base_temperature).items():
            if base_temperature is None:
                std = float(self.std(name, temperature))
            else:
                std = base.parameters[name].std if name in base.parameters else None
            cal.add(name, float(value[0]), std)
        return cal

    def anchored(self, base: Calibration, base_temperature: float) -> ThermalModel:
        """The model with each curve moved to pass through `base`'s value at `base_temperature`.

        p'(T) = base value + p(T) - p(base_temperature) (T clipped): only the
        curve's change with temperature is kept, the constant comes from `base`
        (absent parameters count as 0), as ArduPilot combines its offsets with its
        temperature calibration. Covariances are those of the original curves.
        """
        curves = {}
        for name, curve in self.curves.items():
            coef = curve.coef.astype(float)  # a copy
            coef[0] += base.value(name) - float(self.value(name, base_temperature))
            curves[name] = replace(curve, coef=coef)
        return replace(self, curves=curves)

    def _values(
        self, base: Calibration, temperature: np.ndarray, base_temperature: float | None
    ) -> dict[str, np.ndarray]:
        """(N,) values of the modelled parameters at each temperature."""
        model = self if base_temperature is None else self.anchored(base, base_temperature)
        return {name: model.value(name, temperature) for name in self.curves}

    def correct(
        self,
        acc: np.ndarray,
        gyr: np.ndarray,
        temperature: np.ndarray | float,
        base: Calibration,
        base_temperature: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Invert the error model with every parameter at each sample's temperature.

        Parameters
        ----------
        acc : (N, 3) measured specific force, m/s^2.
        gyr : (N, 3) measured rate, rad/s.
        temperature : (N,) or scalar, deg C (clipped to the model's range).
        base : the calibration that supplies the parameters the model lacks.
        base_temperature : the temperature `base` was measured at. Given, each
            modelled parameter is base's value plus the curve's change from
            base_temperature to T (so a newer calibration's offsets are kept and
            only the thermal change is added, as ArduPilot does); None, the curve
            values are used as they are.

        Returns
        -------
        (acc_true, gyr_true), each (N, 3).
        """
        acc = np.asarray(acc, dtype=float)
        gyr = np.asarray(gyr, dtype=float)
        n = acc.shape[0]
        temp = np.broadcast_to(np.asarray(temperature, dtype=float), (n,))
        values = self._values(base, temp, base_temperature)

        def field_of(name: str) -> np.ndarray:
            return values[name] if name in values else np.full(n, base.value(name))

        def vec(sensor: str) -> np.ndarray:
            return np.stack([field_of(params.bias(sensor, a)) for a in params.AXES], axis=1)

        def mat(names: list[list[str]]) -> np.ndarray:  # (N, 3, 3)
            return np.stack([np.stack([field_of(c) for c in row], -1) for row in names], -2)

        eye = np.eye(3)
        acc_true = np.linalg.solve(
            eye + mat(params.matrix_names("acc")), (acc - vec("acc"))[..., None]
        )[..., 0]
        gsens = mat(params.gsens_names())
        rhs = gyr - vec("gyr") - np.einsum("nij,nj->ni", gsens, acc_true)
        gyr_true = np.linalg.solve(eye + mat(params.matrix_names("gyr")), rhs[..., None])[..., 0]
        return acc_true, gyr_true

    def apply(
        self,
        recording: Recording,
        base: Calibration,
        base_temperature: float | None = None,
        temperature: float | None = None,
    ) -> Recording:
        """The recording calibrated at its own temperature channel (or `temperature`, deg C)."""
        if recording.temp is None and temperature is None:
            raise ValueError(
                f"recording {recording.source or ''}: no temperature channel; give the "
                f"temperature (deg C) to apply the thermal model"
            )
        temp = recording.temp if temperature is None else temperature
        acc, gyr = self.correct(recording.acc, recording.gyr, temp, base, base_temperature)
        return Recording(
            recording.t,
            acc,
            gyr,
            recording.temp,
            recording.reference,
            recording.label,
            recording.source,
        )

    # --- JSON -------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.name,
            "schema_version": self.version,
            "software_version": __version__,
            "t_ref": self.t_ref,
            "t_min": self.t_min,
            "t_max": self.t_max,
            "curves": {n: c.to_dict() for n, c in sorted(self.curves.items())},
            "info": self.info,
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> ThermalModel:
        if doc.get("model") != MODEL_NAME:
            raise ValueError(
                f"thermal model JSON: model {doc.get('model')!r}, expected {MODEL_NAME!r}"
            )
        version = doc.get("schema_version")
        if version != THERMAL_SCHEMA_VERSION:
            raise ValueError(
                f"thermal model JSON schema_version {version!r} is not supported "
                f"(this software reads {THERMAL_SCHEMA_VERSION})"
            )
        return cls(
            t_ref=float(doc["t_ref"]),
            t_min=float(doc["t_min"]),
            t_max=float(doc["t_max"]),
            curves={n: ParameterCurve.from_dict(n, c) for n, c in doc["curves"].items()},
            info=dict(doc.get("info", {})),
        )


def shift_polynomial(coef: np.ndarray, from_ref: float, to_ref: float) -> np.ndarray:
    """Coefficients of the same polynomial in (T - to_ref) instead of (T - from_ref).

    p(T) = sum c_k (T - from_ref)^k = sum d_k (T - to_ref)^k; same length as coef.
    """
    c = np.asarray(coef, dtype=float)
    shifted = np.polynomial.Polynomial(c)(np.polynomial.Polynomial([to_ref - from_ref, 1.0])).coef
    out = np.zeros_like(c)
    out[: shifted.size] = shifted[: c.size]
    return out


# --- measured benefit --------------------------------------------------------


@dataclass(frozen=True)
class Benefit:
    """Residual parameter error over a campaign's points, before and after compensation.

    rms_before : RMS of (point - value at T_ref), what an uncompensated unit shows.
    rms_after : RMS of (point - curve at the point).
    rms_holdout : RMS of (point - curve refitted without that temperature) over
        the interior temperatures, the error at a temperature the fit has not
        seen; None with < 4 temperatures.
    """

    name: str
    rms_before: float
    rms_after: float
    rms_holdout: float | None


def benefit(model: ThermalModel, points: Mapping[str, Sequence[ThermalPoint]]) -> list[Benefit]:
    """Before / after / held-out residual error of each modelled parameter (SI units)."""
    fit = model.info.get("fit", {})
    out = []
    for name, curve in sorted(model.curves.items()):
        pts = points[name]
        T = np.array([p.temperature for p in pts])
        y = np.array([p.value for p in pts])
        before = y - curve.value(0.0)
        after = y - model.value(name, T)
        held: list[float] = []
        temps = np.unique(T)
        if temps.size >= 4:
            for t_out in temps[1:-1]:  # interior points: interpolation, as the model is used
                rest = [p for p in pts if p.temperature != t_out]
                try:
                    c = fit_curve(
                        name,
                        rest,
                        model.t_ref,
                        max_order=curve.order,
                        alpha=fit.get("alpha", DEFAULT_ALPHA),
                    )
                except ValueError:
                    continue
                held += list(y[t_out == T] - c.value(t_out - model.t_ref))
        out.append(
            Benefit(
                name,
                float(np.sqrt(np.mean(before**2))),
                float(np.sqrt(np.mean(after**2))),
                float(np.sqrt(np.mean(np.square(held)))) if held else None,
            )
        )
    return out


# --- continuous sweeps -------------------------------------------------------


def temperature_direction(
    t: np.ndarray, temp: np.ndarray, window_s: float = 60.0, min_rate: float = 0.05 / 60.0
) -> np.ndarray:
    """Per-sample "heating" / "cooling" / "" from the smoothed temperature slope.

    The slope of a moving average over `window_s` seconds (the raw channel's
    quantisation and noise make sample-to-sample differences meaningless);
    slopes below `min_rate` deg C/s are "" (a soak, no direction).
    """
    t = np.asarray(t, dtype=float)
    temp = np.asarray(temp, dtype=float)
    width = max(1, int(round(window_s / np.median(np.diff(t)))))
    slope = np.gradient(uniform_filter1d(temp, width, mode="nearest"), t)
    out = np.full(t.shape, "", dtype=object)
    out[slope > min_rate] = HEATING
    out[slope < -min_rate] = COOLING
    return out


def sweep_points(
    recording: Recording,
    f_true: np.ndarray,
    base: Calibration | None = None,
    *,
    bin_c: float = 1.0,
    min_samples: int = 50,
    window_s: float = 60.0,
) -> dict[str, list[ThermalPoint]]:
    """Bias points from a static soak with a temperature channel (heating and/or cooling).

    The unit stays in one attitude, so only the zero-rate / zero-g outputs are
    observable: for each temperature bin and direction, the mean of
    measured - (I + M) f_true - G f_true (M, G from `base`, else zero) is the
    accelerometer and gyro bias at that temperature.

    Parameters
    ----------
    recording : (N,) samples with a temperature channel.
    f_true : (3,) the true specific force of the soak attitude, m/s^2.
    base : calibration whose scale / misalignment / g-sensitivity are removed.
    bin_c : bin width, deg C.
    min_samples : bins with fewer samples are dropped.
    window_s : smoothing window of the direction detection, s.

    Returns
    -------
    {"acc.bias.x": [ThermalPoint, ...], ..., "gyr.bias.z": [...]}, std = standard
    error of the bin mean (white noise assumed within a bin).
    """
    if recording.temp is None:
        raise ValueError(f"sweep {recording.source or ''}: needs a temperature channel")
    f = np.asarray(f_true, dtype=float).reshape(3)
    cal = base or Calibration("none", float(np.linalg.norm(f)))
    acc_res = recording.acc - (np.eye(3) + cal.matrix("acc")) @ f
    gyr_res = recording.gyr - cal.gsens() @ f
    direction = temperature_direction(recording.t, recording.temp, window_s)
    bins = np.floor(recording.temp / bin_c).astype(int)
    out: dict[str, list[ThermalPoint]] = {
        params.bias(s, a): [] for s in ("acc", "gyr") for a in params.AXES
    }
    for d in (HEATING, COOLING):
        for b in np.unique(bins[direction == d]):
            sel = (direction == d) & (bins == b)
            n = int(sel.sum())
            if n < min_samples:
                continue
            temp = float(recording.temp[sel].mean())
            for s, res in (("acc", acc_res), ("gyr", gyr_res)):
                mean = res[sel].mean(axis=0)
                sem = res[sel].std(axis=0, ddof=1) / np.sqrt(n)
                for i, a in enumerate(params.AXES):
                    out[params.bias(s, a)].append(
                        ThermalPoint(temp, float(mean[i]), float(sem[i]), d)
                    )
    return out
