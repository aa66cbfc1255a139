"""Allan deviation and the noise parameters read from it (IEEE Std 952 / 1554 practice).

For a rate signal x (gyro in rad/s, accelerometer in m/s^2) sampled at rate
f_s, the overlapping Allan variance at cluster time tau = m / f_s is

    theta_k = sum_{i<k} x_i / f_s                          (integrated signal, N + 1 values)
    avar(tau) = sum_k (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2 / (2 tau^2 (N + 1 - 2m))

computed from the cumulative sum, so each tau costs O(N) vectorised operations.

The classic noise terms add in Allan variance:

    avar(tau) = N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3

N: angle (velocity) random walk, rad/s/sqrt(Hz) = rad/sqrt(s) (m/s/sqrt(s)); the
slope -1/2 line read at tau = 1 s.
B: bias instability, rad/s; the flat level is sqrt(2 ln 2 / pi) B = 0.664 B.
K: rate (acceleration) random walk, rad/s/sqrt(s); the slope +1/2 line read at tau = 3 s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib_core.distributions import chi2_ppf, norm_cdf

FLICKER_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.6643: flat ADEV level / B
_ONE_SIGMA = norm_cdf(1.0) - norm_cdf(-1.0)  # 0.6827: coverage of the CI


@dataclass(frozen=True)
class AllanResult:
    """Overlapping Allan deviation of one or more channels.

    Attributes
    ----------
    taus : (K,) cluster times, s (exact multiples of the sample period).
    adev : (K,) or (K, C) Allan deviation, unit of the input.
    n_clusters : (K,) number of overlapping second differences averaged (N + 1 - 2m).
    ci_low, ci_high : like `adev`, 68.3 % confidence interval from the chi-squared
        distribution with the equivalent degrees of freedom of white (rate) noise
        for overlapping samples (Riley, NIST SP 1065, Table 5). Other noise types
        have fewer degrees of freedom at long tau, so there the interval is too narrow.
    edf : (K,) the equivalent degrees of freedom used for the interval.
    rate_hz : sample rate, Hz.
    n_samples : number of samples N.
    """

    taus: np.ndarray
    adev: np.ndarray
    n_clusters: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    edf: np.ndarray
    rate_hz: float
    n_samples: int

    def column(self, i: int) -> AllanResult:
        """The result of channel `i` alone (1-D adev)."""
        if self.adev.ndim == 1:
            if i != 0:
                raise IndexError(f"AllanResult has one channel, asked for column {i}")
            return self
        return AllanResult(
            self.taus,
            self.adev[:, i],
            self.n_clusters,
            self.ci_low[:, i],
            self.ci_high[:, i],
            self.edf,
            self.rate_hz,
            self.n_samples,
        )

    def to_dict(self) -> dict[str, list]:
        """JSON-able lists (for Calibration.info and the archive)."""
        return {
            "taus": self.taus.tolist(),
            "adev": self.adev.tolist(),
            "n_clusters": self.n_clusters.tolist(),
            "ci_low": self.ci_low.tolist(),
            "ci_high": self.ci_high.tolist(),
        }


def cluster_sizes(n_samples: int, rate_hz: float, taus: str | np.ndarray = "octave") -> np.ndarray:
    """Cluster sizes m (samples) for the requested cluster times.

    Parameters
    ----------
    n_samples : N, number of samples.
    rate_hz : sample rate, Hz.
    taus : "octave" (m = 1, 2, 4, ...), "log" (about 10 per decade) or an array of
        cluster times in s (rounded to whole samples).

    Returns
    -------
    (K,) int array, unique, increasing, 1 <= m <= (N - 1) // 2 (so that at
    least two second differences are averaged).
    """
    m_max = (n_samples - 1) // 2
    if m_max < 1:
        raise ValueError(f"Allan deviation needs at least 3 samples, got {n_samples}")
    if isinstance(taus, str):
        if taus == "octave":
            m = 2 ** np.arange(int(math.log2(m_max)) + 1)
        elif taus == "log":
            m = np.unique(
                np.round(np.logspace(0, math.log10(m_max), 10 * int(math.log10(m_max) + 1)))
            )
        else:
            raise ValueError(f"taus must be 'octave', 'log' or an array of seconds, got {taus!r}")
        return m.astype(np.int64)
    tau_arr = np.atleast_1d(np.asarray(taus, dtype=float))
    m = np.round(tau_arr * rate_hz).astype(np.int64)
    bad = (m < 1) | (m > m_max)
    if bad.any():
        raise ValueError(
            f"cluster time(s) {tau_arr[bad].tolist()} s out of range: with {n_samples} samples "
            f"at {rate_hz} Hz, tau must be between {1 / rate_hz} s and {m_max / rate_hz} s"
        )
    return np.unique(m)


def white_noise_edf(n_samples: int, m: np.ndarray) -> np.ndarray:
    """Equivalent degrees of freedom of the overlapping Allan variance for white rate noise.

    Riley, Handbook of Frequency Stability Analysis (NIST SP 1065), Table 5, white FM:
    edf = [3 (N - 1) / (2 m) - 2 (N - 2) / N] * 4 m^2 / (4 m^2 + 5), with N the number
    of phase points (samples + 1). Clipped to >= 1.
    """
    n = float(n_samples + 1)
    m = np.asarray(m, dtype=float)
    edf = (3.0 * (n - 1.0) / (2.0 * m) - 2.0 * (n - 2.0) / n) * 4.0 * m**2 / (4.0 * m**2 + 5.0)
    return np.maximum(edf, 1.0)


def allan_result(m: np.ndarray, avar: np.ndarray, n_samples: int, rate_hz: float) -> AllanResult:
    """The AllanResult of cluster sizes `m` and their sums of squared second differences.

    Parameters
    ----------
    m : (K,) cluster sizes, samples.
    avar : (K,) or (K, C) sum of (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2 over k divided by
        2 (N + 1 - 2m), theta in (unit) s (divided in place by tau^2 here).
    n_samples : N.
    rate_hz : sample rate, Hz.

    The end of `calib_core.streamed.StreamedAllan` (`allan_deviation` is its one-chunk
    case).
    """
    n = n_samples
    taus_s = m / rate_hz
    extra = (1,) * (avar.ndim - 1)
    avar /= (taus_s**2).reshape((-1,) + extra)
    adev = np.sqrt(avar)

    edf = white_noise_edf(n, m)
    lo_q = chi2_ppf(0.5 + _ONE_SIGMA / 2.0, edf)
    hi_q = chi2_ppf(0.5 - _ONE_SIGMA / 2.0, edf)
    shape = (-1,) + extra
    ci_low = adev * np.sqrt(edf / lo_q).reshape(shape)
    ci_high = adev * np.sqrt(edf / hi_q).reshape(shape)
    return AllanResult(
        taus=taus_s,
        adev=adev,
        n_clusters=(n + 1 - 2 * m).astype(np.int64),
        ci_low=ci_low,
        ci_high=ci_high,
        edf=edf,
        rate_hz=float(rate_hz),
        n_samples=n,
    )


@dataclass(frozen=True)
class NoiseParameters:
    """Noise terms of one channel read from its Allan deviation.

    Attributes
    ----------
    arw : angle / velocity random walk N, (unit)/sqrt(Hz), e.g. rad/s/sqrt(Hz) = rad/sqrt(s).
    bias_instability : B, unit of the channel (rad/s, m/s^2).
    rrw : rate / acceleration random walk K, (unit)/sqrt(s).
    method : "lines" or "model" (see `noise_parameters`).
    arw_taus, rrw_taus : cluster times (s) used for the two line fits.
    bias_instability_tau : cluster time (s) of the flat level used.
    """

    arw: float
    bias_instability: float
    rrw: float
    method: str
    arw_taus: list[float] = field(default_factory=list)
    rrw_taus: list[float] = field(default_factory=list)
    bias_instability_tau: float | None = None

    def adev_model(self, tau: float | np.ndarray) -> np.ndarray:
        """Allan deviation of the three-term model at `tau` (s)."""
        tau = np.asarray(tau, dtype=float)
        flat = FLICKER_FACTOR * self.bias_instability
        return np.sqrt(self.arw**2 / tau + flat**2 + self.rrw**2 * tau / 3.0)

    def to_dict(self) -> dict[str, object]:
        return {
            "arw": self.arw,
            "bias_instability": self.bias_instability,
            "rrw": self.rrw,
            "method": self.method,
            "arw_taus": list(self.arw_taus),
            "rrw_taus": list(self.rrw_taus),
            "bias_instability_tau": self.bias_instability_tau,
        }


def _fixed_slope_line(taus: np.ndarray, adev: np.ndarray, w: np.ndarray, slope: float) -> float:
    """Intercept c of log adev = log c + slope log tau, weighted least squares (closed form)."""
    return float(np.exp(np.sum(w * (np.log(adev) - slope * np.log(taus))) / np.sum(w)))


def _model_fit(result: AllanResult) -> np.ndarray:
    """Non-negative weighted LS of avar = a / tau + b + c tau; returns (a, b, c).

    Each Allan variance has relative standard deviation sqrt(2 / edf), so the
    residuals are divided by that (iterated once with the fitted model in the
    denominator, to avoid favouring the downward-fluctuating points).
    """
    from scipy import optimize  # slow to import: only where a noise model is fitted

    taus, avar = result.taus, result.adev**2
    A = np.column_stack([1.0 / taus, np.ones_like(taus), taus / 3.0])
    if not np.any(avar > 0):
        return np.zeros(3)  # a constant signal: no noise at all
    scale = np.where(avar > 0, avar, avar[avar > 0].min())
    coef = np.zeros(3)
    for _ in range(3):
        w = np.sqrt(result.edf / 2.0) / scale
        coef, _ = optimize.nnls(A * w[:, None], avar * w)
        scale = np.maximum(A @ coef, 1e-12 * avar.max())
    return coef  # a = N^2, b = (0.664 B)^2, c = K^2 (the third column carries the 1/3)


def _terms_fit(result: AllanResult, keep: tuple[bool, bool, bool]) -> tuple[np.ndarray, np.ndarray]:
    """`_model_fit` on the kept terms: (coefficients (3,), their standard errors (3,)).

    The standard errors are those of the weighted least squares at the fitted model (each
    Allan variance's relative standard deviation sqrt(2 / edf)); the overlap of the clusters
    correlates neighbouring taus, so they are a lower limit.
    """
    from scipy import optimize

    taus, avar = result.taus, result.adev**2
    A = np.column_stack([1.0 / taus, np.ones_like(taus), taus / 3.0])[:, list(keep)]
    scale = np.where(avar > 0, avar, avar[avar > 0].min())
    coef = np.zeros(A.shape[1])
    for _ in range(3):
        w = np.sqrt(result.edf / 2.0) / scale
        coef, _ = optimize.nnls(A * w[:, None], avar * w)
        scale = np.maximum(A @ coef, 1e-12 * avar.max())
    aw = A * (np.sqrt(result.edf / 2.0) / scale)[:, None]
    se = np.sqrt(np.diag(np.linalg.pinv(aw.T @ aw)))
    full, full_se = np.zeros(3), np.full(3, np.inf)
    full[list(np.flatnonzero(keep))], full_se[list(np.flatnonzero(keep))] = coef, se
    return full, full_se


MEAN_TERM_Z = 3.0  # a flicker or random-walk term enters u(mean) when this many SE above 0


def mean_uncertainty(result: AllanResult, duration_s: float) -> float:
    """Standard uncertainty of the mean of a record of `duration_s` (s) of one channel:
    the Allan deviation at tau = duration_s of the noise model with only the terms the
    curve supports.

    The three-term fit's flicker and random-walk terms are never negative, so on white
    noise they come out positive about half the time, and their extrapolation to the whole
    record (c tau / 3 grows with tau) can multiply u by several times. A term is kept when
    it is MEAN_TERM_Z of its standard errors above zero (those errors are a lower limit:
    neighbouring taus are correlated, hence 3 and not 2), the white term always; the kept
    terms are fitted again without the others. Exact for white noise (std / sqrt(n)) and
    for a random walk the curve shows.
    """
    if result.adev.ndim != 1 or not np.any(result.adev > 0):
        return 0.0
    keep = [True, True, True]
    coef, se = _terms_fit(result, tuple(keep))
    for i in (1, 2):
        keep[i] = bool(coef[i] > MEAN_TERM_Z * se[i])
    if not all(keep):
        coef, _ = _terms_fit(result, tuple(keep))
    a, b, c = coef
    return float(math.sqrt(a / duration_s + b + c * duration_s / 3.0))


def noise_parameters(
    result: AllanResult, *, method: str = "model", slope_tol: float = 0.1
) -> NoiseParameters:
    """Angle random walk, bias instability and rate random walk of one channel.

    Parameters
    ----------
    result : AllanResult of ONE channel (use ``result.column(i)`` for a triad).
    method :
        "lines" (IEEE Std 952 reading): a slope -1/2 line is fitted (fixed slope,
        weighted by the degrees of freedom) to the short-tau points whose local
        log-log slope is within `slope_tol` of -1/2 and read at tau = 1 s; the
        bias instability is the minimum of the curve divided by 0.664; a slope +1/2
        line fitted the same way to the long-tau points is read at tau = 3 s. The
        minimum also holds the white and random-walk terms, so it overestimates B
        unless those are well below the flat level (their sum at the minimum is
        2 N K / sqrt(3) in variance).
        "model" (default): the same three lines, fitted jointly,
        avar = N^2/tau + (0.664 B)^2 + K^2 tau/3 (non-negative least squares over
        all taus, weighted by the degrees of freedom), then read the same way (slope
        -1/2 line at 1 s, flat level / 0.664, slope +1/2 line at 3 s). This removes
        the overlap of the terms and does not depend on finding a clean slope
        region in a noisy curve; on white + flicker + random walk with crossovers
        1 s and 50 s it recovers all three within a few per cent (tests/test_noise.py).
    slope_tol : tolerance on the local log-log slope for the "lines" regions.

    Returns
    -------
    NoiseParameters. A term with no region of its slope in the data is 0.0 (with no taus).
    """
    if result.adev.ndim != 1:
        raise ValueError(
            f"noise_parameters needs one channel, got adev of shape {result.adev.shape}; "
            "use result.column(i)"
        )
    taus, adev = result.taus, result.adev
    if method == "model":
        a, b, c = _model_fit(result)
        imin = int(np.argmin(adev))
        return NoiseParameters(
            arw=math.sqrt(a),
            bias_instability=math.sqrt(b) / FLICKER_FACTOR,
            rrw=math.sqrt(c),
            method="model",
            arw_taus=taus.tolist(),
            rrw_taus=taus.tolist(),
            bias_instability_tau=float(taus[imin]),
        )
    if method != "lines":
        raise ValueError(f"noise_parameters: method must be 'lines' or 'model', got {method!r}")
    if taus.size < 3:
        raise ValueError(f"noise_parameters needs >= 3 cluster times, got {taus.size}")
    # Local slope at each tau: centred difference of log adev over log tau.
    slope = np.gradient(np.log(adev), np.log(taus))
    imin = int(np.argmin(adev))

    # White region: the leading run of points (before the minimum) with slope ~ -1/2.
    white = np.abs(slope + 0.5) <= slope_tol
    white[imin + 1 :] = False
    white_idx = np.flatnonzero(white)
    if white_idx.size and white_idx[0] == 0:
        stop = np.flatnonzero(~white)
        white_idx = white_idx[: (stop[0] if stop.size else white.size)]
    arw = 0.0
    if white_idx.size:
        arw = _fixed_slope_line(taus[white_idx], adev[white_idx], result.edf[white_idx], -0.5)

    # Random-walk region: points after the minimum with slope ~ +1/2.
    rw = np.abs(slope - 0.5) <= slope_tol
    rw[: imin + 1] = False
    rw_idx = np.flatnonzero(rw)
    rrw = 0.0
    if rw_idx.size:
        # sigma = K sqrt(tau / 3) on this line, so K is its value at tau = 3 s
        rrw = _fixed_slope_line(taus[rw_idx], adev[rw_idx], result.edf[rw_idx], 0.5) * math.sqrt(
            3.0
        )
    return NoiseParameters(
        arw=arw,
        bias_instability=float(adev[imin]) / FLICKER_FACTOR,
        rrw=rrw,
        method="lines",
        arw_taus=taus[white_idx].tolist(),
        rrw_taus=taus[rw_idx].tolist(),
        bias_instability_tau=float(taus[imin]),
    )


# The chosen fit must reproduce the data's Allan deviation within this fraction at every
# tau it used, beyond the estimate's own scatter there.
MISFIT_LIMIT = 0.10
# Cluster times with fewer equivalent degrees of freedom are too scattered to judge a fit
# by (relative std of the deviation 1 / sqrt(2 edf) > 16 %).
MISFIT_MIN_EDF = 20.0


def fit_misfit(p: NoiseParameters, result: AllanResult) -> dict[str, float | None]:
    """How far a fit's Allan deviation is from the data's at the taus it used.

    The taus used: every tau for "model"; the white and random-walk line points and
    the minimum for "lines"; those with edf >= MISFIT_MIN_EDF. At each, the relative
    misfit |model / data - 1| less twice the data's relative scatter 1 / sqrt(2 edf)
    (a correct model sits within that of the estimate 95 % of the time). Past the
    curve's minimum the random walk dominates, whose estimate has far fewer degrees of
    freedom than white noise's (NIST SP 1065, Table 5); there edf = N / (2 m) is used
    (white noise: ~1.5 N / m), which covers the scatter seen on simulated white + flicker
    + random walk records (tests/test_noise.py, benchmarks/solvers.py).

    Returns
    -------
    {"misfit_max": the largest relative misfit beyond the scatter (0 if within it),
    "misfit_raw_max": the largest |model / data - 1|, "misfit_tau": its tau, s};
    None values when no used tau has enough degrees of freedom.
    """
    taus = result.taus
    if p.method == "model":
        used = np.ones(taus.size, dtype=bool)
    else:
        picked = set(p.arw_taus) | set(p.rrw_taus) | {p.bias_instability_tau}
        used = np.isin(taus, [t for t in picked if t is not None])
    edf = result.edf.astype(float)
    past_min = np.arange(taus.size) > int(np.argmin(result.adev))
    m = np.round(taus * result.rate_hz)
    edf = np.where(past_min, np.minimum(edf, result.n_samples / (2.0 * m)), edf)
    used &= (edf >= MISFIT_MIN_EDF) & (result.adev > 0)
    if not used.any():
        return {"misfit_max": None, "misfit_raw_max": None, "misfit_tau": None}
    rel = np.abs(p.adev_model(taus[used]) / result.adev[used] - 1.0)
    beyond = np.maximum(rel - 2.0 / np.sqrt(2.0 * edf[used]), 0.0)
    i = int(np.argmax(beyond if beyond.max() > 0 else rel))
    return {
        "misfit_max": float(beyond.max()),
        "misfit_raw_max": float(rel.max()),
        "misfit_tau": float(taus[used][i]),
    }


def choose_noise_fit(
    result: AllanResult, preferred: str = "model"
) -> tuple[NoiseParameters, dict[str, float | None], str | None]:
    """The noise fit of one channel that reproduces its Allan curve, or a warning.

    The preferred method is taken when its misfit (`fit_misfit`) is within MISFIT_LIMIT;
    else the other method when it is; else the one with the smaller misfit, with a
    warning. (A three-term model cannot follow a curve whose flat region is not flat,
    e.g. flicker over many decades; the IEEE 952 line reading then still can.)

    Returns
    -------
    (parameters, misfit of the chosen fit (with "tried": the misfits of both), warning
    or None).
    """
    other = "lines" if preferred == "model" else "model"
    fits = {}
    for method in (preferred, other):
        try:
            with np.errstate(divide="ignore", invalid="ignore"):  # log 0 of a constant channel
                fits[method] = noise_parameters(result, method=method)
        except ValueError:
            continue  # "lines" needs >= 3 taus
    misfits = {m: fit_misfit(p, result) for m, p in fits.items()}

    def score(m: str) -> float:
        v = misfits[m]["misfit_max"]
        return -1.0 if v is None else v

    ok = [m for m in fits if score(m) <= MISFIT_LIMIT]
    chosen = ok[0] if ok else min(fits, key=score)
    record = {**misfits[chosen], "tried": {m: misfits[m]["misfit_max"] for m in fits}}
    warning = None
    if not ok:
        warning = (
            f"noise fit: no method reproduces the Allan deviation within "
            f"{100 * MISFIT_LIMIT:.0f} % (beyond its scatter); {chosen!r} is off by "
            f"{100 * score(chosen):.0f} % at tau = {misfits[chosen]['misfit_tau']:g} s: "
            "the noise parameters are not a description of this curve"
        )
    return fits[chosen], record, warning


NOISE_TERMS = ("arw", "bias_instability", "rrw")
NOT_DETERMINED = "not determined"


def archived_terms(
    p: NoiseParameters, result: AllanResult, described: bool, varies: bool = True
) -> dict[str, float | str | None]:
    """The three noise terms as the archive keeps them: never 0, each with its method.

    A fit's 0 is not a measurement: the term was below what the curve resolves, or the
    model could not place it. Where the fit describes the curve (`described`), a term
    it found is kept ("<method> fit"); a term it put at 0 is read from the curve as the
    upper bound the curve sets on it. Where it does not describe the curve, every term
    is read from the curve (IEEE Std 952): N on the slope -1/2 line at tau = 1 s, B as
    the minimum of the deviation / 0.664, K on the slope +1/2 line at tau = 3 s, or the
    bound where the curve has no such region. A channel that does not vary gives no
    reading: None, "not determined".

    Parameters
    ----------
    p : the chosen fit (`choose_noise_fit`).
    result : the channel's Allan deviation.
    described : the fit reproduces the curve (no misfit warning).
    varies : False for a channel whose samples do not vary beyond rounding (its Allan
        deviation is rounding error): every term None, "not determined".

    Returns
    -------
    {"arw": value or None, "arw_method": text, "bias_instability": ..., "rrw": ...}.
    """
    lines = None
    if not described and result.taus.size >= 3:
        with np.errstate(divide="ignore", invalid="ignore"):
            lines = noise_parameters(result, method="lines")
    out: dict[str, float | str | None] = {}
    for term in NOISE_TERMS:
        if not varies:
            out[term], out[f"{term}_method"] = None, f"{NOT_DETERMINED}: the channel does not vary"
            continue
        fitted = float(getattr(p, term))
        if described and fitted > 0 and math.isfinite(fitted):
            value, method = fitted, f"{p.method} fit"
        else:
            value, method = _curve_reading(term, result, lines)
            if described:
                method += f" (the {p.method} fit puts it at 0)"
        out[term], out[f"{term}_method"] = value, method
    return out


def _curve_reading(
    term: str, result: AllanResult, lines: NoiseParameters | None
) -> tuple[float | None, str]:
    """One term read from the Allan curve: its IEEE 952 line where `lines` found one, else
    the upper bound the curve sets; (None, "not determined ...") for a curve of zeros."""
    taus, adev = result.taus, result.adev
    if lines is not None and term == "arw" and lines.arw > 0:
        return float(lines.arw), "slope -1/2 line read at tau = 1 s (IEEE 952)"
    if lines is not None and term == "rrw" and lines.rrw > 0:
        return float(lines.rrw), "slope +1/2 line read at tau = 3 s (IEEE 952)"
    if term == "arw":
        value = float(adev[0] * math.sqrt(taus[0]))
        method = "upper bound: ADEV at the shortest tau x sqrt(tau)"
    elif term == "bias_instability":
        value = float(adev.min()) / FLICKER_FACTOR
        method = "min of ADEV / 0.664 (IEEE 952; an upper bound)"
    else:
        value = float(adev[-1] * math.sqrt(3.0 / taus[-1]))
        method = "upper bound: ADEV at the longest tau x sqrt(3 / tau)"
    if not (value > 0 and math.isfinite(value)):
        return None, f"{NOT_DETERMINED}: the channel's Allan deviation is 0"
    return value, method


# --- converters to the units datasheets use ---------------------------------
_DEG = 180.0 / math.pi


def arw_to_deg_per_sqrt_h(arw: float) -> float:
    """rad/s/sqrt(Hz) (= rad/sqrt(s)) -> deg/sqrt(h)."""
    return arw * _DEG * 60.0


def rate_to_deg_per_h(rate: float) -> float:
    """rad/s -> deg/h (bias, bias instability)."""
    return rate * _DEG * 3600.0


def rrw_to_deg_per_h_per_sqrt_h(rrw: float) -> float:
    """rad/s/sqrt(s) -> deg/h/sqrt(h)."""
    return rrw * _DEG * 3600.0 * 60.0
