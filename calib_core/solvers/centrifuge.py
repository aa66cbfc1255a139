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

(10 regressors + constant: with 6 positions x 10 steps, n = 60, F(10, 49) as
in the paper), fitted by least squares and reduced by `stepwise_reduce`.

Limits the data impose (say so to users):
- R and the radial axis's 1 g gain cannot be separated by a centrifuge; the
  1 g scale error of each axis (``acc.scale.i`` from a static calibration) is an
  input. A relative radius error eps shows up as -eps/g in the product of
  the axis's own input with the vertical input (x: a_x*a_z, y: a_x*a_y,
  z: a_y*a_z): keep that in mind when that term survives the reduction.
- A linear coupling of the tangential axis to the radial input is, at one
  mounting, indistinguishable from phi_h and is absorbed into it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from calib_core.calibration import StepRecord
from calib_core.earth import EARTH_RATE
from calib_core.params import AXES, AXIS_INDEX
from calib_core.recording import Recording
from calib_core.significance import CONST, OlsFit, Reduction, stepwise_reduce
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


# Canonical names for the terms that have one (calib_core.params); the other
# cross-axis high-g terms live only in this module's result types.
def canonical_name(axis: str, term: str) -> str | None:
    """Canonical parameter name of `term` in the model of `axis`, or None if it has none."""
    if term == CONST:
        return f"acc.bias.{axis}"
    m = _TERM.match(term)
    if not m or m[3]:
        return None
    if m[1] == axis:
        return {None: f"acc.scale.{axis}", "2": f"acc.k2.{axis}", "3": f"acc.k3.{axis}"}[m[2]]
    return None if m[2] else f"acc.misalign.{axis}{m[1]}"


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
    iterations : radius / model passes; later passes remove the model's
        even-order terms at 1 g from the radius estimate.
    """

    latitude_deg: float
    gravity: float = STANDARD_GRAVITY
    alpha: float = 0.05
    scale_1g: Mapping[str, float] = field(default_factory=dict)
    common_radius: bool = True
    iterations: int = 3


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
    """The reduced high-g model of one accelerometer axis (error = output - input)."""

    axis: str
    reduction: Reduction

    @property
    def fit(self) -> OlsFit:
        return self.reduction.final

    @property
    def terms(self) -> tuple[str, ...]:
        return self.fit.names

    @property
    def qualified_terms(self) -> tuple[str, ...]:
        """Terms prefixed with the axis, e.g. ``"x:a_x*a_y"``."""
        return tuple(f"{self.axis}:{t}" for t in self.terms)

    def error(self, f: np.ndarray) -> np.ndarray:
        """(N, 3) sensor-axis inputs, m/s^2 -> (N,) modelled error of this axis, m/s^2."""
        return term_values(f, self.terms) @ self.fit.coef


@dataclass(frozen=True, eq=False)
class CentrifugeModel:
    """Result of `solve_centrifuge`.

    axes : per axis the reduced model with F, F_crit, R^2, t values and the removal sequence.
    radius : per mounting position the effective radius used, m.
    radius_raw : per position the estimate from its own near-1 g run, m.
    phi_h : per position the horizontal misalignment, rad.
    zero : per position the zero output (3,), m/s^2.
    """

    axes: dict[str, AxisModel]
    radius: dict[str, Estimate]
    radius_raw: dict[str, Estimate]
    phi_h: dict[str, Estimate]
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
        """Kept terms that have canonical names (bias, scale, k2, k3, misalign)."""
        out = {}
        for axis, m in self.axes.items():
            for term, c, s in zip(m.terms, m.fit.coef, m.fit.std, strict=True):
                name = canonical_name(axis, term)
                if name:
                    out[name] = Estimate(float(c), float(s))
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
    means: _Means, settings: CentrifugeSettings, omega_v: float, axes: dict[str, AxisModel] | None
) -> tuple[dict[str, Estimate], dict[str, Estimate], dict[str, Estimate]]:
    """phi_h and radius per mount from the near-1 g runs (with the current model's nonlinearity)."""
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
        a_std = d_std[i] / ((1.0 + scale) * math.cos(phi))
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
) -> tuple[np.ndarray, np.ndarray]:
    """Inputs f (n, 3) and outputs E (n, 3) of all high-g steps, in sensor axes."""
    f, E = [], []
    for mount, _, mean in means.steps:
        a = centripetal_input(radius[mount].value, mean.rate, omega_v)
        phi = phi_h[mount].value
        f.append(MOUNTS[mount] @ np.array([a * math.cos(phi), a * math.sin(phi), g]))
        E.append(mean.acc)
    return np.array(f), np.array(E)


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
    axes: dict[str, AxisModel] | None = None
    for _ in range(max(1, settings.iterations)):
        phi_h, raw, radius = _geometry(means, settings, omega_v, axes)
        f, E = _regression(means, radius, phi_h, settings.gravity, omega_v)
        axes = {}
        for i, axis in enumerate(AXES):
            names = full_terms(axis)
            red = stepwise_reduce(
                term_values(f, names), E[:, i] - f[:, i], names, settings.alpha, add_constant=True
            )
            axes[axis] = AxisModel(axis, red)
    assert axes is not None
    model = CentrifugeModel(
        axes=axes,
        radius=radius,
        radius_raw=raw,
        phi_h=phi_h,
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
            "phi_h_rad": {m: p.value for m, p in phi_h.items()},
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
