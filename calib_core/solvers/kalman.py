"""Sequential (Kalman) estimator of the static accelerometer model.

docs/methods.md 3.5: "least-squares solving; a Kalman-filter refinement is an
optional extra" (the rate-table procedure: "least squares or Kalman filter").
The filter estimates the 12 parameters of f_meas = (I + M) f_true + b from
the samples one at a time, as a lab would while the table still stands.

State per output axis i: x_i = (b_i, A_i0, A_i1, A_i2), A = I + M, with the
measurement m_i = x_i . (1, f_true) + noise. The parameters do not change
during a calibration, so there is no process noise and the filter is
recursive least squares: with a diffuse prior its final state and covariance
are the weighted least-squares solution of the same samples. The axes are
independent (diagonal measurement noise), so the three 4-state filters run
side by side as scalar updates in Joseph form.

Measurement variance. A sample of position k, axis i gets
R = std^2 * n / n_eff (the position's sample std, inflated by the ratio of
samples to effective samples): n samples then carry the information of the
position mean with variance sem^2, the weight `fit_affine` gives it. With
plain std^2 correlated noise would make the filter's covariance n / n_eff
times too small.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calib_core.solvers.multi_position import LinearFit, design_condition, linear_fit_from
from calib_core.stats import channel_stats

# Prior standard deviations of the diffuse start (x0 = nominal: b = 0, A = I).
# Against the 1e-4 .. 1e-3 posterior std of a lab calibration these give the
# prior a relative weight below 1e-10 (posterior variance / prior variance).
PRIOR_BIAS_STD = 100.0  # m/s^2, ten times g
PRIOR_MATRIX_STD = 10.0  # dimensionless


def kalman_update(
    x: np.ndarray, P: np.ndarray, h: np.ndarray, z: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One scalar measurement update of several independent filters sharing h.

    Parameters
    ----------
    x : (m, s) states of m filters.
    P : (m, s, s) their covariances.
    h : (s,) measurement row, the same for all filters.
    z : (m,) measurements.
    r : (m,) measurement variances (> 0).

    Returns
    -------
    (x, P) after the update; P in Joseph form (stays symmetric, positive definite).
    """
    Ph = P @ h  # (m, s)
    gain = Ph / (Ph @ h + r)[:, None]  # (m, s)
    x = x + gain * (z - x @ h)[:, None]
    ikh = np.eye(len(h)) - gain[:, :, None] * h[None, None, :]  # (m, s, s)
    P = ikh @ P @ ikh.transpose(0, 2, 1) + r[:, None, None] * (gain[:, :, None] * gain[:, None, :])
    return x, P


def kalman_accel_linear(f_true: np.ndarray, samples: Sequence[np.ndarray]) -> LinearFit:
    """The 12-parameter accelerometer model by a sequential Kalman filter over every sample.

    Parameters
    ----------
    f_true : (K, 3) reference specific force per position, m/s^2.
    samples : K arrays (N_k, 3) of accelerometer output at each position, m/s^2,
        in the order they were recorded.

    Returns
    -------
    LinearFit as `solve_accel_linear` (acc.bias.*, acc.scale.*, acc.misalign.*),
    the covariance the filter's final P; residuals and chi2 at the position means.

    Raises
    ------
    ValueError
        when the positions do not determine the model (the filter would return
        its prior in the undetermined directions), or a position has fewer than
        2 samples or a channel without noise.
    """
    f_true = np.asarray(f_true, dtype=float)
    if f_true.ndim != 2 or f_true.shape[1] != 3 or len(samples) != len(f_true):
        raise ValueError(
            f"f_true must be (K, 3) with one sample array per position; got {f_true.shape} "
            f"and {len(samples)} arrays"
        )
    design_condition(f_true)  # refuses a position set that leaves directions undetermined
    x = np.tile(np.array([0.0, 0.0, 0.0, 0.0]), (3, 1))
    x[:, 1:] = np.eye(3)
    P = np.tile(np.diag([PRIOR_BIAS_STD**2, *[PRIOR_MATRIX_STD**2] * 3]), (3, 1, 1))
    means, sems = np.empty((len(f_true), 3)), np.empty((len(f_true), 3))
    for k, (f, acc) in enumerate(zip(f_true, samples, strict=True)):
        stats = channel_stats(acc)
        if not np.all(stats.std > 0):
            raise ValueError(f"position {k}: an accelerometer channel has no noise (std 0)")
        means[k], sems[k] = stats.mean, stats.sem
        r = stats.std**2 * stats.n / stats.n_eff
        h = np.array([1.0, *f])
        for z in np.asarray(acc, dtype=float):
            x, P = kalman_update(x, P, h, z, r)
    P = 0.5 * (P + P.transpose(0, 2, 1))
    return linear_fit_from("acc", f_true, means, sems, x, P, identity=True)
