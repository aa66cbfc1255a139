"""Centrifuge procedure, the science: the high-g fit with significance-based reduction.

Procedure (docs/methods.md 2.8). The IMU is mounted on the centrifuge arm in six
positions, each accelerometer axis once pointing to the table axis (``+``)
and once away from it (``-``). Per mounting position:

1. zero output: static records at table positions 0/90/180/270 deg, averaged,
   so a tilt of the table axis (which puts g*tilt on the horizontal axes with
   the table angle's phase) cancels; with the same records after the run, the
   zero before and the zero after averaged (`zero_mean`), as the paper does;
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
- R and the radial axis's gain are hard to separate on a centrifuge; the
  1 g scale error of each axis (``acc.scale.i`` from a static calibration) is
  an input to the radius, and the remaining radius error goes one for one
  into the fitted scale (its uncertainty includes the radius's). By default
  (`radius_from = "all_records"`, docs/methods.md 2.8) the radius is refined
  with every axis's model over all records, each axis's linear term held at
  its 1 g scale, and the near-1 g runs and zero outputs are rows of the fits;
  the paper's radius from the near-1 g runs alone is ``"near_1g"``.
- Products of inputs need mountings with two non-zero horizontal inputs
  (e.g. the axis at 45 deg to the arm), which this procedure does not have.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from calib_core.calibration import StepRecord
from calib_core.params import AXES, AXIS_INDEX
from calib_core.significance import CONST, fit_ols, stepwise_reduce
from calib_core.solvers.centrifuge_model import (
    MOUNTS,
    AxisModel,
    CentrifugeModel,
    CentrifugeSettings,
    CentrifugeStep,
    Estimate,
    RevolutionMean,
    centripetal_input,
    compensate,
    effective_radius,
    full_terms,
    term_values,
    vertical_earth_rate,
    whole_revolution_mean,
    zero_output,
)
from calib_core.solvers.centrifuge_plan import zero_shift
from calib_core.units import STANDARD_GRAVITY


@dataclass(frozen=True)
class _Means:
    zero: dict[str, tuple[np.ndarray, np.ndarray]]  # used: before and after averaged
    zero_before: dict[str, tuple[np.ndarray, np.ndarray]]
    zero_after: dict[str, tuple[np.ndarray, np.ndarray]]
    one_g: dict[str, RevolutionMean]
    steps: list[tuple[str, float, RevolutionMean]]  # (mount, nominal g, mean)


def _collect(steps: Sequence[CentrifugeStep]) -> _Means:
    by_mount: dict[str, list[CentrifugeStep]] = {m: [] for m in MOUNTS}
    for s in steps:
        by_mount[s.mount].append(s)
    zero, zero_before, zero_after, one_g, highs = {}, {}, {}, {}, []
    for mount, recs in by_mount.items():
        if not recs:
            continue
        zeros = [r for r in recs if r.kind == "zero"]
        ones = [r for r in recs if r.kind == "1g"]
        if len(ones) != 1:
            raise ValueError(f"mount {mount}: expected one near-1 g run, got {len(ones)}")
        zero[mount] = zero_before[mount] = zero_output(zeros)
        afters = [r for r in recs if r.kind == "zero_after"]
        if afters:  # the paper averages the zero output before and after the run
            zero_after[mount] = zero_output(afters)
            zero[mount] = zero_mean(zero_before[mount], zero_after[mount])
        one_g[mount] = whole_revolution_mean(ones[0].recording)
        highs += [
            (mount, r.nominal_g, whole_revolution_mean(r.recording))
            for r in recs
            if r.kind == "step"
        ]
    if not highs:
        raise ValueError("centrifuge run has no high-g steps")
    return _Means(zero, zero_before, zero_after, one_g, highs)


def zero_mean(
    before: tuple[np.ndarray, np.ndarray], after: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """The zero output of a mounting position as the paper takes it: the four-position zero
    before and after the run averaged; (mean (3,), standard error (3,)), m/s^2."""
    (b, ub), (a, ua) = before, after
    return (b + a) / 2.0, np.hypot(ub, ua) / 2.0


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


Rows = list[tuple[str, float, RevolutionMean]]  # (mount, nominal g, mean) of each fitted row


def _rows(means: _Means, settings: CentrifugeSettings) -> Rows:
    """The records each axis's model is fitted to: the high-g steps; with the radius from
    all records (`radius_from = "all_records"`) also each position's near-1 g run and its
    zero output (the four table positions' mean, input g along up alone), which the
    near-1 g radius uses up instead. A zero output measured before and after the run is
    their mean, and the zero moved between them in a way not known: its standard
    uncertainty adds |after - before| / (2 sqrt 3) (a rectangular distribution over the
    change), so a zero that moved does not pass for a model term."""
    if settings.radius_from == "near_1g":
        return list(means.steps)
    zeros = []
    for m, (z, z_sem) in means.zero.items():
        if m in means.zero_after:
            moved = means.zero_after[m][0] - means.zero_before[m][0]
            z_sem = np.hypot(z_sem, np.abs(moved) / (2.0 * math.sqrt(3.0)))
        zeros.append((m, 0.0, RevolutionMean(z, z_sem, 0.0, 0.0, 0, 0)))
    return [*zeros, *((m, 1.0, one) for m, one in means.one_g.items()), *means.steps]


def _regression(
    rows: Rows, radius: dict[str, Estimate], phi_h: dict[str, Estimate], g: float, omega_v: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inputs f (n, 3) and outputs E (n, 3) of the fitted rows in sensor axes,
    and d f / d phi_h (n, 3) of each row (the phi_h nuisance columns)."""
    f, E, dphi = [], [], []
    for mount, _, mean in rows:
        a = centripetal_input(radius[mount].value, mean.rate, omega_v)
        phi = phi_h[mount].value
        P = MOUNTS[mount]
        f.append(P @ np.array([a * math.cos(phi), a * math.sin(phi), g]))
        dphi.append(P @ np.array([-a * math.sin(phi), a * math.cos(phi), 0.0]))
        E.append(mean.acc)
    return np.array(f), np.array(E), np.array(dphi)


@dataclass(frozen=True)
class FittedRows:
    """The rows of the fit and what places their inputs: the horizontal phi_h of each
    position, the settings (gravity, radius groups, 1 g scales) and the vertical Earth
    rate omega_v, rad/s; `regression(radius)` gives their inputs at a radius."""

    rows: Rows
    phi_h: dict[str, Estimate]
    settings: CentrifugeSettings
    omega_v: float

    def regression(self, radius: dict[str, Estimate]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`_regression` of these rows at `radius` (m per position)."""
        return _regression(self.rows, radius, self.phi_h, self.settings.gravity, self.omega_v)


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
    from scipy import optimize  # slow to import: only where a centrifuge run is solved

    kappa = math.exp(optimize.brentq(excess, lo, hi, xtol=1e-3))
    return weights(kappa), kappa


_PHI = "phi:"


def _nuisance_name(mount: str) -> str:
    return f"{_PHI}{mount}"


def _columns(
    names: Sequence[str], i: int, step_mounts: np.ndarray, f: np.ndarray, dphi: np.ndarray
) -> np.ndarray:
    """Design columns of axis i for `names`: the phi_h nuisance of a position (its rows'
    d f_i / d phi_h, zero elsewhere) or a model term of the inputs f (steps, 3)."""
    cols = [
        np.where(step_mounts == n[len(_PHI) :], dphi[:, i], 0.0)
        if n.startswith(_PHI)
        else term_values(f, [n])[:, 0]
        for n in names
        if n != CONST
    ]
    return np.column_stack(cols) if cols else np.empty((len(f), 0))


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
    rows = _rows(means, settings)
    mounts = [m for m in MOUNTS if m in means.one_g]
    g_levels = sorted({n_g for _, n_g, _ in rows})
    candidates = {
        a: identifiable_terms(a, mounts, g_levels, settings.common_radius, settings.gravity)
        for a in AXES
    }
    step_mounts = np.array([m for m, _, _ in rows])
    sem = np.array([mean.acc_std for _, _, mean in rows])
    axes: dict[str, AxisModel] | None = None
    phi_fit: dict[str, Estimate] | None = None
    joint: dict[str, Estimate] | None = None
    for _ in range(max(1, settings.iterations)):
        phi_1g, raw, radius = _geometry(means, settings, omega_v, axes, phi_fit)
        phi_used = phi_fit or phi_1g
        fitted = FittedRows(rows, phi_used, settings, omega_v)
        if axes and settings.radius_from == "all_records":
            radius = joint = _joint_radius(axes, fitted, joint or radius)
        f, E, dphi = fitted.regression(radius)
        axes, phi_fit = {}, {}
        for i, axis in enumerate(AXES):
            axes[axis] = _fit_axis(
                axis, i, candidates[axis], mounts, step_mounts, f, E, dphi, sem, settings
            )
            final = axes[axis].reduction.final
            for m, name in zip(_tangential_mounts(axis, mounts), axes[axis].nuisance, strict=True):
                j = final.names.index(name)
                phi_fit[m] = Estimate(phi_used[m].value + float(final.coef[j]), float(final.std[j]))
    axes = _with_radius_covariance(axes, fitted, radius, sem)
    model = CentrifugeModel(
        axes=axes,
        radius=radius,
        radius_raw=raw,
        phi_h=phi_fit,
        phi_h_1g=phi_1g,
        zero={m: z[0] for m, z in means.zero.items()},
        gravity=settings.gravity,
        omega_v=omega_v,
        zero_shift={
            m: zero_shift(m, means.zero_before[m], after, settings.zero_shift_limit)
            for m, after in means.zero_after.items()
        },
    )
    return model, _step_record(settings, means, model)


def _radius_groups(radius: dict[str, Estimate], common: bool) -> list[list[str]]:
    """The positions that share one radius: all of them for a common radius, else each."""
    return [list(radius)] if common else [[m] for m in radius]


def _scaled(
    radius: dict[str, Estimate], groups: list[list[str]], factors: Sequence[float]
) -> dict[str, Estimate]:
    """The radii with each group's multiplied by its factor (uncertainties kept)."""
    return {
        m: Estimate(radius[m].value * f, radius[m].std)
        for g, f in zip(groups, factors, strict=True)
        for m in g
    }


def _with_radius_covariance(
    axes: dict[str, AxisModel],
    fitted: FittedRows,
    radius: dict[str, Estimate],
    sem: np.ndarray,
    step: float = 1e-5,
) -> dict[str, AxisModel]:
    """The axes' models with the covariance the effective radius adds (`AxisModel.radius_cov`).

    With `radius_from = "near_1g"` the radius comes from the near-1 g runs and the zero
    records, outside the fitted steps; with "all_records" from the same rows as the
    models (`_joint_radius`), some 25 times more precise, its small uncertainty added the
    same way (its correlation with the coefficients left out). Every input of a radial
    axis is proportional to the radius: a relative error
    eps moves the fitted scale by about -eps and, because the scale must also explain
    the up axis's input g, the bias by about eps g (as large as the bias's own noise at
    a 1e-4 radius). Each final model is refitted (its terms and weights fixed) with the
    radii of a group (all positions for a common radius, else each position) scaled by
    1 +- `step`; d coef / d ln R times the radius's relative uncertainty adds
    s s^T (u_R / R)^2, the groups' radii being independent.
    """
    groups = _radius_groups(radius, fitted.settings.common_radius)
    step_mounts = np.array([m for m, _, _ in fitted.rows])
    f, E, dphi = fitted.regression(radius)
    out = {}
    for i, axis in enumerate(AXES):
        m = axes[axis]
        names = [n for n in m.fit.names if n != CONST]
        X = _columns(names, i, step_mounts, f, dphi)
        w, _ = step_weights(X, E[:, i] - f[:, i], names, sem[:, i], f[:, i], m.scale_instability)
        cov = np.zeros_like(m.fit.cov)
        for group in groups:
            coefs = []
            for sign in (1.0, -1.0):
                factors = [1.0 + sign * step if other is group else 1.0 for other in groups]
                scaled = _scaled(radius, groups, factors)
                fs, Es, dphis = fitted.regression(scaled)
                X = _columns(names, i, step_mounts, fs, dphis)
                fit = fit_ols(X, Es[:, i] - fs[:, i], names, add_constant=True, weights=w)
                if fit.names != m.fit.names:
                    raise AssertionError(f"refit columns {fit.names} != {m.fit.names}")
                coefs.append(fit.coef)
            sens = (coefs[0] - coefs[1]) / (2.0 * step)
            rel = radius[group[0]].std / radius[group[0]].value
            cov += np.outer(sens, sens) * rel**2
        out[axis] = replace(m, radius_cov=cov)
    return out


def _joint_radius(
    axes: dict[str, AxisModel],
    fitted: FittedRows,
    radius: dict[str, Estimate],
    rounds: int = 3,
    step: float = 1e-6,
) -> dict[str, Estimate]:
    """The effective radius refined with every axis's model over all fitted rows.

    A centrifuge sees each radial axis's gain times the radius; with each axis's linear
    term held at its 1 g scale (`scale_1g`, as the near-1 g radius does), every row whose
    input has a radial part informs the radius, the high-g steps most (the input grows
    with g, the noise of a mean does not). Gauss-Newton in ln R of each radius group (all
    positions for a common radius, else each position) on the three axes' weighted
    residuals stacked, each axis's other columns (its kept terms, the phi_h nuisances, the
    constant; weights fixed at `radius`'s) refitted at every radius (variable projection).
    The standard uncertainty is that of the Gauss-Newton normal equations scaled by the
    residual variance (as `fit_ols`'s). Returns radius per position, m.
    """
    groups = _radius_groups(radius, fitted.settings.common_radius)
    mounts = np.array([m for m, _, _ in fitted.rows])
    sem = np.array([mean.acc_std for _, _, mean in fitted.rows])
    f0, E, _ = fitted.regression(radius)
    held = {a: fitted.settings.scale_1g.get(a, 0.0) for a in AXES}
    names = {a: [n for n in m.fit.names if n not in (CONST, f"a_{a}")] for a, m in axes.items()}
    sqrt_w = {
        a: np.sqrt(
            step_weights(
                np.empty((len(fitted.rows), 0)),
                E[:, i],
                [],
                sem[:, i],
                f0[:, i],
                axes[a].scale_instability,
            )[0]  # fmt: skip
        )
        for i, a in enumerate(AXES)
    }

    def residuals(log_r: np.ndarray) -> tuple[np.ndarray, int]:
        f, _, dphi = fitted.regression(_scaled(radius, groups, np.exp(log_r)))
        out, p = [], len(groups)
        for i, a in enumerate(AXES):
            X = _columns(names[a], i, mounts, f, dphi)
            y = E[:, i] - (1.0 + held[a]) * f[:, i]
            fit = fit_ols(X, y, names[a], add_constant=True, weights=sqrt_w[a] ** 2)
            out.append(fit.residuals * sqrt_w[a])
            p += len(fit.names)
        return np.concatenate(out), p

    log_r = np.zeros(len(groups))
    for _ in range(rounds):
        r0, p = residuals(log_r)
        J = np.column_stack(
            [(residuals(log_r + step * e)[0] - r0) / step for e in np.eye(len(groups))]
        )
        log_r = log_r - np.linalg.lstsq(J, r0, rcond=None)[0]
    r0, p = residuals(log_r)
    var = float(r0 @ r0) / (r0.size - p) * np.diag(np.linalg.inv(J.T @ J))
    out = {}
    for k, group in enumerate(groups):
        value = radius[group[0]].value * math.exp(log_r[k])
        out |= {m: Estimate(value, value * math.sqrt(var[k])) for m in group}
    return out


def _fit_axis(
    axis: str,
    i: int,
    candidates: tuple[tuple[str, ...], tuple[str, ...]],
    mounts: list[str],
    step_mounts: np.ndarray,
    f: np.ndarray,
    E: np.ndarray,
    dphi: np.ndarray,
    sem: np.ndarray,
    settings: CentrifugeSettings,
) -> AxisModel:
    """Weighted stepwise fit of one accelerometer axis (index i) over all steps.

    phi_h of the positions where this axis is tangential is refined over all
    steps with the model (nuisance columns `dphi`, rad -> m/s^2 per rad): the
    1 g run alone leaves an error that the high steps amplify 20-fold.
    f, E : (steps, 3) reference specific force and step means, m/s^2; sem : (steps, 3)
    standard errors of the step means, m/s^2.
    """
    terms, dropped = candidates
    nuisance = tuple(_nuisance_name(m) for m in _tangential_mounts(axis, mounts))
    names = (*nuisance, *terms)
    X = _columns(names, i, step_mounts, f, dphi)
    y = E[:, i] - f[:, i]
    try:
        w, kappa = step_weights(X, y, names, sem[:, i], f[:, i], _instability_of(settings, axis))
    except ValueError as exc:
        if settings.radius_from != "all_records":
            raise
        raise ValueError(
            f'axis {axis}: {exc}. With radius_from = "all_records" the zero outputs and '
            "near-1 g runs are rows of the fit, and a bias that moves from record to record "
            'cannot pass for a scale instability there; radius_from = "near_1g" fits the '
            "high-g steps alone (docs/methods.md 2.8)"
        ) from None
    red = stepwise_reduce(
        X,
        y,
        names,
        settings.alpha,
        keep=(CONST, *nuisance),
        add_constant=True,
        weights=w,
        t_test=settings.t_test,
        steer=settings.steer,
    )
    return AxisModel(axis, red, nuisance, dropped, kappa)


def _step_record(settings: CentrifugeSettings, means: _Means, model: CentrifugeModel) -> StepRecord:
    """The solve's step record: its settings and the fit's statistics per axis."""
    return StepRecord(
        name="centrifuge",
        settings={
            "latitude_deg": settings.latitude_deg,
            "gravity": settings.gravity,
            "alpha": settings.alpha,
            "t_test": settings.t_test,
            "steer": settings.steer,
            "scale_1g": dict(settings.scale_1g),
            "common_radius": settings.common_radius,
            "iterations": settings.iterations,
            "zero_shift_limit": settings.zero_shift_limit,
            "radius_from": settings.radius_from,
        },
        statistics={
            "zero_shift": {m: z.shift.tolist() for m, z in model.zero_shift.items()},
            "steps": len(means.steps),
            "mounts": sorted(means.one_g),
            "radius_m": {m: r.value for m, r in model.radius.items()},
            "phi_h_rad": {m: p.value for m, p in model.phi_h.items()},
            **{f"{a}.not_identifiable": list(m.not_identifiable) for a, m in model.axes.items()},
            **{f"{a}.terms": list(m.terms) for a, m in model.axes.items()},
            **{f"{a}.removed": list(m.reduction.removed) for a, m in model.axes.items()},
            **{f"{a}.F": m.fit.F for a, m in model.axes.items()},
            **{f"{a}.F_crit": m.fit.F_crit for a, m in model.axes.items()},
            **{f"{a}.r2": m.fit.r2 for a, m in model.axes.items()},
        },
    )


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
