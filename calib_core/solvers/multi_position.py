"""Multi-position least squares: the linear model from any set of static positions.

Each static position k gives the mean sensor output m_k (3,) at a known true
specific force f_k (3,). Row i of the output is affine in f,

    m_k,i = b_i + sum_j A_ij f_k,j,

so each axis is a weighted least-squares fit of 4 unknowns (b_i, A_i,:) to K
positions, independent of the other axes. For the accelerometer A = I + M_a;
for a gyro at rest A = G (g-sensitivity) and b = b_g.

`solve_accel_multi` generalises the accelerometer fit to the models labs use
(methods.md 1), still one independent fit per output axis i:

    full       m_i = b_i + sum_j (delta_ij + M_ij) f_j                  4 terms
    reduced    m_i = K_i (f_i + b'_i) = K_i f_i + b_i  (b_i = K_i b'_i)  2 terms
    quadratic  full + k2_i f_i^2                                         5 terms
    nonlinear  full + k2_i f_i^2 + k3_i f_i^3                            6 terms (18 for the triad)

A position set that cannot separate the requested terms (quadratic terms from
six +-1 g positions: f_i^2 = g^2 is a constant, the bias column again) gives a
rank-deficient design. The fit then fixes the confounded higher-order terms at
0, says so in a warning and lists them in `not_separable` (archived in
Calibration.warnings and info), instead of returning numbers that mean nothing.

`solve_multi_position` is the procedure: labelled static segments plus the
table attitude of each (settings, reference channels, or a face label), the
reference specific force through rotation matrices (calib_core.attitude).
"""

from __future__ import annotations

from dataclasses import dataclass, field
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
from calib_core.recording import Recording
from calib_core.stats import channel_stats, column_mean_std, largest_std
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
    """

    params: dict[str, float]
    names: list[str]
    cov: np.ndarray
    std: dict[str, float]
    condition_number: float
    residual_means: np.ndarray
    chi2: np.ndarray


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
    f_true, means, sem = _position_arrays(f_true, means, sem)
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
        cov[i] = np.linalg.inv((design * (w * w)[:, None]).T @ design)
    residual = means - design @ x.T
    chi2 = ((residual / sem) ** 2).sum(axis=0)
    return x[:, 0], x[:, 1:], cov, condition, residual, chi2


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
    return _named_fit(sensor, b, A, cov, condition, residual, chi2, identity)


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
    return _named_fit(sensor, x[:, 0], x[:, 1:], cov, condition, residual, chi2, identity)


def _named_fit(
    sensor: str,
    b: np.ndarray,
    A: np.ndarray,
    cov: np.ndarray,
    condition: float,
    residual: np.ndarray,
    chi2: np.ndarray,
    identity: bool,
) -> LinearFit:
    """Canonical names, values, stds and the (12, 12) block covariance of an affine fit."""
    row_names = params.matrix_names("acc") if sensor == "acc" else params.gsens_names()
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
    return LinearFit(values, names, full_cov, std, condition, residual, chi2)


def _position_arrays(
    f_true: np.ndarray, means: np.ndarray, sem: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The three per-position inputs as float arrays, checked to be (K, 3) each."""
    f_true, means, sem = (np.asarray(a, dtype=float) for a in (f_true, means, sem))
    k = f_true.shape[0]
    if f_true.shape != (k, 3) or means.shape != (k, 3) or sem.shape != (k, 3):
        raise ValueError(
            f"f_true, means and sem must all have shape (K, 3); got {f_true.shape}, "
            f"{means.shape}, {sem.shape}"
        )
    return f_true, means, sem


def solve_accel_linear(f_true: np.ndarray, means: np.ndarray, sem: np.ndarray) -> LinearFit:
    """Accelerometer bias, scale and misalignment from K >= 4 static positions.

    Weighted least squares of the 12-parameter model f_meas = (I + M) f_true + b.
    On the six +-g positions with equal weights it is the closed form of
    methods.md 2.1 (the normal matrix is diag(6, 2g^2, 2g^2, 2g^2)).

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


# --- general models: full, reduced, quadratic, nonlinear ------------------------

ACCEL_MODELS = ("full", "reduced", "quadratic", "nonlinear")
# Which term is given up first when the positions cannot separate them: the
# highest order first (a lab asking for k3 from +-1 g positions still gets the
# linear model), bias last.
_PRIORITY = {"bias": 0, "scale": 1, "misalign": 2, "k2": 3, "k3": 4}
# A singular value below this fraction of the largest (columns scaled to unit
# norm) is a direction the data do not determine: rank deficiency, not noise.
RANK_TOLERANCE = 1e-8
# Above this condition number the fit is kept but flagged: uncertainties are
# large and a small error in the attitudes is amplified.
CONDITION_WARNING = 1e3


def _axis_terms(model: str, i: int) -> list[tuple[str, str]]:
    """(canonical name, kind) of the terms of output axis i; kind picks the column."""
    a = params.AXES[i]
    names = params.matrix_names("acc")[i]
    terms = [(params.bias("acc", a), "bias")]
    if model == "reduced":
        terms.append((names[i], "scale"))
    else:
        terms += [(names[j], "scale" if j == i else "misalign") for j in range(3)]
    if model in ("quadratic", "nonlinear"):
        terms.append((f"acc.k2.{a}", "k2"))
    if model == "nonlinear":
        terms.append((f"acc.k3.{a}", "k3"))
    return terms


def _column(name: str, kind: str, i: int, f: np.ndarray) -> np.ndarray:
    if kind == "bias":
        return np.ones(f.shape[0])
    if kind in ("scale", "misalign"):
        return f[:, params.AXIS_INDEX[name[-1]]]
    return f[:, i] ** (2 if kind == "k2" else 3)


def accel_output(values: dict[str, float], f_true: np.ndarray) -> np.ndarray:
    """Accelerometer output of the general model for true specific force f (N, 3).

    m = (I + M) f + b + k2 * f^2 + k3 * f^3 (per axis); absent names count as 0.
    """
    f = np.atleast_2d(np.asarray(f_true, dtype=float))
    M = np.array([[values.get(n, 0.0) for n in row] for row in params.matrix_names("acc")])
    b = np.array([values.get(params.bias("acc", a), 0.0) for a in params.AXES])
    k2 = np.array([values.get(f"acc.k2.{a}", 0.0) for a in params.AXES])
    k3 = np.array([values.get(f"acc.k3.{a}", 0.0) for a in params.AXES])
    return f @ (np.eye(3) + M).T + b + k2 * f**2 + k3 * f**3


@dataclass(frozen=True)
class MultiPositionFit:
    """Result of `solve_accel_multi`.

    Attributes
    ----------
    model : one of ACCEL_MODELS.
    params, std : canonical name -> value / standard uncertainty (SI) of every
        estimated term (terms fixed at 0 are absent).
    names : estimated names in the order of cov.
    cov : (P, P) covariance, block diagonal over the output axes.
    condition_number : of the design with unit-norm columns, worst axis (scale-free).
    residual_means : (K, 3) mean - model at each position.
    chi2 : (3,) weighted residual sum of squares per axis; dof : (3,) its degrees of freedom.
    not_separable : names the positions cannot separate from other terms (fixed at 0).
    warnings : human-readable warnings (not separable, ill-conditioned).
    """

    model: str
    params: dict[str, float]
    std: dict[str, float]
    names: list[str]
    cov: np.ndarray
    condition_number: float
    residual_means: np.ndarray
    chi2: np.ndarray
    dof: np.ndarray
    not_separable: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def _separable_columns(
    design: np.ndarray, terms: list[tuple[str, str]]
) -> tuple[list[int], list[str]]:
    """Indices of columns kept after dropping terms the design cannot separate."""
    keep = list(range(design.shape[1]))
    dropped: list[str] = []
    while keep:
        a = design[:, keep]
        a = a / np.maximum(np.linalg.norm(a, axis=0), 1e-300)
        _, s, vt = np.linalg.svd(a, full_matrices=False)
        if len(keep) <= a.shape[0] and s[-1] > RANK_TOLERANCE * s[0]:
            break
        # Null direction: the terms with weight in it are confounded; drop the
        # highest-order one among them (more rows than columns assumed below).
        null = np.abs(vt[-1]) if len(keep) <= a.shape[0] else np.ones(len(keep))
        involved = [k for k, w in zip(keep, null, strict=True) if w > 0.05]
        worst = max(involved, key=lambda k: (_PRIORITY[terms[k][1]], k))
        keep.remove(worst)
        dropped.append(terms[worst][0])
    return keep, dropped


def solve_accel_multi(
    f_true: np.ndarray, means: np.ndarray, sem: np.ndarray, model: str = "full"
) -> MultiPositionFit:
    """Accelerometer model from K static positions by weighted least squares.

    Parameters
    ----------
    f_true : (K, 3) reference specific force per position (from the table
        attitudes), m/s^2.
    means : (K, 3) mean accelerometer output per position, m/s^2.
    sem : (K, 3) standard uncertainty of each mean, m/s^2 (> 0).
    model : "full" (12), "reduced" (6: K_i and b_i per axis), "quadratic" (15)
        or "nonlinear" (18: with k2 and k3), see the module docstring.

    Returns
    -------
    MultiPositionFit. On the six +-g positions with model "full" it equals
    `solve_accel_linear` (and so the closed form of methods.md 2.1).
    """
    if model not in ACCEL_MODELS:
        raise ValueError(
            f"unknown accelerometer model {model!r}; expected one of {list(ACCEL_MODELS)}"
        )
    f_true, means, sem = _position_arrays(f_true, means, sem)
    k = f_true.shape[0]
    if not np.all(sem > 0):
        raise ValueError("every standard uncertainty of a position mean must be > 0")
    values: dict[str, float] = {}
    std: dict[str, float] = {}
    names: list[str] = []
    blocks: list[np.ndarray] = []
    residual = np.empty((k, 3))
    chi2, dof = np.empty(3), np.empty(3, dtype=int)
    conditions: list[float] = []
    not_separable: list[str] = []
    for i in range(3):
        terms = _axis_terms(model, i)
        design = np.column_stack([_column(n, kind, i, f_true) for n, kind in terms])
        keep, dropped = _separable_columns(design, terms)
        not_separable += dropped
        a = design[:, keep]
        w = 1.0 / sem[:, i]
        aw = a * w[:, None]
        x = np.linalg.lstsq(aw, means[:, i] * w, rcond=None)[0]
        cov = np.linalg.inv(aw.T @ aw)
        unit = a / np.linalg.norm(a, axis=0)
        conditions.append(float(np.linalg.cond(unit)))
        residual[:, i] = means[:, i] - a @ x
        chi2[i] = float(((residual[:, i] * w) ** 2).sum())
        dof[i] = k - len(keep)
        for c, kk in enumerate(keep):
            name, kind = terms[kk]
            # The archive stores M = A - I: the on-axis coefficient minus one.
            values[name] = float(x[c] - (1.0 if kind == "scale" else 0.0))
            std[name] = float(np.sqrt(cov[c, c]))
            names.append(name)
        blocks.append(cov)
    full_cov = np.zeros((len(names), len(names)))
    at = 0
    for block in blocks:
        n = block.shape[0]
        full_cov[at : at + n, at : at + n] = block
        at += n
    condition = max(conditions)
    warnings: list[str] = []
    if not_separable:
        warnings.append(
            f"the {k} positions cannot separate {', '.join(not_separable)} from the other "
            f"terms of the {model!r} model (rank-deficient design); they were fixed at 0. "
            "Add tilted positions (12/18/24-position schemes) to estimate them"
        )
    if condition > CONDITION_WARNING:
        warnings.append(
            f"ill-conditioned position set for the {model!r} model (condition number "
            f"{condition:.3g} > {CONDITION_WARNING:g}): uncertainties are large and attitude "
            "errors are amplified"
        )
    if np.any(dof < 0):
        raise ValueError(f"{k} positions are fewer than the unknowns of the {model!r} model")
    return MultiPositionFit(
        model, values, std, names, full_cov, condition, residual, chi2, dof, not_separable, warnings
    )


# --- the procedure ----------------------------------------------------------------

MULTI_POSITION_DEFAULTS: dict[str, Any] = {
    "model": "full",
    "table_axes": "pitch_roll",
    "attitude_convention": "project",
    "attitudes": {},
    "mount": None,
    "gyro_gsens": True,
}


def _face_vector(label: str, gravity: float) -> np.ndarray | None:
    axis, _, sense = label.partition("_")
    if axis not in params.AXIS_INDEX or sense not in ("up", "dn"):
        return None
    f = np.zeros(3)
    f[params.AXIS_INDEX[axis]] = gravity if sense == "up" else -gravity
    return f


def reference_force(
    label: str, rec: Recording, gravity: float, settings: dict[str, Any]
) -> np.ndarray:
    """Reference specific force (3,) of one static segment, m/s^2.

    In order of precedence: the table angles given in ``settings["attitudes"][label]``
    (``pitch_deg``/``roll_deg`` for a pitch/roll table, ``azimuth_deg``/``pitch_deg``
    for an azimuth/pitch one); the mean of the segment's reference channels
    (``table_pitch``/``table_roll`` or ``table_azimuth``/``table_pitch``, rad); a
    face label (``x_up`` .. ``z_dn``).
    """
    axes = settings["table_axes"]
    if axes not in TABLE_AXES:
        raise ValueError(f"settings.table_axes: {axes!r}; expected one of {list(TABLE_AXES)}")
    keys = ("pitch", "roll") if axes == "pitch_roll" else ("azimuth", "pitch")
    mount = settings.get("mount")
    convention = settings.get("attitude_convention", "project")
    given = settings["attitudes"].get(label)
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
    cal.info["gyr_fit_chi2"] = [float(v) for v in fit.chi2]


def multi_position_settings(settings: dict[str, Any] | None) -> dict[str, Any]:
    """Settings of `solve_multi_position` with defaults filled in, validated."""
    given = dict(settings or {})
    merged = {
        **MULTI_POSITION_DEFAULTS,
        **{k: v for k, v in given.items() if k in MULTI_POSITION_DEFAULTS},
    }
    if merged["model"] not in ACCEL_MODELS:
        raise ValueError(
            f"settings.model: {merged['model']!r}; expected one of {list(ACCEL_MODELS)}"
        )
    if merged["attitude_convention"] not in ATTITUDE_CONVENTIONS:
        raise ValueError(
            f"settings.attitude_convention: {merged['attitude_convention']!r}; expected one of "
            f"{list(ATTITUDE_CONVENTIONS)}"
        )
    if not isinstance(merged["attitudes"], dict):
        raise ValueError("settings.attitudes: expected a table {label = {pitch_deg, roll_deg}}")
    if merged["mount"] is not None:
        m = np.asarray(merged["mount"], dtype=float)
        if m.shape != (3, 3) or not np.allclose(m @ m.T, np.eye(3), atol=1e-6):
            raise ValueError("settings.mount: expected a 3x3 rotation matrix (rows of numbers)")
    return merged


def solve_multi_position(
    segments: dict[str, Recording], gravity: float, settings: dict[str, Any] | None = None
) -> Calibration:
    """Multi-position static calibration from table attitudes (methods.md 2.2).

    Parameters
    ----------
    segments : label -> static Recording, one per table position (>= 4; the
        model's unknowns per axis at least). Rotation segments (``*_cw``,
        ``*_ccw``) are ignored.
    gravity : local gravity, m/s^2.
    settings : model ("full", "reduced", "quadratic", "nonlinear"), table_axes
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
    s = multi_position_settings(settings)
    labels = [lab for lab in segments if not lab.endswith(("_cw", "_ccw"))]
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
        f_true, np.array([a.mean for a in acc]), np.array([a.sem for a in acc]), s["model"]
    )
    cal = Calibration(procedure="multi_position", gravity=gravity)
    cal.add_fit(fit.names, fit.params, fit.cov)
    if s["gyro_gsens"]:
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
        if s["gyro_gsens"]:
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
