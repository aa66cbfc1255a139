"""Multi-position least squares: the linear model from any set of static positions.

Each static position k gives the mean sensor output m_k (3,) at a known true
specific force f_k (3,). Row i of the output is affine in f,

    m_k,i = b_i + sum_j A_ij f_k,j,

so each axis is a weighted least-squares fit of 4 unknowns (b_i, A_i,:) to K
positions, independent of the other axes. For the accelerometer A = I + M_a;
for a gyro at rest A = G (g-sensitivity) and b = b_g.

The general accelerometer models (reduced, quadratic, nonlinear) are
calib_core.solvers.accel_models (`solve_accel_multi`).

`solve_multi_position` is the procedure: labelled static segments plus the
table attitude of each (settings, reference channels, or a face label), the
reference specific force through rotation matrices (calib_core.attitude).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calib_core import params
from calib_core.attitude import (
    ATTITUDE_CONVENTIONS,
    TABLE_AXES,
    attitude_problems,
    specific_force,
    table_attitude,
)
from calib_core.calibration import Calibration, SegmentResidual
from calib_core.preprocess.motion import is_rotation
from calib_core.recording import Recording
from calib_core.settings import Setting, Settings, SettingsIn
from calib_core.solvers.accel_models import (
    ACCEL_MODELS,
    accel_output,
    position_arrays,
    solve_accel_multi,
)
from calib_core.solvers.six_position import reference_up
from calib_core.stats import (
    channel_stats,
    column_mean_std,
    largest_std,
    misfit_scale,
    misfit_warnings,
)
from calib_core.units import DEG


@dataclass(frozen=True)
class LinearFit:
    """Result of a per-axis weighted least-squares fit of the linear model.

    Attributes
    ----------
    params : canonical name -> value (SI).
    names : the 12 names in the order of cov: [bias x, row x of the matrix,
        bias y, row y, bias z, row z].
    cov : (12, 12) parameter covariance (block diagonal: axes are independent).
    std : canonical name -> standard uncertainty.
    condition_number : of the design matrix [1, f / g] (scale-free; sqrt(3) for
        the six-position set).
    residual_means : (K, 3) measured mean - model at each position.
    chi2 : (3,) weighted residual sum of squares per axis (K - 4 degrees of freedom).
    misfit_scaled : whether cov carries `misfit_scale` (a `fit_affine` fit), so that a
        rejected noise-only model is said in `warnings`; False for estimates found
        another way (`linear_fit_from`), whose covariance is their own.
    """

    params: dict[str, float]
    names: list[str]
    cov: np.ndarray
    std: dict[str, float]
    condition_number: float
    residual_means: np.ndarray
    chi2: np.ndarray
    misfit_scaled: bool = False

    @property
    def warnings(self) -> list[str]:
        """Said when the residuals rejected the noise-only model (`misfit_scale`)."""
        if not self.misfit_scaled:
            return []
        dof = np.full(3, self.residual_means.shape[0] - 4)
        sensor = "gyro" if self.names[0].startswith("gyr") else "accelerometer"
        return misfit_warnings(f"the {sensor} fit", self.chi2, dof)


def fit_affine(
    f_true: np.ndarray, means: np.ndarray, sem: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
    """Weighted least squares of means = b + A f per output axis.

    Parameters
    ----------
    f_true : (K, 3) true specific force at each position, m/s^2.
    means : (K, 3) mean output at each position.
    sem : (K, 3) standard uncertainty of each mean (> 0).

    Returns
    -------
    b : (3,) offsets.
    A : (3, 3) matrix, A[i, j] = d output_i / d f_j.
    cov : (3, 4, 4) covariance of (b_i, A_i0, A_i1, A_i2) per output axis.
    condition_number : of the design [1, f / |f|max].
    residual_means : (K, 3).
    chi2 : (3,).
    """
    f_true, means, sem = position_arrays(f_true, means, sem)
    k = f_true.shape[0]
    if not np.all(sem > 0):
        raise ValueError("every standard uncertainty of a position mean must be > 0")
    condition = design_condition(f_true)
    design = np.hstack([np.ones((k, 1)), f_true])  # (K, 4)
    x = np.empty((3, 4))
    cov = np.empty((3, 4, 4))
    for i in range(3):
        w = 1.0 / sem[:, i]
        # Whitened least squares via lstsq (QR/SVD), not the normal equations.
        x[i] = np.linalg.lstsq(design * w[:, None], means[:, i] * w, rcond=None)[0]
        try:
            cov[i] = np.linalg.inv((design * (w * w)[:, None]).T @ design)
        except np.linalg.LinAlgError:  # singular in double precision: _check_variances says why
            cov[i] = np.nan
    _check_variances(cov, sem)
    residual = means - design @ x.T
    chi2 = ((residual / sem) ** 2).sum(axis=0)
    cov *= (misfit_scale(chi2, np.full(3, k - 4)) ** 2)[:, None, None]
    return x[:, 0], x[:, 1:], cov, condition, residual, chi2


def _check_variances(cov: np.ndarray, sem: np.ndarray) -> None:
    """ValueError unless every variance of the fit (`cov`, (3, 4, 4)) is finite and > 0.

    Weights that span more than double precision resolves (a position mean whose sem is
    rounding, its samples one repeated reading) leave the inverted normal matrix with
    negative or undefined variances: the fit is refused before any uncertainty is taken.
    """
    var = np.diagonal(cov, axis1=1, axis2=2)
    if np.all(np.isfinite(var) & (var > 0)):
        return
    k, axis = np.unravel_index(int(np.argmin(sem)), sem.shape)
    raise ValueError(
        "the weighted fit has no defined uncertainty: the standard uncertainties of the "
        f"position means span {sem.min():.3g} .. {sem.max():.3g} (smallest: position {k + 1}, "
        f"axis {'xyz'[axis]}); a position whose samples show no scatter (one reading "
        "repeated) must be recorded again"
    )


def design_condition(f_true: np.ndarray) -> float:
    """Condition number of the scale-free design [1, f / |f|max] of K positions (K, 3).

    How well the positions pin the 12-parameter linear model; ValueError below
    4 positions or when it exceeds 1e8 (directions the data do not determine).
    """
    k = f_true.shape[0]
    if k < 4:
        raise ValueError(f"the 12-parameter linear model needs at least 4 positions, got {k}")
    scale = np.abs(f_true).max()
    condition = float(np.linalg.cond(np.hstack([np.ones((k, 1)), f_true / scale])))
    if not np.isfinite(condition) or condition > 1e8:
        raise ValueError(
            f"the positions do not determine the linear model (condition number {condition:.3g}); "
            "use positions that excite every axis in both directions"
        )
    return condition


def _linear_fit(
    sensor: str, f_true: np.ndarray, means: np.ndarray, sem: np.ndarray, identity: bool
) -> LinearFit:
    b, A, cov, condition, residual, chi2 = fit_affine(f_true, means, sem)
    return named_fit(sensor, b, A, cov, condition, residual, chi2, identity, misfit_scaled=True)


def linear_fit_from(
    sensor: str,
    f_true: np.ndarray,
    means: np.ndarray,
    sem: np.ndarray,
    x: np.ndarray,
    cov: np.ndarray,
    identity: bool,
) -> LinearFit:
    """A LinearFit from per-axis estimates found another way (e.g. a Kalman filter).

    x : (3, 4) rows (b_i, A_i0, A_i1, A_i2); cov : (3, 4, 4) their covariances;
    f_true, means, sem : (K, 3) positions, for the residuals and chi2.
    """
    design = np.hstack([np.ones((len(f_true), 1)), f_true])
    residual = means - design @ x.T
    chi2 = ((residual / sem) ** 2).sum(axis=0)
    condition = design_condition(f_true)
    return named_fit(sensor, x[:, 0], x[:, 1:], cov, condition, residual, chi2, identity)


def named_fit(
    sensor: str,
    b: np.ndarray,
    A: np.ndarray,
    cov: np.ndarray,
    condition: float,
    residual: np.ndarray,
    chi2: np.ndarray,
    identity: bool,
    misfit_scaled: bool = False,
) -> LinearFit:
    """Canonical names, values, stds and the (12, 12) block covariance of an affine fit
    (`misfit_scaled`: cov carries `misfit_scale`, see `LinearFit`)."""
    row_names = params.matrix_names(sensor) if identity else params.gsens_names()
    M = A - np.eye(3) if identity else A
    names: list[str] = []
    values: dict[str, float] = {}
    std: dict[str, float] = {}
    full_cov = np.zeros((12, 12))
    for i, a in enumerate(params.AXES):
        block = [params.bias(sensor, a), *row_names[i]]
        names += block
        for j, name in enumerate(block):
            values[name] = float(b[i] if j == 0 else M[i, j - 1])
            std[name] = float(np.sqrt(cov[i, j, j]))
        full_cov[4 * i : 4 * i + 4, 4 * i : 4 * i + 4] = cov[i]
    return LinearFit(values, names, full_cov, std, condition, residual, chi2, misfit_scaled)


def solve_accel_linear(f_true: np.ndarray, means: np.ndarray, sem: np.ndarray) -> LinearFit:
    """Accelerometer bias, scale and misalignment from K >= 4 static positions.

    Weighted least squares of the 12-parameter model f_meas = (I + M) f_true + b.
    On the six +-g positions with equal weights it is the closed form of
    docs/methods.md 2.1 (the normal matrix is diag(6, 2g^2, 2g^2, 2g^2)).

    Parameters
    ----------
    f_true : (K, 3) reference specific force per position, m/s^2.
    means : (K, 3) mean accelerometer output per position, m/s^2.
    sem : (K, 3) standard uncertainty of each mean, m/s^2.

    Returns
    -------
    LinearFit with acc.bias.*, acc.scale.*, acc.misalign.*.
    """
    return _linear_fit("acc", f_true, means, sem, identity=True)


def solve_gyro_static(f_true: np.ndarray, means: np.ndarray, sem: np.ndarray) -> LinearFit:
    """Gyro bias and g-sensitivity from K >= 4 static positions (no rotation).

    At rest w_meas = b_g + G f_true, the same affine structure as the
    accelerometer with G in place of I + M. On the six +-g positions this is
    G_ij = (W_i(j up) - W_i(j down)) / (2g) and b_g = mean of the six.
    Earth rate is neglected (below MEMS noise); remove it from the means first
    for better sensors.

    Parameters
    ----------
    f_true : (K, 3) reference specific force per position, m/s^2.
    means : (K, 3) mean gyro output per position, rad/s.
    sem : (K, 3) standard uncertainty of each mean, rad/s.

    Returns
    -------
    LinearFit with gyr.bias.* and gyr.gsens.* ((rad/s)/(m/s^2)).
    """
    return _linear_fit("gyr", f_true, means, sem, identity=False)


# --- the procedure ----------------------------------------------------------------

# The procedure's settings (docs/procedures.md); its solver takes them typed.
SETTINGS = Settings(
    Setting("model", "text", "", "full",
            "accelerometer model: full (12), reduced (bias and scale per axis), quadratic, "
            "nonlinear", choices=ACCEL_MODELS),
    Setting("table_axes", "text", "", "pitch_roll",
            "the table's two axes the attitudes are given in", choices=TABLE_AXES),
    Setting("attitude_convention", "text", "", "project",
            "sign of the table's pitch: project a_x = -g sin(pitch), rate_table_procedure "
            "a_x = +g sin(pitch)", choices=ATTITUDE_CONVENTIONS),
    Setting("attitudes", "table", "deg", {},
            "per label the table angles {pitch_deg, roll_deg} (or azimuth_deg, pitch_deg); "
            "absent: reference channels or a face label"),
    Setting("mount", "list", "1", None,
            "3x3 body-to-table rotation (rows of numbers; absent: identity)"),
    Setting("gyro_gsens", "bool", "", True,
            "fit gyro bias and g-sensitivity from the same statics"),
    name="MultiPositionSettings",
)  # fmt: skip


def _face_vector(label: str, gravity: float) -> np.ndarray | None:
    axis, _, sense = label.partition("_")
    if axis not in params.AXIS_INDEX or sense not in ("up", "dn"):
        return None
    f = np.zeros(3)
    f[params.AXIS_INDEX[axis]] = gravity if sense == "up" else -gravity
    return f


def reference_force(label: str, rec: Recording, gravity: float, settings: Any) -> np.ndarray:
    """Reference specific force (3,) of one static segment, m/s^2.

    settings : the typed `SETTINGS` (`SETTINGS.parse`).

    In order of precedence: the table angles given in ``settings.attitudes[label]``
    (``pitch_deg``/``roll_deg`` for a pitch/roll table, ``azimuth_deg``/``pitch_deg``
    for an azimuth/pitch one); the mean of the segment's reference channels
    (``table_pitch``/``table_roll`` or ``table_azimuth``/``table_pitch``, rad); a
    face label (``x_up`` .. ``z_dn``), rotated to the segment's ``reference_up`` channel
    when it has one (a cube face found not square, `calib impact`).
    """
    axes = settings.table_axes
    keys = ("pitch", "roll") if axes == "pitch_roll" else ("azimuth", "pitch")
    mount = mount_of(settings)
    convention = settings.attitude_convention
    given = settings.attitudes.get(label)
    if given is not None:
        try:
            outer, inner = (float(given[f"{k}_deg"]) * DEG for k in keys)
        except (KeyError, TypeError, ValueError):
            raise ValueError(
                f"settings.attitudes.{label}: expected numbers {keys[0]}_deg and {keys[1]}_deg "
                f"for a {axes} table, got {given!r}"
            ) from None
        return specific_force(table_attitude(outer, inner, axes, mount, convention), gravity)
    channels = [f"table_{k}" for k in keys]
    if all(c in rec.reference for c in channels):
        outer, inner = (float(np.mean(rec.reference[c])) for c in channels)
        return specific_force(table_attitude(outer, inner, axes, mount, convention), gravity)
    face = _face_vector(label, gravity)
    if face is not None:  # a face found not square carries its true direction
        face = reference_up(label, rec, gravity)
    if face is None:
        raise ValueError(
            f"segment {label!r} ({rec.source or 'no source'}): no table attitude; give "
            f"settings.attitudes.{label} = {{{keys[0]}_deg, {keys[1]}_deg}}, reference channels "
            f"{' and '.join(channels)} (rad), or a face label x_up .. z_dn"
        )
    return face


def segment_residual(
    label: str, sensor: str, samples: np.ndarray, model: np.ndarray
) -> SegmentResidual:
    """Residual statistics (measured - model) of one segment, per axis.

    `model` is (N, 3), or (3,) for a model that is constant over the segment.
    """
    samples = np.asarray(samples, dtype=float)
    model = np.asarray(model, dtype=float)
    # Column by column: one (N,) subtraction per axis costs less than an (N, 3) one.
    r = [samples[:, j] - model[..., j] for j in range(samples.shape[1])]
    mean, std, _ = column_mean_std(r, ddof=1)
    return SegmentResidual(
        segment=label,
        sensor=sensor,
        mean=tuple(float(v) for v in mean),
        std=tuple(float(v) for v in std),
        n=int(samples.shape[0]),
    )


def gyro_bias_and_gsens(
    cal: Calibration, f_true: np.ndarray, means: np.ndarray, sem: np.ndarray
) -> None:
    """Add gyro bias and g-sensitivity from static means to `cal` (`solve_gyro_static`).

    When the positions cannot determine G (too few gravity directions), the bias
    is the weighted mean of the static means (it then includes G f) and a
    warning says so.
    """
    try:
        fit = solve_gyro_static(f_true, means, sem)
    except ValueError:
        w = 1.0 / sem**2
        bias = (w * means).sum(axis=0) / w.sum(axis=0)
        for i, a in enumerate(params.AXES):
            cal.add(params.bias("gyr", a), bias[i], 1.0 / np.sqrt(w[:, i].sum()))
        cal.warnings.append(
            "the positions do not separate the gyro g-sensitivity from the bias; "
            "gyr.gsens.* not estimated (gyr.bias includes G f)"
        )
        return
    cal.add_fit(fit.names, fit.params, fit.cov)
    cal.warnings += fit.warnings
    cal.info["gyr_fit_chi2"] = [float(v) for v in fit.chi2]


def mount_of(settings: Any) -> Any:
    """The typed settings' ``mount`` checked: a 3x3 rotation matrix (rows) or None."""
    if settings.mount is not None:
        m = np.asarray(settings.mount, dtype=float)
        if m.shape != (3, 3) or not np.allclose(m @ m.T, np.eye(3), atol=1e-6):
            raise ValueError("settings.mount: expected a 3x3 rotation matrix (rows of numbers)")
    return settings.mount


def solve_multi_position(
    segments: dict[str, Recording], gravity: float, settings: SettingsIn = None
) -> Calibration:
    """Multi-position static calibration from table attitudes (docs/methods.md 2.2).

    Parameters
    ----------
    segments : label -> static Recording, one per table position (>= 4; the
        model's unknowns per axis at least). Rotation segments (``*_cw``,
        ``*_ccw``) are ignored.
    gravity : local gravity, m/s^2.
    settings : typed `SETTINGS` (a mapping is parsed): model ("full", "reduced",
        "quadratic", "nonlinear"), table_axes
        ("pitch_roll" or "azimuth_pitch"), attitudes ({label: {pitch_deg,
        roll_deg}}), attitude_convention ("project": a_x = -g sin(pitch), or
        "rate_table_procedure": a_x = +g sin(pitch)), mount (3x3 body-to-table
        rotation), gyro_gsens (fit gyro bias and g-sensitivity from the same
        statics, default true).

    Returns
    -------
    Calibration "multi_position": the accelerometer terms of the model, gyro bias
    and g-sensitivity, noise, residuals per position; info holds the condition
    number, chi2, the accelerometer covariance, the reference forces and
    `not_separable` (warnings say why). Axes never seen in both senses are named in
    warnings, with the duplicate attitudes when there are any (info
    `duplicate_attitudes` always; calib_core.attitude.attitude_problems).
    """
    s = SETTINGS.parse(settings)
    labels = [lab for lab in segments if not is_rotation(lab)]
    f_true = np.array([reference_force(lab, segments[lab], gravity, s) for lab in labels])
    if len(labels) < 4:
        raise ValueError(
            f"multi_position: need >= 4 static positions, got {len(labels)} ({labels})"
        )
    acc, gyr = [], []
    for lab in labels:
        rec = segments[lab]
        try:
            acc.append(channel_stats(rec.acc))
            gyr.append(channel_stats(rec.gyr))
        except ValueError as exc:
            raise ValueError(f"segment {lab} ({rec.source or 'no source'}): {exc}") from None
    fit = solve_accel_multi(
        f_true, np.array([a.mean for a in acc]), np.array([a.sem for a in acc]), s.model
    )
    cal = Calibration(procedure="multi_position", gravity=gravity)
    cal.add_fit(fit.names, fit.params, fit.cov)
    if s.gyro_gsens:
        gyro_bias_and_gsens(
            cal, f_true, np.array([g.mean for g in gyr]), np.array([g.sem for g in gyr])
        )
    for sensor, stats in (("acc", acc), ("gyr", gyr)):
        value, u = largest_std(np.array([x.std for x in stats]), np.array([x.n_eff for x in stats]))
        for i, a in enumerate(params.AXES):
            cal.add(f"{sensor}.noise.{a}", value[i], u[i])
    for lab, f in zip(labels, f_true, strict=True):
        rec = segments[lab]
        # The model is one constant (3,) per position; broadcasting does the rest.
        acc_model = accel_output(fit.params, f[None, :])[0]
        cal.residuals.append(segment_residual(lab, "acc", rec.acc, acc_model))
        if s.gyro_gsens:
            w_model = cal.gsens() @ f + cal.vector("gyr", "bias")
            cal.residuals.append(segment_residual(lab, "gyr", rec.gyr, w_model))
    cal.warnings += fit.warnings
    duplicates, uncovered = attitude_problems(labels, f_true, gravity)
    # Repeats in a set that sees every axis both ways are a repeatability design; with a
    # sense missing, a repeat is the likely stand-in for it (a convention slip): warn.
    cal.warnings += (duplicates if uncovered else []) + uncovered
    cal.info["duplicate_attitudes"] = duplicates
    cal.info.update(
        {
            "model": fit.model,
            "condition_number": fit.condition_number,
            "positions": len(labels),
            "acc_fit_chi2": [float(v) for v in fit.chi2],
            "fit_dof_per_axis": [int(v) for v in fit.dof],
            "not_separable": list(fit.not_separable),
            # Full accelerometer covariance (block diagonal over the axes), SI units.
            "acc_covariance": {"names": list(fit.names), "matrix": fit.cov.tolist()},
            "separable": not fit.not_separable,
            "reference_force": {
                lab: [float(v) for v in f] for lab, f in zip(labels, f_true, strict=True)
            },
            "sample_counts": {lab: len(segments[lab]) for lab in labels},
        }
    )
    return cal
