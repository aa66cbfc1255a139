"""Multi-position least squares: the linear model from any set of static positions.

Each static position k gives the mean sensor output m_k (3,) at a known true
specific force f_k (3,). Row i of the output is affine in f,

    m_k,i = b_i + sum_j A_ij f_k,j,

so each axis is a weighted least-squares fit of 4 unknowns (b_i, A_i,:) to K
positions, independent of the other axes. For the accelerometer A = I + M_a;
for a gyro at rest A = G (g-sensitivity) and b = b_g.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core import params


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
    f_true = np.asarray(f_true, dtype=float)
    means = np.asarray(means, dtype=float)
    sem = np.asarray(sem, dtype=float)
    k = f_true.shape[0]
    if f_true.shape != (k, 3) or means.shape != (k, 3) or sem.shape != (k, 3):
        raise ValueError(
            f"f_true, means and sem must all have shape (K, 3); got {f_true.shape}, "
            f"{means.shape}, {sem.shape}"
        )
    if k < 4:
        raise ValueError(f"the 12-parameter linear model needs at least 4 positions, got {k}")
    if not np.all(sem > 0):
        raise ValueError("every standard uncertainty of a position mean must be > 0")
    design = np.hstack([np.ones((k, 1)), f_true])  # (K, 4)
    # Condition number of the scale-free design: how well the positions pin the model.
    scale = np.abs(f_true).max()
    condition = float(np.linalg.cond(np.hstack([np.ones((k, 1)), f_true / scale])))
    if not np.isfinite(condition) or condition > 1e8:
        raise ValueError(
            f"the positions do not determine the linear model (condition number {condition:.3g}); "
            "use positions that excite every axis in both directions"
        )
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


def _linear_fit(
    sensor: str, f_true: np.ndarray, means: np.ndarray, sem: np.ndarray, identity: bool
) -> LinearFit:
    b, A, cov, condition, residual, chi2 = fit_affine(f_true, means, sem)
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
