"""Small statistics shared by the solvers: honest standard errors and integrals.

The uncertainty of a position mean is the sample std over sqrt(N_eff). For white
noise N_eff = N; filtered or otherwise correlated samples carry less information,
so N_eff is estimated from the integrated autocorrelation time.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import fft as sp_fft

from calib_core.distributions import chi2_ppf, norm_cdf, norm_pdf


def integrated_autocorrelation_time(x: np.ndarray, c: float = 5.0) -> float:
    """Integrated autocorrelation time tau of a 1-D series, in samples (>= 1).

    tau = 1 + 2 sum_k rho_k, summed up to Sokal's automatic window: the smallest
    lag M with M >= c tau(M), which keeps the noise of the far lags out.
    A series whose lag-1 autocorrelation is consistent with zero (|rho_1| <
    3/sqrt(N)) is taken as white (tau = 1): for white noise the windowed sum
    would only add noise to the uncertainty.

    Parameters
    ----------
    x : (N,) samples.
    c : window constant (Sokal recommends ~5).
    """
    x = np.asarray(x, dtype=float)
    return _centred_iat(x - x.mean(), c)


def _centred_iat(d: np.ndarray, c: float = 5.0) -> float:
    """`integrated_autocorrelation_time` of a centred series d (1.0 below 8 samples)."""
    return float(centred_iats(d[None, :], c)[0])


def white_rho1_limit(n: int) -> float:
    """|rho_1| below this is white noise's for n samples (3 standard errors, 3 / sqrt(n)):
    the series' time is then 1 sample without an FFT."""
    return float(3.0 / np.sqrt(n))


def centred_iats(d: np.ndarray, c: float = 5.0) -> np.ndarray:
    """`integrated_autocorrelation_time` of each row of d (k, N), each row centred on its
    own mean (1.0 below 8 samples), vectorised over the rows.

    Returns
    -------
    (k,) tau in samples, each >= 1.
    """
    k, n = d.shape
    out = np.ones(k)
    if n < 8 or k == 0:
        return out
    sum_sq = np.einsum("ij,ij->i", d, d)
    # rho_1 by one dot product: the white-noise test needs no more, and a white
    # series (the usual static record) is then done without any FFT.
    lag1 = np.einsum("ij,ij->i", d[:, :-1], d[:, 1:])
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_1 = lag1 / sum_sq
    rows = np.nonzero((sum_sq != 0.0) & ~(np.abs(rho_1) < white_rho1_limit(n)))[0]
    if rows.size == 0:
        return out
    # All lags by FFT, zero-padded to >= 2N - 1 so it is not circular; a 5-smooth
    # length (scipy's next_fast_len) instead of the next power of two, one thread.
    size = sp_fft.next_fast_len(2 * n - 1, real=True)
    spec = sp_fft.rfft(d[rows], size, axis=1, workers=1)
    acf = sp_fft.irfft(spec.real**2 + spec.imag**2, size, axis=1, workers=1)[:, :n]
    acf /= sum_sq[rows, None]
    taus = 1.0 + 2.0 * np.cumsum(acf[:, 1:], axis=1)
    lags = np.arange(1, n)
    window = lags >= c * taus
    first = np.where(window.any(axis=1), np.argmax(window, axis=1), n - 2)
    out[rows] = np.maximum(taus[np.arange(rows.size), first], 1.0)
    return out


def effective_sample_size(x: np.ndarray) -> np.ndarray:
    """N_eff = N / tau per column.

    Parameters
    ----------
    x : (N,) or (N, k) samples.

    Returns
    -------
    float for 1-D input, (k,) for 2-D input.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        return np.float64(x.shape[0] / integrated_autocorrelation_time(x))
    return np.array([x.shape[0] / integrated_autocorrelation_time(col) for col in x.T])


def column_mean_std(
    x: np.ndarray | list[np.ndarray], ddof: int = 1
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Mean and std of each column of x, and the centred columns.

    Column by column rather than ``x.mean(axis=0)`` / ``x.std(axis=0)``: a
    reduction along axis 0 of an (N, 3) array sums row after row in an inner
    loop of 3, far slower than summing one (strided) column, and it does without
    NumPy's pairwise summation, so the column sums are also the more accurate ones.

    Parameters
    ----------
    x : (N, k) samples, or the k columns as a list of (N,) arrays.
    ddof : delta degrees of freedom of the std (N - ddof in the denominator).

    Returns
    -------
    (mean (k,), std (k,), [centred column (N,), ...]).
    """
    if isinstance(x, list):
        cols = [np.asarray(col, dtype=float) for col in x]
    else:
        x = np.asarray(x, dtype=float)
        cols = [x[:, j] for j in range(x.shape[1])]
    n = cols[0].shape[0] if cols else 0
    mean = np.array([col.mean() for col in cols])
    centred = [col - m for col, m in zip(cols, mean, strict=True)]
    # As NumPy's std: N <= ddof gives nan (0 / 0) with a RuntimeWarning, no exception.
    std = np.sqrt(np.array([d @ d for d in centred]) / max(n - ddof, 0))
    return mean, std, centred


@dataclass(frozen=True)
class ChannelStats:
    """Per-channel statistics of a static stretch.

    mean, std, sem, n_eff : (3,) each; std is the sample std (ddof=1),
    sem = std / sqrt(n_eff) the standard uncertainty of the mean.
    n : number of samples.
    """

    mean: np.ndarray
    std: np.ndarray
    sem: np.ndarray
    n_eff: np.ndarray
    n: int


def channel_stats(x: np.ndarray) -> ChannelStats:
    """Mean, std and standard error of the mean of each column of x, shape (N, 3)."""
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    if n < 2:
        raise ValueError(f"need at least 2 samples for a mean and its uncertainty, got {n}")
    mean, std, centred = column_mean_std(x, ddof=1)
    # The centred columns serve the autocorrelation too (effective_sample_size).
    n_eff = np.array([n / _centred_iat(d) for d in centred])
    return ChannelStats(mean, std, std / np.sqrt(n_eff), n_eff, n)


def no_scatter(stats: ChannelStats) -> np.ndarray:
    """(3,) bool: channels whose samples scatter no more than the rounding of their mean.

    The mean of n samples is summed pairwise, within about log2(n) units in the last place
    of its value; a sample std within that says the samples are one repeated reading (a
    stuck sensor, a repeated log line). Its sem would claim a precision no record holds.
    """
    rounding = np.log2(max(stats.n, 2)) * np.spacing(np.abs(stats.mean))
    return ~(stats.std > rounding)


def row_medians(a: np.ndarray) -> np.ndarray:
    """Median of each row of a 2-D array of finite values, (k, n) -> (k,); `a` is reordered.

    The values of ``np.median(a, axis=1)`` (the middle element, or the mean of
    the two middle ones), partitioned in place: without np.median's copy and NaN
    scan, which dominated `solvers.integral.noise_from_differences` on a long rotation
    sampled at 1 kHz. An empty row gives NaN.
    """
    n = a.shape[1]
    k = n // 2
    if n == 0:
        return np.full(a.shape[0], np.nan)
    if n % 2:
        a.partition(k, axis=1)
        return a[:, k].copy()
    a.partition([k - 1, k], axis=1)
    return 0.5 * (a[:, k - 1] + a[:, k])


def trapezoid_weights(t: np.ndarray) -> np.ndarray:
    """Weights w with sum(w * y) equal to the trapezoid integral of y over t.

    With white noise of std sigma on y, the integral's std is sigma * ||w||.

    Parameters
    ----------
    t : (N,) sample times, s.

    Returns
    -------
    (N,) weights, s.
    """
    dt = np.diff(np.asarray(t, dtype=float))
    w = np.zeros(dt.shape[0] + 1)
    w[:-1] += dt / 2.0
    w[1:] += dt / 2.0
    return w


@lru_cache(maxsize=64)
def max_normal_moments(k: int) -> tuple[float, float]:
    """Mean and variance of the largest of k independent standard normal variables."""
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    # The trapezoid rule on a smooth integrand that vanishes at both ends converges
    # geometrically: 4801 points agree with adaptive quadrature to 1e-13 for k <= 1000
    # (and spare the import of scipy.integrate, slow, at every start).
    z = np.linspace(-12.0, 12.0, 4801)
    density = k * norm_pdf(z) * norm_cdf(z) ** (k - 1)
    m1 = float(np.trapezoid(z * density, z))
    m2 = float(np.trapezoid(z * z * density, z))
    return m1, m2 - m1 * m1


def largest_std(stds: np.ndarray, n_eff: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The largest of K per-position std estimates, with its standard uncertainty.

    The paper's noise figure is the largest per-position std. As an estimate of
    the sensor's noise sigma it is biased upwards: the maximum of K estimates,
    each with std u = s / sqrt(2 (N_eff - 1)), exceeds sigma by e_K u on average
    (e_6 = 1.27) and scatters by sqrt(v_K) u. The reported uncertainty is the
    root-mean-square error sqrt(v_K + e_K^2) u, which covers both.

    Parameters
    ----------
    stds : (K, 3) per-position std of each channel.
    n_eff : (K, 3) effective sample counts.

    Returns
    -------
    (value (3,), standard uncertainty (3,)).
    """
    stds = np.asarray(stds, dtype=float)
    n_eff = np.asarray(n_eff, dtype=float)
    k = stds.shape[0]
    idx = np.argmax(stds, axis=0)
    cols = np.arange(stds.shape[1])
    value = stds[idx, cols]
    u_one = value / np.sqrt(2.0 * np.maximum(n_eff[idx, cols] - 1.0, 1.0))
    e_k, v_k = max_normal_moments(k)
    return value, u_one * np.sqrt(v_k + e_k * e_k)


# A fit's residuals reject the noise-only model when chi2 exceeds its 1 - MISFIT_ALPHA quantile.
MISFIT_ALPHA = 0.001


def misfit_scale(chi2: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """The factor on each axis's standard uncertainties (GUM Type A of a least-squares fit:
    the covariance scaled by the residual variance).

    The weights are the position means' own noise, so chi2 / dof is 1 for a model that
    holds. Where chi2 exceeds its 1 - `MISFIT_ALPHA` quantile (the noise-only model
    rejected: faces not opposite, attitudes not as assumed), the means scatter by more
    than their noise and the parameters carry that scatter: the factor is
    sqrt(chi2 / dof). Otherwise 1, so a model that holds keeps its noise-only
    uncertainty (and its coverage). Axes without degrees of freedom: 1.

    Parameters
    ----------
    chi2, dof : (3,) weighted residual sum of squares and its degrees of freedom per axis.

    Returns
    -------
    (3,) factors >= 1.
    """
    out = np.ones(len(chi2))
    for i, (c, d) in enumerate(zip(chi2, dof, strict=True)):
        if d > 0 and c > float(chi2_ppf(1.0 - MISFIT_ALPHA, d)):
            out[i] = float(np.sqrt(c / d))
    return out


def misfit_warnings(what: str, chi2: np.ndarray, dof: np.ndarray) -> list[str]:
    """The warning a fit's record carries when `misfit_scale` widened its uncertainties.

    what : the fit, for the reader ("the gyro fit", "the 'linear' model").
    chi2, dof : (3,) as for `misfit_scale`. Returns [] when no axis was scaled.
    """
    scale = misfit_scale(chi2, dof)
    if not np.any(scale > 1.0):
        return []
    axes = ", ".join(f"{a} x{v:.3g}" for a, v in zip("xyz", scale, strict=True) if v > 1)
    return [
        f"the position means scatter about {what} beyond their noise (chi2 "
        f"{', '.join(f'{c:.4g}' for c in chi2)} for {', '.join(str(int(d)) for d in dof)} "
        f"degrees of freedom, p < {MISFIT_ALPHA:g}): a face, attitude or input not as "
        f"assumed; the standard uncertainties of those axes are scaled by sqrt(chi2 / dof) "
        f"({axes})"
    ]
