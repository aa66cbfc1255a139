"""The motion check's per-window statistics, compiled: median, trimmed variance, lag-1 test.

Each window of each channel needs its median, the variance of its samples less the
few farthest from that median, and its lag-1 autocorrelation (the white-noise test of
`calib_core.stats.centred_iats`). In NumPy that is a partition for the median, an
argpartition of the distances for the trim, gathers and several passes over a copy of
the windows, the bulk of the motion check's cost in a long record's first pass. Here one
compiled loop per window does it from a few kilobytes of scratch that stay in cache. A
selection (the median; the trim's threshold, the keep-th smallest distance from it)
samples every STEP-th value to bracket the order statistic it wants, gathers the values
within the bracket in one branch-free pass, and quickselects among those few (a noisy
window's comparisons are coin flips: the partitions are branch-free too); when the
bracket misses (a sample far in its tail, a pattern of period STEP) it selects among
all. The order statistics are exact: the median is ``np.median``'s. No library offers a
trimmed variance by windows, so it is written here, compiled by Numba (`cache=True`:
once per installation); the rare windows whose lag-1 test fails get their
autocorrelation time from `centred_iats`'s FFT in NumPy (the caller's part).

Summation: the sums over a window (about its median) are vectorised (the order of the
additions is the processor's vector width's), the kept sums' last few terms added in
time order; each within (width - 1) eps of the sum of its terms' magnitudes. The lag-1
test takes the centred sums from those about the median (it decides only which windows
get the FFT, within rounding of NumPy's at its limit).
"""

from __future__ import annotations

import numba
import numpy as np

STEP = 8  # every STEP-th value of a window samples it for a selection's bracket


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _below_first(a: np.ndarray, lo: int, hi: int, pivot: float, ties: bool) -> int:
    """Move the values of a[lo:hi] below pivot (at or below: ties) to its front; returns
    the end of them. Branch-free (Lomuto's scheme, the end advanced by the comparison):
    a noisy window's comparisons are coin flips a branch would mispredict."""
    i = lo
    if ties:
        for j in range(lo, hi):
            v = a[j]
            a[j] = a[i]
            a[i] = v
            i += v <= pivot
    else:
        for j in range(lo, hi):
            v = a[j]
            a[j] = a[i]
            a[i] = v
            i += v < pivot
    return i


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _select(a: np.ndarray, n: int, k: int) -> float:
    """The k-th smallest (0-based) of a[:n] of finite values, a reordered in place so
    that a[:k] <= a[k] (quickselect, median-of-three pivot)."""
    lo, hi = 0, n  # k's value is among a[lo:hi]
    while hi - lo > 1:
        x, y, z = a[lo], a[(lo + hi) >> 1], a[hi - 1]
        pivot = max(min(x, y), min(max(x, y), z))
        below = _below_first(a, lo, hi, pivot, False)
        if k < below:
            hi = below
        elif below > lo:
            lo = below
        else:  # the pivot is the least: its ties split off (a run of equal values ends)
            upto = _below_first(a, lo, hi, pivot, True)  # a[lo:upto] == pivot
            if k < upto:
                return pivot
            lo = upto
    return a[k]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _bracket(sample: np.ndarray, s: int, k: int, n: int) -> tuple[float, float]:
    """Two values of sample[:s] (s of n values, reordered) that bracket the n values'
    k-th smallest: the sample's order statistics at k's expected rank +-3 standard
    deviations (and 2); beyond the sample's ends, -inf or inf (all values that side)."""
    p = (k + 0.5) / n
    r = p * s
    margin = 3.0 * np.sqrt(s * p * (1.0 - p)) + 2.0
    rl, rh = int(r - margin), int(r + margin) + 1
    high, top = np.inf, s
    if rh < s - 1:
        high, top = _select(sample, s, rh), rh  # sample[:rh] <= high
    low = _select(sample, top, rl) if rl > 0 else -np.inf
    return low, high


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _median(col: np.ndarray, g: np.ndarray, buf: np.ndarray) -> float:
    """``np.median`` of the finite values col (n,); g and buf scratch of n.

    Every STEP-th value brackets the middle between two of them, a branch-free pass
    gathers the values between the two (some 3 sqrt(n STEP) of them) and counts those
    below, and only those few are selected; when the bracket misses (a sample's tail),
    the whole of col is.
    """
    n = col.size
    k = n // 2
    lower = n % 2 == 0  # the two middle values averaged
    s = (n + STEP - 1) // STEP
    m, j = 0, -1
    if s >= 16:
        for i in range(s):
            buf[i] = col[i * STEP]
        low, high = _bracket(buf, s, k, n)
        below = 0
        for i in range(n):
            x = col[i]
            g[m] = x
            below += x < low
            m += (x >= low) & (x <= high)
        j = k - below
    if not ((1 if lower else 0) <= j < m):
        for i in range(n):
            g[i] = col[i]
        m, j = n, k
    for i in range(m):
        buf[i] = g[i]
    upper = _select(buf, m, j)
    if not lower:
        return upper
    # the other middle value: the largest below the upper, or the upper if tied there
    count, largest = 0, -np.inf
    for i in range(m):
        x = g[i]
        b = x < upper
        count += b
        largest = max(largest, x if b else -np.inf)
    return ((largest if count >= j else upper) + upper) / 2.0


@numba.njit(cache=True, nogil=True, boundscheck=False, fastmath={"reassoc"})
def _moments(
    col: np.ndarray, med: float, low: float
) -> tuple[float, float, float, float, float, int]:
    """Sums over col (n,) about med: (d, d^2, d[i-1] d[i], d and d^2 of the samples
    closer than `low`, their count), d = col - med. Vectorised: the order of the
    additions is the processor's vector width's."""
    total, sq, lag, s1, s2, below = 0.0, 0.0, 0.0, 0.0, 0.0, 0
    for i in range(col.size):
        d = col[i] - med
        total += d
        sq += d * d
        inside = abs(d) < low
        s1 += d if inside else 0.0
        s2 += d * d if inside else 0.0
        below += inside
    for i in range(1, col.size):
        lag += (col[i - 1] - med) * (col[i] - med)
    return total, sq, lag, s1, s2, below


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _window(
    col: np.ndarray, scratch: np.ndarray, trim: int, white_limit: float
) -> tuple[float, float, bool]:
    """One window's (median, trimmed variance, white) of the finite samples col (n,);
    scratch (2, n).

    The trim's threshold (the keep-th smallest distance from the median) is bracketed as
    the median is (`_median`); one pass takes the moments about the median, the kept
    sums of the samples closer than the bracket and gathers the samples within it, in
    time order; the threshold and the rest of the kept sums come from those few.
    """
    g, buf = scratch[0], scratch[1]
    n = col.size
    med = _median(col, g, buf)
    keep = n - trim
    k = keep - 1  # the threshold's rank among the distances
    s = (n + STEP - 1) // STEP
    low, high = -1.0, np.inf  # no sample: all gathered
    if s >= 16:
        for i in range(s):
            buf[i] = abs(col[i * STEP] - med)
        low, high = _bracket(buf, s, k, n)
    total, sq, lag, s1, s2, below = _moments(col, med, low)
    m = 0
    for i in range(n):
        d = col[i] - med
        g[m] = d
        a = abs(d)
        m += (a >= low) & (a <= high)
    j = k - below
    if not (0 <= j < m):  # the bracket missed: all samples
        s1, s2, below, m, j = 0.0, 0.0, 0, n, k
        for i in range(n):
            g[i] = col[i] - med
    for i in range(m):
        buf[i] = abs(g[i])
    thr = _select(buf, m, j)
    closer = 0
    for i in range(m):
        closer += abs(g[i]) < thr
    ties = keep - below - closer  # of the samples at the threshold, the earliest kept
    for i in range(m):
        d = g[i]
        a = abs(d)
        if a < thr or (a == thr and ties > 0):
            ties -= a == thr
            s1 += d
            s2 += d * d
    var = max(s2 - s1 * s1 / keep, 0.0) / (keep - 1)
    # lag-1 autocorrelation about the mean from the sums about the median
    mean = total / n
    sum_sq = sq - total * mean
    lag_c = lag - mean * (2.0 * total - (col[0] - med) - (col[n - 1] - med)) + (n - 1) * mean * mean
    white = sq == 0.0 or abs(lag_c) < white_limit * sum_sq
    return med, var, white


@numba.njit(cache=True, nogil=True, boundscheck=False)
def trimmed_windows(
    x: np.ndarray,
    width: int,
    trim: int,
    white_limit: float,
    med: np.ndarray,
    var: np.ndarray,
    white: np.ndarray,
) -> None:
    """Fill med, var (K, C) float and white (K, C) bool for each whole window of `width`
    rows of x (n, C), K = n // width: the window's median (as ``np.median``), the
    variance about their mean of its samples less the `trim` farthest from that median
    (ties at the threshold: the later ones left out), and whether its lag-1
    autocorrelation about its mean is within +-white_limit (or the window constant). A
    window holding a non-finite value: med, var NaN, white False."""
    k = x.shape[0] // width
    channels = x.shape[1]
    cols = np.empty((channels, width))
    scratch = np.empty((2, width))
    check = np.empty(channels)
    for w in range(k):
        base = w * width
        check[:] = 0.0
        for i in range(width):
            for c in range(channels):
                v = x[base + i, c]
                cols[c, i] = v
                check[c] += v * 0.0  # NaN if any value is not finite
        for c in range(channels):
            if np.isnan(check[c]):
                med[w, c] = np.nan
                var[w, c] = np.nan
                white[w, c] = False
                continue
            med[w, c], var[w, c], white[w, c] = _window(cols[c], scratch, trim, white_limit)
