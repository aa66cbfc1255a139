"""Multi-position least squares, the accelerometer models: full, reduced, quadratic, nonlinear.

`solve_accel_multi` generalises the accelerometer fit to the models labs use
(docs/methods.md 1), still one independent fit per output axis i:

    full       m_i = b_i + sum_j (delta_ij + M_ij) f_j                  4 terms
    reduced    m_i = K_i (f_i + b'_i) = K_i f_i + b_i  (b_i = K_i b'_i)  2 terms
    quadratic  full + k2_i f_i^2                                         5 terms
    nonlinear  full + k2_i f_i^2 + k3_i f_i^3                            6 terms (18 for the triad)

A position set that cannot separate the requested terms (quadratic terms from
six +-1 g positions: f_i^2 = g^2 is a constant, the bias column again) gives a
rank-deficient design. The fit then fixes the confounded higher-order terms at
0, says so in a warning and lists them in `not_separable` (archived in
Calibration.warnings and info), instead of returning numbers that mean nothing.

Each output axis i is still one independent weighted fit (calib_core.solvers.multi_position
for the plain linear fit of accelerometer and gyro and the multi-position procedure).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core import params
from calib_core.stats import misfit_scale, misfit_warnings


def position_arrays(
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
    warnings : human-readable warnings (not separable, ill-conditioned, misfit).
    misfit_scale : (3,) factor on each axis's standard uncertainties: 1, or sqrt(chi2 / dof)
        where the residuals reject the noise-only model (`MISFIT_ALPHA`).
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
    misfit_scale: np.ndarray = field(default_factory=lambda: np.ones(3))


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
    `solve_accel_linear` (and so the closed form of docs/methods.md 2.1).
    """
    if model not in ACCEL_MODELS:
        raise ValueError(
            f"unknown accelerometer model {model!r}; expected one of {list(ACCEL_MODELS)}"
        )
    f_true, means, sem = position_arrays(f_true, means, sem)
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
    scale = misfit_scale(chi2, dof)
    at = 0
    for i, block in enumerate(blocks):
        n = block.shape[0]
        full_cov[at : at + n, at : at + n] *= scale[i] ** 2
        for name in names[at : at + n]:
            std[name] *= float(scale[i])
        at += n
    warnings += misfit_warnings(f"the {model!r} model", chi2, dof)
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
        model,
        values,
        std,
        names,
        full_cov,
        condition,
        residual,
        chi2,
        dof,
        not_separable,
        warnings,
        scale,
    )
