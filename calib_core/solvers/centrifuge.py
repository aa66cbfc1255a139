"""Centrifuge high-g accelerometer modelling with significance-based reduction.

Procedure (methods.md 2.8). The IMU is mounted on the centrifuge arm in six
positions, each accelerometer axis once pointing to the table axis (``+``)
and once away from it (``-``). Per mounting position:

1. zero output: static records at table positions 0/90/180/270 deg, averaged,
   so a tilt of the table axis (which puts g*tilt on the horizontal axes with
   the table angle's phase) cancels;
2. a run near 1 g: the radial output change gives the effective radius

       E_rot - E_static = R * w0 * (w0 + 2 * Omega_V)

   with w0 the signed table rate about the up axis (positive anticlockwise
   seen from above) and Omega_V the up component of Earth rate, so the
   ``+-`` of the paper is the rotation sense; and the horizontal misalignment
   phi_h = atan(a_tangential / a_radial);
3. steps 2 g .. 20 g: each averaged over whole table revolutions only (the
   tilt term is a sinusoid of the table angle), input specific force
   a = R * w * (w + 2 * Omega_V) along the radial direction rotated by phi_h,
   plus g along the up axis.

Frames. A mounting position's frame is (r, t, u): r towards the table axis,
u up, t = u x r. The centripetal specific force points along +r, gravity's
reaction along +u. The sensor axes are a signed permutation of (r, t, u)
(`MOUNTS`); phi_h is the angle at which the sensor sees the radial force in
its r-t plane: f_mount = (a cos phi_h, a sin phi_h, g).

Model per accelerometer axis i (others j, k), error = output - input:

    E_i - f_i = c0 + c1 f_i + c2 f_i^2 + c3 f_i^3 + d_j f_j + d_k f_k
                + q_j f_j^2 + q_k f_k^2 + p_ij f_i f_j + p_ik f_i f_k + p_jk f_j f_k

fitted by weighted least squares and reduced by `stepwise_reduce`. Three
things make the reduction keep the true terms and only those:

- Identifiability (`identifiable_terms`). In every position only the radial
  input and g are non-zero (up to phi_h ~ 1e-2), so each product p is g times
  a radial input where it is non-zero: a radius change (own axis x up axis),
  a phi_h change (radial x up, seen by the tangential axis) or a linear term
  minus a position-group offset. The paper's 10-term model is therefore
  rank deficient but for phi_h; the products are reported as not
  identifiable with these mountings and not fitted (7 candidates per axis).
- phi_h is refined over all steps. From the 1 g run alone its error
  (~1e-4 rad) reaches 0.02 m/s^2 on the tangential axis at 20 g; the fit of
  each axis carries one nuisance column d f_i / d phi_h per position where
  the axis is tangential (kept, not tested), iterated to convergence. The
  tangential axis's linear coupling to the radial input is then separated
  from phi_h by the position-group offset only (it is g d_ij where the
  other axis is up).
- Weights. A step mean's variance is sem^2 + (kappa f_i)^2: white noise plus
  a scale factor that changes from step to step (`step_weights`, kappa
  estimated from the full model unless given). Unweighted, the growth of
  the residuals with g passes for cubic and quadratic terms.

Limits the data impose (say so to users):
- R and the radial axis's gain cannot be separated by a centrifuge; the
  1 g scale error of each axis (``acc.scale.i`` from a static calibration) is
  an input to the radius, and the remaining radius error goes one for one
  into the fitted scale (its uncertainty includes the radius's).
- Products of inputs need mountings with two non-zero horizontal inputs
  (e.g. the axis at 45 deg to the arm), which this procedure does not have.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from calib_core.calibration import Calibration, SegmentResidual, StepRecord
from calib_core.earth import EARTH_RATE
from calib_core.params import AXES, AXIS_INDEX
from calib_core.recording import Recording
from calib_core.significance import CONST, OlsFit, Reduction, fit_ols, stepwise_reduce
from calib_core.units import STANDARD_GRAVITY

# Sensor axes in the mounting frame (r, t, u): row i of P is sensor axis i.
# Positions keep the frame right-handed (for "-": axis = -r, the next = -t).
MOUNTS: dict[str, np.ndarray] = {
    "x+": np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float),
    "x-": np.array([[-1, 0, 0], [0, -1, 0], [0, 0, 1]], dtype=float),
    "y+": np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], dtype=float),
    "y-": np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=float),
    "z+": np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], dtype=float),
    "z-": np.array([[0, -1, 0], [0, 0, 1], [-1, 0, 0]], dtype=float),
}
ZERO_POSITIONS_DEG = (0.0, 90.0, 180.0, 270.0)
STEP_KINDS = ("zero", "1g", "step")

_TERM = re.compile(r"^a_([xyz])(?:\^([23]))?(?:\*a_([xyz]))?$")


def full_terms(axis: str) -> tuple[str, ...]:
    """The 10 candidate regressors of the full high-g model of `axis` (constant not included)."""
    i = AXIS_INDEX[axis]
    j, k = AXES[(i + 1) % 3], AXES[(i + 2) % 3]
    # products named in axis order: "a_x*a_z", never "a_z*a_x"
    pairs = [sorted(p, key=AXIS_INDEX.__getitem__) for p in ((axis, j), (axis, k), (j, k))]
    return (
        f"a_{axis}",
        f"a_{axis}^2",
        f"a_{axis}^3",
        f"a_{j}",
        f"a_{k}",
        f"a_{j}^2",
        f"a_{k}^2",
        *(f"a_{p}*a_{q}" for p, q in pairs),
    )


def term_values(f: np.ndarray, terms: Sequence[str]) -> np.ndarray:
    """Regressor columns for the given term names.

    Parameters
    ----------
    f : (N, 3) input specific force in the sensor axes, m/s^2.
    terms : names ``"const"``, ``"a_x"``, ``"a_x^2"``, ``"a_x^3"``, ``"a_x*a_y"``.

    Returns
    -------
    (N, len(terms)) float.
    """
    f = np.atleast_2d(np.asarray(f, dtype=float))
    cols = []
    for name in terms:
        if name == CONST:
            cols.append(np.ones(f.shape[0]))
            continue
        m = _TERM.match(name)
        if not m or (m[2] and m[3]):
            raise ValueError(
                f"unknown high-g term {name!r}; expected const, a_x, a_x^2, a_x^3 or a_x*a_y"
            )
        col = f[:, AXIS_INDEX[m[1]]] ** (int(m[2]) if m[2] else 1)
        if m[3]:
            col = col * f[:, AXIS_INDEX[m[3]]]
        cols.append(col)
    return np.column_stack(cols) if cols else np.empty((f.shape[0], 0))


def canonical_name(axis: str, term: str) -> str:
    """Canonical parameter name (calib_core.params) of `term` in the model of `axis`.

    const -> acc.bias.x, a_x -> acc.scale.x, a_x^2 -> acc.k2.x, a_x^3 -> acc.k3.x,
    a_y -> acc.misalign.xy, a_y^2 -> acc.k2.xy, a_y*a_z -> acc.kp.x_yz.
    """
    if term == CONST:
        return f"acc.bias.{axis}"
    m = _TERM.match(term)
    if not m or (m[2] and m[3]) or (m[1] != axis and m[2] == "3"):
        raise ValueError(f"term {term!r} has no canonical name in the model of axis {axis!r}")
    if m[3]:
        return f"acc.kp.{axis}_{m[1]}{m[3]}"
    if m[1] == axis:
        return {None: f"acc.scale.{axis}", "2": f"acc.k2.{axis}", "3": f"acc.k3.{axis}"}[m[2]]
    return f"acc.k2.{axis}{m[1]}" if m[2] else f"acc.misalign.{axis}{m[1]}"


@dataclass(frozen=True, eq=False)
class CentrifugeStep:
    """One record of a centrifuge run.

    mount : one of `MOUNTS` ("x+", ..., "z-").
    kind : "zero" (static at `table_position_deg`), "1g" (the radius run) or "step".
    recording : samples with reference channels ``"table_angle"`` (rad,
        unwrapped or wrapped) and ``"table_rate"`` (rad/s, signed about up).
    nominal_g : nominal input in g (0 for zero records), for labels and reports.
    """

    mount: str
    kind: str
    recording: Recording
    nominal_g: float = 0.0
    table_position_deg: float | None = None

    def __post_init__(self) -> None:
        where = self.recording.source or f"{self.mount} {self.kind} {self.nominal_g:g} g"
        if self.mount not in MOUNTS:
            raise ValueError(f"{where}: mount must be one of {list(MOUNTS)}, got {self.mount!r}")
        if self.kind not in STEP_KINDS:
            raise ValueError(f"{where}: kind must be one of {STEP_KINDS}, got {self.kind!r}")
        for ch in ("table_angle", "table_rate"):
            if ch not in self.recording.reference:
                raise ValueError(f"{where}: reference channel {ch!r} is missing")
        if self.kind == "zero" and self.table_position_deg is None:
            raise ValueError(f"{where}: a zero record needs table_position_deg")


@dataclass(frozen=True)
class CentrifugeSettings:
    """Settings of `solve_centrifuge`.

    latitude_deg : site latitude (Earth rate's vertical component).
    gravity : local gravity, m/s^2 (the vertical input).
    alpha : significance level of the t and F tests.
    scale_1g : per axis, the 1 g scale error K - 1 from a static calibration
        (the centrifuge cannot separate it from the radius); absent = 0.
    common_radius : one effective radius for all positions (inverse-variance
        mean of the six estimates; right when the proof masses sit within
        millimetres) instead of one per position.
    iterations : radius / phi_h / model passes; later passes remove the model's
        even-order terms at 1 g from the radius estimate and refine phi_h.
    scale_instability : relative scale-factor instability from step to step
        (one value or one per axis), which makes a step's error grow with its
        input; None (default) estimates it per axis from the full model's
        residuals (`step_weights`). The steps are weighted by 1 / variance.
    """

    latitude_deg: float
    gravity: float = STANDARD_GRAVITY
    alpha: float = 0.05
    scale_1g: Mapping[str, float] = field(default_factory=dict)
    common_radius: bool = True
    iterations: int = 4
    scale_instability: float | Mapping[str, float] | None = None


@dataclass(frozen=True)
class Estimate:
    """A value with its standard uncertainty (1 sigma)."""

    value: float
    std: float


@dataclass(frozen=True)
class RevolutionMean:
    """Whole-revolution average of one record: mean (3,) outputs and mean table rate."""

    acc: np.ndarray
    acc_std: np.ndarray  # (3,) standard error of the mean, white-noise assumption
    rate: float
    rate_std: float
    revolutions: int
    samples: int


def whole_revolution_mean(recording: Recording) -> RevolutionMean:
    """Average a rotating record over whole revolutions of the table angle only.

    Samples from the first one up to (not including) the first sample whose
    accumulated table angle reaches the last whole revolution are averaged;
    anything periodic in the table angle (axis tilt, horizontal Earth-rate
    Coriolis) then averages out.
    """
    angle = np.unwrap(np.asarray(recording.reference["table_angle"], dtype=float))
    turned = np.abs(angle - angle[0])
    revolutions = int(np.floor(turned[-1] / (2.0 * math.pi)))
    if revolutions < 1:
        raise ValueError(
            f"{recording.source or recording.label}: the table turned "
            f"{math.degrees(turned[-1]):.1f} deg, need at least one whole revolution"
        )
    use = turned < revolutions * 2.0 * math.pi
    n = int(use.sum())
    acc = recording.acc[use]
    rate = np.asarray(recording.reference["table_rate"], dtype=float)[use]
    return RevolutionMean(
        acc=acc.mean(axis=0),
        acc_std=acc.std(axis=0, ddof=1) / math.sqrt(n),
        rate=float(rate.mean()),
        rate_std=float(rate.std(ddof=1) / math.sqrt(n)),
        revolutions=revolutions,
        samples=n,
    )


def zero_output(records: Sequence[CentrifugeStep]) -> tuple[np.ndarray, np.ndarray]:
    """Zero output of one mounting position from its four static table positions.

    Returns
    -------
    (mean (3,), standard error (3,)), m/s^2: the average of the four position
    means, in which a table-axis tilt cancels.
    """
    positions = sorted(float(r.table_position_deg) % 360.0 for r in records)
    if len(positions) != 4 or not np.allclose(positions, ZERO_POSITIONS_DEG, atol=1.0):
        where = records[0].mount if records else "?"
        raise ValueError(
            f"mount {where}: zero output needs static records at table positions "
            f"{ZERO_POSITIONS_DEG} deg, got {positions}"
        )
    means = np.array([r.recording.acc.mean(axis=0) for r in records])
    sems = np.array(
        [r.recording.acc.std(axis=0, ddof=1) / math.sqrt(len(r.recording)) for r in records]
    )
    return means.mean(axis=0), np.sqrt((sems**2).sum(axis=0)) / 4.0


def vertical_earth_rate(latitude_deg: float) -> float:
    """Up component of Earth rate, rad/s (positive in the northern hemisphere)."""
    return EARTH_RATE * math.sin(math.radians(latitude_deg))


def centripetal_input(radius: float, rate: float, omega_v: float) -> float:
    """Specific force towards the table axis, R w (w + 2 Omega_V), m/s^2.

    `rate` is signed about the up axis; the Coriolis term of Earth rate adds
    when the table turns with the Earth and subtracts when against it.
    """
    return radius * rate * (rate + 2.0 * omega_v)


def effective_radius(
    delta: float, delta_std: float, rate: float, rate_std: float, omega_v: float
) -> Estimate:
    """Effective radius from the radial input change at the near-1 g run.

    Parameters
    ----------
    delta, delta_std : a_radial = E_rot - E_static corrected to input units, m/s^2.
    rate, rate_std : mean signed table rate and its standard error, rad/s.
    omega_v : vertical Earth-rate component, rad/s.

    Returns
    -------
    Estimate, m: R = delta / (w0 (w0 + 2 Omega_V)), uncertainty from delta and w0.
    """
    denom = rate * (rate + 2.0 * omega_v)
    if denom <= 0.0:
        raise ValueError(f"near-1 g run: table rate {rate} rad/s gives no centripetal input")
    R = delta / denom
    d_rate = (2.0 * rate + 2.0 * omega_v) / denom  # d ln(denom) / d rate
    return Estimate(R, abs(R) * math.hypot(delta_std / delta, d_rate * rate_std))


@dataclass(frozen=True, eq=False)
class AxisModel:
    """The reduced high-g model of one accelerometer axis (error = output - input).

    reduction : the stepwise reduction; its fits also hold the nuisance columns.
    nuisance : names of the fitted columns that are not model terms: the
        horizontal-misalignment corrections ``"phi:<mount>"`` of the positions
        where this axis is tangential (kept in every fit, never tested).
    not_identifiable : candidate terms of the full model that these mountings
        cannot separate from other terms, the radius or phi_h (`identifiable_terms`);
        they were not fitted.
    scale_instability : relative step-to-step scale instability used in the
        weights (estimated or given).
    """

    axis: str
    reduction: Reduction
    nuisance: tuple[str, ...] = ()
    not_identifiable: tuple[str, ...] = ()
    scale_instability: float = 0.0

    @property
    def fit(self) -> OlsFit:
        return self.reduction.final

    @property
    def _model_columns(self) -> list[int]:
        return [j for j, n in enumerate(self.fit.names) if n not in self.nuisance]

    @property
    def terms(self) -> tuple[str, ...]:
        """Kept model terms (nuisance columns excluded), e.g. ``("const", "a_x", "a_x^2")``."""
        return tuple(self.fit.names[j] for j in self._model_columns)

    @property
    def coef(self) -> np.ndarray:
        """(len(terms),) coefficients of `terms`, m/s^2 per unit of each term."""
        return self.fit.coef[self._model_columns]

    @property
    def std(self) -> np.ndarray:
        """(len(terms),) standard uncertainties of `coef`."""
        return self.fit.std[self._model_columns]

    @property
    def qualified_terms(self) -> tuple[str, ...]:
        """Terms prefixed with the axis, e.g. ``"x:a_x*a_y"``."""
        return tuple(f"{self.axis}:{t}" for t in self.terms)

    def error(self, f: np.ndarray) -> np.ndarray:
        """(N, 3) sensor-axis inputs, m/s^2 -> (N,) modelled error of this axis, m/s^2."""
        return term_values(f, self.terms) @ self.coef


@dataclass(frozen=True, eq=False)
class CentrifugeModel:
    """Result of `solve_centrifuge`.

    axes : per axis the reduced model with F, F_crit, R^2, t values and the removal sequence.
    radius : per mounting position the effective radius used, m.
    radius_raw : per position the estimate from its own near-1 g run, m.
    phi_h : per position the horizontal misalignment, rad, refined over all
        steps together with the model of the tangential axis (used for the inputs).
    phi_h_1g : per position phi_h = atan(a_t / a_r) from the near-1 g run alone.
    zero : per position the zero output (3,), m/s^2.
    """

    axes: dict[str, AxisModel]
    radius: dict[str, Estimate]
    radius_raw: dict[str, Estimate]
    phi_h: dict[str, Estimate]
    phi_h_1g: dict[str, Estimate]
    zero: dict[str, np.ndarray]
    gravity: float
    omega_v: float

    def error(self, f: np.ndarray) -> np.ndarray:
        """(N, 3) inputs -> (N, 3) modelled errors, m/s^2."""
        return np.column_stack([self.axes[a].error(f) for a in AXES])

    def input_force(self, mount: str, rate: np.ndarray | float) -> np.ndarray:
        """Reference input (N, 3) in sensor axes for table rate(s) at a mounting position."""
        a = centripetal_input(self.radius[mount].value, np.asarray(rate, dtype=float), self.omega_v)
        phi = self.phi_h[mount].value
        f_mount = np.column_stack(
            np.broadcast_arrays(a * math.cos(phi), a * math.sin(phi), self.gravity)
        )
        return f_mount @ MOUNTS[mount].T

    def parameters(self) -> dict[str, Estimate]:
        """Kept terms by canonical name (acc.bias.x, acc.scale.x, acc.k2.xy, ...).

        A relative radius error moves the radial input, hence the scale
        factor, one for one: the scale's uncertainty includes the radius's.
        """
        out = {}
        for axis, m in self.axes.items():
            radial = [r for mount, r in self.radius.items() if mount[0] == axis]
            rel = max((r.std / r.value for r in radial), default=0.0)
            for term, c, s in zip(m.terms, m.coef, m.std, strict=True):
                s = math.hypot(s, rel) if term == f"a_{axis}" else s
                out[canonical_name(axis, term)] = Estimate(float(c), float(s))
        return out


def compensate(model: CentrifugeModel, readings: np.ndarray, iterations: int = 8) -> np.ndarray:
    """Invert the high-g model: readings E (N, 3) -> input estimates f (N, 3), m/s^2.

    Solves E = f + e(f) by fixed-point iteration f <- E - e(f); the model's
    slope is ~1e-3, so each pass gains about three digits.
    """
    E = np.atleast_2d(np.asarray(readings, dtype=float))
    if E.shape[1:] != (3,):
        raise ValueError(f"readings must have shape (N, 3), got {E.shape}")
    f = E.copy()
    for _ in range(iterations):
        f = E - model.error(f)
    return f


@dataclass(frozen=True)
class _Means:
    zero: dict[str, tuple[np.ndarray, np.ndarray]]
    one_g: dict[str, RevolutionMean]
    steps: list[tuple[str, float, RevolutionMean]]  # (mount, nominal g, mean)


def _collect(steps: Sequence[CentrifugeStep]) -> _Means:
    by_mount: dict[str, list[CentrifugeStep]] = {m: [] for m in MOUNTS}
    for s in steps:
        by_mount[s.mount].append(s)
    zero, one_g, highs = {}, {}, []
    for mount, recs in by_mount.items():
        if not recs:
            continue
        zeros = [r for r in recs if r.kind == "zero"]
        ones = [r for r in recs if r.kind == "1g"]
        if len(ones) != 1:
            raise ValueError(f"mount {mount}: expected one near-1 g run, got {len(ones)}")
        zero[mount] = zero_output(zeros)
        one_g[mount] = whole_revolution_mean(ones[0].recording)
        highs += [
            (mount, r.nominal_g, whole_revolution_mean(r.recording))
            for r in recs
            if r.kind == "step"
        ]
    if not highs:
        raise ValueError("centrifuge run has no high-g steps")
    return _Means(zero, one_g, highs)


def _geometry(
    means: _Means,
    settings: CentrifugeSettings,
    omega_v: float,
    axes: dict[str, AxisModel] | None,
    phi_fit: dict[str, Estimate] | None,
) -> tuple[dict[str, Estimate], dict[str, Estimate], dict[str, Estimate]]:
    """phi_h and radius per mount from the near-1 g runs (with the current model's nonlinearity).

    The radius uses `phi_fit` (phi_h refined over all steps) once there is one,
    else the 1 g estimate. Returns (phi_h from the 1 g runs, raw radii, radii used).
    """
    g = settings.gravity
    phi_h, raw = {}, {}
    for mount, one in means.one_g.items():
        P = MOUNTS[mount]
        z_mean, z_sem = means.zero[mount]
        d_sensor = one.acc - z_mean
        d_std = np.hypot(one.acc_std, z_sem)
        d_mount = P.T @ d_sensor  # (r, t, u)
        std_mount = np.abs(P.T) @ d_std
        dr, dt = d_mount[0], d_mount[1]
        phi = math.atan(dt / dr)
        phi_std = math.hypot(std_mount[1] * dr, std_mount[0] * dt) / (dr * dr + dt * dt)
        phi_h[mount] = Estimate(phi, phi_std)
        if phi_fit is not None:
            phi = phi_fit[mount].value

        i = int(np.flatnonzero(P[:, 0])[0])  # sensor axis along r
        axis, sign = AXES[i], P[i, 0]
        scale = settings.scale_1g.get(axis, 0.0)
        a = dr  # first guess: all of the radial change is input
        for _ in range(3 if axes else 1):
            corr = 0.0
            if axes:
                # Modelled error change at 1 g beyond the 1 g linear gain.
                m = axes[axis]
                f1 = np.array([a * math.cos(phi), a * math.sin(phi), g]) @ P.T
                f0 = np.array([0.0, 0.0, g]) @ P.T
                lin = m.fit.coefficient(f"a_{axis}") if f"a_{axis}" in m.terms else 0.0
                corr = float(m.error(f1)[0] - m.error(f0)[0]) - lin * (f1[i] - f0[i])
            a = sign * (d_sensor[i] - corr) / ((1.0 + scale) * math.cos(phi))
        # The 1 g record has its own scale-factor draw like every step
        # (`step_weights`), once the model has estimated it.
        kappa = axes[axis].scale_instability if axes else 0.0
        a_std = math.hypot(d_std[i], kappa * d_sensor[i]) / ((1.0 + scale) * math.cos(phi))
        raw[mount] = effective_radius(a, a_std, one.rate, one.rate_std, omega_v)

    if settings.common_radius:
        v = np.array([e.value for e in raw.values()])
        w = 1.0 / np.array([e.std for e in raw.values()]) ** 2
        pooled = Estimate(float((w * v).sum() / w.sum()), float(1.0 / math.sqrt(w.sum())))
        radius = {m: pooled for m in raw}
    else:
        radius = dict(raw)
    return phi_h, raw, radius


def _regression(
    means: _Means, radius: dict[str, Estimate], phi_h: dict[str, Estimate], g: float, omega_v: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inputs f (n, 3) and outputs E (n, 3) of all high-g steps in sensor axes,
    and d f / d phi_h (n, 3) of each step (the phi_h nuisance columns)."""
    f, E, dphi = [], [], []
    for mount, _, mean in means.steps:
        a = centripetal_input(radius[mount].value, mean.rate, omega_v)
        phi = phi_h[mount].value
        P = MOUNTS[mount]
        f.append(P @ np.array([a * math.cos(phi), a * math.sin(phi), g]))
        dphi.append(P @ np.array([-a * math.sin(phi), a * math.cos(phi), 0.0]))
        E.append(mean.acc)
    return np.array(f), np.array(E), np.array(dphi)


def _instability_of(settings: CentrifugeSettings, axis: str) -> float | None:
    value = settings.scale_instability
    if isinstance(value, Mapping):
        if axis not in value:
            raise ValueError(f"settings.scale_instability: no value for axis {axis!r}")
        return float(value[axis])
    return value


def step_weights(
    X: np.ndarray,
    y: np.ndarray,
    names: Sequence[str],
    sem: np.ndarray,
    f_axis: np.ndarray,
    scale_instability: float | None = None,
) -> tuple[np.ndarray, float]:
    """Weights 1 / variance of the high-g steps of one axis, and the instability used.

    Variance model of a step mean: var = sem^2 + (kappa f)^2, white noise of
    the mean plus a relative scale-factor error kappa drawn anew per step
    (temperature, in-run drift), which is why the paper's residuals grow with g.
    Unweighted least squares would let that growth pass for cubic or quadratic
    terms. kappa, if not given, is the Paule-Mandel estimate: the value at which
    the full model's weighted residual sum equals its degrees of freedom
    (kappa = 0 when white noise already explains the residuals).

    Parameters
    ----------
    X, names : full design of the axis (without the constant, which is added).
    y : (n,) output - input, m/s^2.
    sem : (n,) standard error of each step mean, m/s^2.
    f_axis : (n,) the axis's input at each step, m/s^2.
    scale_instability : kappa, or None to estimate it.

    Returns
    -------
    (weights (n,), kappa)
    """
    if np.any(sem <= 0.0):
        raise ValueError("step standard errors must be positive (a constant output record?)")

    def weights(kappa: float) -> np.ndarray:
        return 1.0 / (sem**2 + (kappa * f_axis) ** 2)

    if scale_instability is not None:
        return weights(scale_instability), float(scale_instability)

    def excess(log_kappa: float) -> float:
        fit = fit_ols(X, y, names, add_constant=True, weights=weights(math.exp(log_kappa)))
        return fit.Q / fit.dof - 1.0

    fit0 = fit_ols(X, y, names, add_constant=True, weights=weights(0.0))
    if fit0.Q / fit0.dof <= 1.0:
        return weights(0.0), 0.0
    # excess falls monotonically with kappa; bracket it between 1e-9 and 1 (all
    # of a 1e-9 .. 100 % gain change), beyond which the data make no sense.
    lo, hi = math.log(1e-9), 0.0
    if excess(lo) <= 0.0:
        return weights(1e-9), 1e-9
    if excess(hi) > 0.0:
        raise ValueError("step residuals exceed 100 % scale instability: the model does not fit")
    kappa = math.exp(optimize.brentq(excess, lo, hi, xtol=1e-3))
    return weights(kappa), kappa


def _nuisance_name(mount: str) -> str:
    return f"phi:{mount}"


def _tangential_mounts(axis: str, mounts: Sequence[str]) -> list[str]:
    """The positions (of those given) in which `axis` lies along the tangential direction."""
    i = AXIS_INDEX[axis]
    return [m for m in mounts if MOUNTS[m][i, 1] != 0.0]


def identifiable_terms(
    axis: str,
    mounts: Sequence[str],
    g_levels: Sequence[float],
    common_radius: bool = True,
    gravity: float = STANDARD_GRAVITY,
    tol: float = 1e-6,
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Split the full model of `axis` into terms these mountings can and cannot identify.

    The analysis uses the ideal design (phi_h = 0, one row per position and
    step) together with the unknowns the procedure estimates from the same
    data: one phi_h per position where `axis` is tangential, and the
    effective radius (one, or one per position) of the positions where `axis`
    is radial. Candidate terms are taken in `full_terms` order (lower orders
    first) and a term is identifiable if its column adds a new direction to
    the span of the constant, those unknowns and the terms already accepted.

    Why terms drop out: at phi_h = 0 every position has exactly two non-zero
    inputs, the radial one and g along up. A product f_j f_k is therefore non-zero
    only where it equals g times a radial input, which is a radius change
    (own axis x up axis), a phi_h change (radial x up, seen by the
    tangential axis) or a linear term minus a position-group offset. Only the
    horizontal misalignment itself (~1e-2 rad) would separate them, which is
    no basis for a model.

    Parameters
    ----------
    axis : "x", "y" or "z".
    mounts : positions in the run (keys of `MOUNTS`).
    g_levels : step inputs in g.
    common_radius : one radius for all positions (else one per position).
    gravity : m/s^2.
    tol : a column whose unit-norm residual after projection on the span is
        below this is dependent (double-precision rounding is ~1e-13).

    Returns
    -------
    (identifiable, not identifiable) : term names, each in `full_terms` order.
    """
    i = AXIS_INDEX[axis]
    mounts = list(mounts)
    tangential = _tangential_mounts(axis, mounts)
    radial = [m for m in mounts if MOUNTS[m][i, 0] != 0.0]
    radius_groups = [radial] if common_radius else [[m] for m in radial]
    rows, dphi, dradius = [], [], []
    for m in mounts:
        P = MOUNTS[m]
        for n_g in g_levels:
            a = n_g * gravity
            rows.append(P @ np.array([a, 0.0, gravity]))
            # d f_axis / d phi_h and d f_axis / d ln R of this row, per unknown
            dphi.append([P[i, 1] * a * (m == t) for t in tangential])
            dradius.append([P[i, 0] * a * (m in group) for group in radius_groups])
    f = np.array(rows)
    base = [np.ones(len(f)), *np.array(dphi).T, *np.array(dradius).T]
    basis = np.zeros((len(f), 0))

    def residual(col: np.ndarray) -> np.ndarray:
        col = col / np.linalg.norm(col)
        return col - basis @ (basis.T @ col)

    for col in base:
        if np.linalg.norm(col) == 0.0:
            continue
        r = residual(col)
        if np.linalg.norm(r) > tol:
            basis = np.column_stack([basis, r / np.linalg.norm(r)])
    keep, drop = [], []
    for name in full_terms(axis):
        col = term_values(f, [name])[:, 0]
        r = residual(col) if np.linalg.norm(col) > 0 else col
        if np.linalg.norm(r) > tol:
            basis = np.column_stack([basis, r / np.linalg.norm(r)])
            keep.append(name)
        else:
            drop.append(name)
    return tuple(keep), tuple(drop)


def solve_centrifuge(
    steps: Sequence[CentrifugeStep], settings: CentrifugeSettings
) -> tuple[CentrifugeModel, StepRecord]:
    """Process a centrifuge run into a reduced high-g model per accelerometer axis.

    Parameters
    ----------
    steps : all records of the run (zero, near-1 g and high-g steps of each position).
    settings : CentrifugeSettings.

    Returns
    -------
    (CentrifugeModel, StepRecord)
    """
    omega_v = vertical_earth_rate(settings.latitude_deg)
    means = _collect(steps)
    mounts = [m for m in MOUNTS if m in means.one_g]
    g_levels = sorted({n_g for _, n_g, _ in means.steps})
    candidates = {
        a: identifiable_terms(a, mounts, g_levels, settings.common_radius, settings.gravity)
        for a in AXES
    }
    step_mounts = np.array([m for m, _, _ in means.steps])
    sem = np.array([mean.acc_std for _, _, mean in means.steps])
    axes: dict[str, AxisModel] | None = None
    phi_fit: dict[str, Estimate] | None = None
    for _ in range(max(1, settings.iterations)):
        phi_1g, raw, radius = _geometry(means, settings, omega_v, axes, phi_fit)
        phi_used = phi_fit or phi_1g
        f, E, dphi = _regression(means, radius, phi_used, settings.gravity, omega_v)
        axes, phi_fit = {}, {}
        for i, axis in enumerate(AXES):
            terms, dropped = candidates[axis]
            # phi_h of the positions where this axis is tangential is refined
            # over all steps with the model: the 1 g run alone leaves an error
            # that the high steps amplify 20-fold.
            tangential = _tangential_mounts(axis, mounts)
            nuisance = tuple(_nuisance_name(m) for m in tangential)
            X = np.column_stack(
                [np.where(step_mounts == m, dphi[:, i], 0.0) for m in tangential]
                + [term_values(f, terms)]
            )
            names = (*nuisance, *terms)
            y = E[:, i] - f[:, i]
            w, kappa = step_weights(
                X, y, names, sem[:, i], f[:, i], _instability_of(settings, axis)
            )
            red = stepwise_reduce(
                X, y, names, settings.alpha, keep=(CONST, *nuisance), add_constant=True, weights=w
            )
            axes[axis] = AxisModel(axis, red, nuisance, dropped, kappa)
            for m, name in zip(tangential, nuisance, strict=True):
                j = red.final.names.index(name)
                phi_fit[m] = Estimate(
                    phi_used[m].value + float(red.final.coef[j]), float(red.final.std[j])
                )
    model = CentrifugeModel(
        axes=axes,
        radius=radius,
        radius_raw=raw,
        phi_h=phi_fit,
        phi_h_1g=phi_1g,
        zero={m: z[0] for m, z in means.zero.items()},
        gravity=settings.gravity,
        omega_v=omega_v,
    )
    record = StepRecord(
        name="centrifuge",
        settings={
            "latitude_deg": settings.latitude_deg,
            "gravity": settings.gravity,
            "alpha": settings.alpha,
            "scale_1g": dict(settings.scale_1g),
            "common_radius": settings.common_radius,
            "iterations": settings.iterations,
        },
        statistics={
            "steps": len(means.steps),
            "mounts": sorted(means.one_g),
            "radius_m": {m: r.value for m, r in radius.items()},
            "phi_h_rad": {m: p.value for m, p in phi_fit.items()},
            **{f"{a}.not_identifiable": list(m.not_identifiable) for a, m in axes.items()},
            **{f"{a}.terms": list(m.terms) for a, m in axes.items()},
            **{f"{a}.removed": list(m.reduction.removed) for a, m in axes.items()},
            **{f"{a}.F": m.fit.F for a, m in axes.items()},
            **{f"{a}.F_crit": m.fit.F_crit for a, m in axes.items()},
            **{f"{a}.r2": m.fit.r2 for a, m in axes.items()},
        },
    )
    return model, record


@dataclass(frozen=True)
class AxisValidation:
    """Errors (reading - reference input) of one axis over a run's high-g steps, m/s^2."""

    rms_before: float
    max_before: float
    rms_after: float
    max_after: float

    @property
    def rms_reduction(self) -> float:
        """Fraction of the RMS error removed by compensation (0.83 = 83 %)."""
        return 1.0 - self.rms_after / self.rms_before


def validation_errors(
    model: CentrifugeModel, repeat_run: Sequence[CentrifugeStep]
) -> dict[str, AxisValidation]:
    """RMS and maximum error per axis before and after compensation on a repeat run.

    The repeat run's high-g steps are whole-revolution averaged; the reference
    input of each comes from its table rate with the model's radius and phi_h
    (same fixture). Errors are taken over every step of every position.
    """
    rows = [(s.mount, whole_revolution_mean(s.recording)) for s in repeat_run if s.kind == "step"]
    if not rows:
        raise ValueError("repeat run has no high-g steps to validate on")
    missing = {m for m, _ in rows} - set(model.radius)
    if missing:
        raise ValueError(f"repeat run has positions {sorted(missing)} the model was not solved for")
    f = np.vstack([model.input_force(m, r.rate) for m, r in rows])
    E = np.array([r.acc for _, r in rows])
    before = E - f
    after = compensate(model, E) - f
    return {
        a: AxisValidation(
            rms_before=float(np.sqrt(np.mean(before[:, i] ** 2))),
            max_before=float(np.max(np.abs(before[:, i]))),
            rms_after=float(np.sqrt(np.mean(after[:, i] ** 2))),
            max_after=float(np.max(np.abs(after[:, i]))),
        )
        for i, a in enumerate(AXES)
    }


# --- the generic procedure shape: labelled segments -> Calibration ---------------

_LABEL = re.compile(r"^([xyz])([pm])_(?:zero_(\d+(?:\.\d+)?)|1g|step_(\d+(?:\.\d+)?)g)$")
SETTINGS_KEYS = (
    "latitude_deg",
    "alpha",
    "scale_1g",
    "common_radius",
    "iterations",
    "scale_instability",
)


def step_label(step: CentrifugeStep) -> str:
    """The segment label of a step: "xp_zero_90", "xm_1g", "zp_step_10g"."""
    mount = step.mount[0] + ("p" if step.mount[1] == "+" else "m")
    if step.kind == "zero":
        return f"{mount}_zero_{step.table_position_deg:g}"
    return f"{mount}_1g" if step.kind == "1g" else f"{mount}_step_{step.nominal_g:g}g"


def steps_from_segments(segments: Mapping[str, Recording]) -> list[CentrifugeStep]:
    """Centrifuge steps from labelled segments.

    Labels: ``<axis><p|m>_zero_<table deg>`` (static zero output at that table
    position), ``<axis><p|m>_1g`` (the near-1 g radius run) and
    ``<axis><p|m>_step_<n>g`` (a high-g step); p = the axis points to the
    table axis, m = away. Every recording needs the reference channels
    ``table_angle`` (rad) and ``table_rate`` (rad/s, signed about up).
    """
    steps = []
    for label, rec in segments.items():
        m = _LABEL.match(label)
        if not m:
            raise ValueError(
                f"segment {label!r}: not a centrifuge label; expected e.g. 'xp_zero_90', "
                "'xm_1g' or 'zp_step_10g' (<axis><p|m>_zero_<deg> | _1g | _step_<n>g)"
            )
        mount = m[1] + ("+" if m[2] == "p" else "-")
        if m[3] is not None:
            steps.append(CentrifugeStep(mount, "zero", rec, 0.0, float(m[3])))
        elif m[4] is not None:
            steps.append(CentrifugeStep(mount, "step", rec, float(m[4])))
        else:
            steps.append(CentrifugeStep(mount, "1g", rec, 1.0))
    return steps


def settings_from_dict(settings: Mapping[str, object], gravity: float) -> CentrifugeSettings:
    """CentrifugeSettings from a manifest's procedure settings (keys `SETTINGS_KEYS`).

    ``latitude_deg`` is required; ``scale_1g`` is a table axis -> K - 1;
    ``scale_instability`` a number, a table axis -> number, or absent (estimate).
    Other keys (e.g. preprocessing settings of the same run) are ignored.
    """
    s = {k: settings[k] for k in SETTINGS_KEYS if settings.get(k) is not None}
    if "latitude_deg" not in s:
        raise ValueError(
            "centrifuge: settings.latitude_deg is required (site latitude, deg: Earth rate)"
        )
    scale = s.get("scale_1g", {})
    if not isinstance(scale, Mapping) or set(scale) - set(AXES):
        raise ValueError(
            f"centrifuge: settings.scale_1g must map axes x, y, z to K - 1, got {scale!r}"
        )
    try:
        return CentrifugeSettings(
            latitude_deg=float(s["latitude_deg"]),
            gravity=gravity,
            alpha=float(s.get("alpha", 0.05)),
            scale_1g={a: float(v) for a, v in scale.items()},
            common_radius=bool(s.get("common_radius", True)),
            iterations=int(s.get("iterations", 4)),
            scale_instability=s.get("scale_instability"),
        )
    except (TypeError, ValueError) as exc:
        raise ValueError(f"centrifuge: bad settings {s}: {exc}") from None


def solve_centrifuge_segments(
    segments: dict[str, Recording], gravity: float, settings: dict | None = None
) -> Calibration:
    """The centrifuge as a procedure: labelled segments -> Calibration.

    Parameters
    ----------
    segments : label -> Recording, labels as `steps_from_segments`.
    gravity : local gravity, m/s^2.
    settings : as `settings_from_dict`.

    Returns
    -------
    Calibration with the kept terms by canonical name (acc.bias.x, acc.scale.x,
    acc.k2.x, acc.k2.xy, acc.misalign.xy, ...), the residual of every high-g
    step after compensation, and in `info` the geometry and per axis F,
    F_crit, R^2, t values, removal sequence and the terms not identifiable.
    """
    cs = settings_from_dict(settings or {}, gravity)
    model, record = solve_centrifuge(steps_from_segments(segments), cs)
    cal = Calibration(procedure="centrifuge", gravity=gravity)
    for name, est in model.parameters().items():
        cal.add(name, est.value, est.std)
    for label, rec in segments.items():
        step = steps_from_segments({label: rec})[0]
        if step.kind != "step":
            continue
        mean = whole_revolution_mean(rec)
        f = model.input_force(step.mount, mean.rate)[0]
        r = compensate(model, mean.acc[None, :])[0] - f
        cal.residuals.append(
            SegmentResidual(
                segment=label,
                sensor="acc",
                mean=tuple(float(v) for v in r),
                std=tuple(float(v) for v in rec.acc.std(axis=0, ddof=1)),
                n=len(rec),
            )
        )
    cal.info.update(model_summary(model))
    cal.info["step_record"] = {"name": record.name, "settings": record.settings}
    return cal


def model_summary(model: CentrifugeModel) -> dict:
    """JSON-ready facts of a solved model: geometry and per-axis statistics."""

    def est(e: Estimate) -> list[float]:
        return [e.value, e.std]

    axes = {}
    for axis, m in model.axes.items():
        fit, full = m.fit, m.reduction.full
        axes[axis] = {
            "terms": list(m.terms),
            "coef": [float(c) for c in m.coef],
            "std": [float(s) for s in m.std],
            "t": {n: float(t) for n, t in zip(fit.names, fit.t, strict=True)},
            "F": fit.F,
            "F_crit": fit.F_crit,
            "r2": fit.r2,
            "t_crit": fit.t_crit,
            "n": fit.n,
            "k": fit.k,
            "full_F": full.F,
            "full_F_crit": full.F_crit,
            "full_r2": full.r2,
            "removed": [{"term": s.removed, "t": s.t, "p": s.p} for s in m.reduction.steps],
            "not_identifiable": list(m.not_identifiable),
            "nuisance": list(m.nuisance),
            "scale_instability": m.scale_instability,
        }
    return {
        "radius_m": {k: est(v) for k, v in model.radius.items()},
        "radius_1g_m": {k: est(v) for k, v in model.radius_raw.items()},
        "phi_h_rad": {k: est(v) for k, v in model.phi_h.items()},
        "phi_h_1g_rad": {k: est(v) for k, v in model.phi_h_1g.items()},
        "omega_v": model.omega_v,
        "alpha": next(iter(model.axes.values())).fit.alpha,
        "axes": axes,
    }
