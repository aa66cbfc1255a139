"""Outlier (spike) removal on static segments, per channel.

Three detectors, all returning a boolean mask of the flagged samples:

- `sigma_mask`: iterative n-sigma clipping about the mean (docs/methods.md 3.1: 3-sigma).
- `grubbs_mask`: Grubbs' two-sided test at significance `alpha`, iterated,
  applied in blocks of `window` samples (the test's critical value grows with
  the sample count, so a block keeps its power against single spikes).
- `hampel_mask`: Hampel filter, |x - rolling median| > n_sigma * 1.4826 * rolling
  MAD; robust for heavy-tailed data and slowly varying signals.

They assume the signal is constant plus noise inside the stretch they see, so
apply them to static segments (or rate plateaus), never across a rotation.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from calib_core.calibration import StepRecord
from calib_core.distributions import norm_cdf, norm_pdf, norm_sf, t_isf
from calib_core.recording import Recording

MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): MAD of a Gaussian -> its std
METHODS = ("sigma", "grubbs", "hampel")
POLICIES = ("delete", "interpolate")


def sigma_mask(x: np.ndarray, n_sigma: float = 3.0, max_iter: int = 20) -> np.ndarray:
    """Iterative n-sigma clipping, each column on its own.

    Repeats: flag |x - mean| > n_sigma * std over the samples not yet flagged,
    until nothing new is flagged.

    Parameters
    ----------
    x : (N,) samples of one channel, or (N, C) channels cleaned independently.
    n_sigma : threshold in standard deviations. Note: on pure Gaussian noise
        3-sigma flags 0.27 % of the samples (2 * Q(3)); 3.5 flags 0.05 %.
    max_iter : most clipping passes per column.

    Returns
    -------
    bool array of x's shape, True for outliers.
    """
    x = np.asarray(x, dtype=float)
    cols = x.reshape(x.shape[0], -1)
    flagged = np.zeros(cols.shape, dtype=bool)
    if cols.shape[0] >= 3:
        rows = np.ascontiguousarray(cols.T)  # one contiguous row per column of x
        # Centred: the sums in _sigma_clip do not cancel.
        for j, d in enumerate(rows - rows.mean(axis=1, keepdims=True)):
            flagged[_sigma_clip(d, n_sigma, max_iter), j] = True
    return flagged.reshape(x.shape)


def _sigma_clip(d: np.ndarray, n_sigma: float, max_iter: int) -> np.ndarray:
    """Indices flagged by iterative n-sigma clipping of one centred channel (N,), N >= 3.

    A pass moves the mean a little and shrinks the std a little, so samples
    well inside the limit stay unflagged pass after pass. The passes therefore
    run on a small candidate set (samples farther than a radius r from a
    centre c; r starts at n_sigma * std / 2: 13 % of Gaussian noise at 3 sigma)
    and the rest enters only through its sums. A sample with |x - c| <= r has
    |x - mean| <= r + |mean - c|; while that stays within the limit no such
    sample can be flagged, else the candidates are rebuilt (one full pass).
    The result is exactly that of clipping all samples every pass: the flagged
    samples are summed in the same (index) order.
    """
    n_all = d.size
    # einsum, not np.dot: BLAS dot spins up threads, which costs more than the
    # sum itself on a busy machine.
    s1_all, s2_all = float(d.sum()), float(np.einsum("i,i->", d, d))
    std0 = np.sqrt(max(s2_all - s1_all * s1_all / n_all, 0.0) / (n_all - 1))
    centre, radius = 0.0, 0.5 * n_sigma * std0
    cand = np.flatnonzero(np.abs(d) > radius)  # ascending indices into d
    d_cand = d[cand]
    out = np.zeros(cand.size, dtype=bool)  # which candidates are flagged
    n_out = 0
    for _ in range(max_iter):
        v = d_cand[out]
        n = n_all - n_out
        if n < 3:
            break
        s1 = s1_all - v.sum()
        mean = s1 / n
        std = np.sqrt(max(s2_all - np.einsum("i,i->", v, v) - s1 * mean, 0.0) / (n - 1))
        limit = n_sigma * std
        if radius + abs(mean - centre) > limit:
            # A non-candidate could now cross the limit: rebuild the candidates,
            # keeping the flagged ones among them.
            centre, radius = mean, 0.5 * limit
            kept = cand[out]
            cand = np.union1d(np.flatnonzero(np.abs(d - centre) > radius), kept)
            out = np.isin(cand, kept, assume_unique=True)
            d_cand = d[cand]
        # Flags only grow, as in plain clipping.
        out |= np.abs(d_cand - mean) > limit
        count = int(np.count_nonzero(out))
        if count == n_out:
            break
        n_out = count
    return cand[out]


def grubbs_critical(n: np.ndarray | int, alpha: float) -> np.ndarray:
    """Two-sided Grubbs critical value G_crit for n samples at significance alpha.

    G_crit = (n-1)/sqrt(n) * sqrt(t^2 / (n - 2 + t^2)), t = t_{1 - alpha/(2n), n-2}.
    """
    n = np.asarray(n, dtype=float)
    t = t_isf(alpha / (2.0 * n), n - 2.0)
    return (n - 1.0) / np.sqrt(n) * np.sqrt(t * t / (n - 2.0 + t * t))


def grubbs_mask(
    x: np.ndarray, alpha: float = 0.05, window: int | None = 100, max_iter: int = 50
) -> np.ndarray:
    """Iterated two-sided Grubbs test, block by block.

    Each pass computes G_i = |x_i - mean| / std over the samples still in the
    block and flags the samples with G_i > G_crit(n). With one outlier this is
    Grubbs' test; flagging every sample over the limit in one pass (instead of
    one per pass) gives the same result when outliers are many, because the
    mean and std only tighten as outliers leave.

    Parameters
    ----------
    x : (N,) samples of one channel.
    alpha : significance level of each test (false-alarm probability per block
        and pass).
    window : block length in samples (None: the whole array). The expected
        false-positive rate on clean Gaussian data is about alpha / window.

    Returns
    -------
    (N,) bool, True for outliers.
    """
    x = np.asarray(x, dtype=float)
    n_total = x.size
    if window is None or window >= n_total:
        window = n_total
    # N // window blocks of near-equal length (window or a little more), as rows
    # of a 2-D array so each pass tests all blocks at once.
    n_blocks = max(1, n_total // window)
    flagged = np.zeros(n_total, dtype=bool)
    edges = np.linspace(0, n_total, n_blocks + 1).astype(int)
    lengths = np.diff(edges)
    for length in np.unique(lengths):
        starts = edges[:-1][lengths == length]
        if length < 3:
            continue
        idx = starts[:, None] + np.arange(length)[None, :]
        block = x[idx]
        out = np.zeros(block.shape, dtype=bool)
        for _ in range(max_iter):
            w = ~out
            n = w.sum(axis=1)
            mean = np.where(w, block, 0.0).sum(axis=1) / n
            dev = np.where(w, block - mean[:, None], 0.0)
            std = np.sqrt((dev * dev).sum(axis=1) / (n - 1))
            g = np.abs(dev) / np.where(std > 0, std, np.inf)[:, None]
            new = w & (g > grubbs_critical(np.maximum(n, 3), alpha)[:, None]) & (n >= 3)[:, None]
            if not new.any():
                break
            out |= new
        flagged[idx] = out
    return flagged


def hampel_mask(x: np.ndarray, n_sigma: float = 3.0, window: int = 201) -> np.ndarray:
    """Hampel filter: |x - rolling median| > n_sigma * 1.4826 * rolling MAD.

    The rolling MAD is the rolling median of |x - rolling median| (each sample's
    deviation from its own window's median), which keeps both passes to one
    vectorised median filter each.

    Parameters
    ----------
    x : (N,) samples of one channel.
    n_sigma : threshold in (robust) standard deviations.
    window : odd window length in samples; the MAD of w Gaussian samples has a
        relative std of about 1.17 / sqrt(w), so short windows raise the false
        alarms (w = 201: 8 %).

    Returns
    -------
    (N,) bool, True for outliers.
    """
    from scipy.ndimage import median_filter  # slow to import: only where a filter runs

    x = np.asarray(x, dtype=float)
    if window < 3:
        raise ValueError(f"hampel_mask: window must be >= 3 samples, got {window}")
    largest_odd = x.size if x.size % 2 else x.size - 1
    window = min(window | 1, largest_odd)  # median_filter wants an odd size <= N
    med = median_filter(x, size=window, mode="nearest")
    dev = np.abs(x - med)
    mad = median_filter(dev, size=window, mode="nearest")
    return dev > n_sigma * MAD_TO_SIGMA * mad


def false_alarm_rate(
    method: str, n_sigma: float = 3.0, alpha: float = 0.05, window: int | None = None
) -> float:
    """Probability that a detector flags one sample of clean Gaussian noise.

    - sigma: iterated clipping converges where the limit a (in the noise's std) is
      n_sigma times the std of the noise truncated at +-a: a = n_sigma sqrt(v(a)),
      v(a) = 1 - 2 a phi(a) / (2 Phi(a) - 1); then 2 Q(a) (3 sigma: 0.31 %, not 0.27 %).
    - hampel: 2 Q(n_sigma s) averaged over the scatter of the window's MAD scale s
      (relative std 1.17 / sqrt(window)).
    - grubbs: alpha per block of `window` samples: alpha / window.
    """
    if method == "sigma":
        a = float(n_sigma)
        for _ in range(100):
            v = 1.0 - 2.0 * a * float(norm_pdf(a)) / (2.0 * float(norm_cdf(a)) - 1.0)
            a_next = n_sigma * math.sqrt(v)
            if abs(a_next - a) < 1e-12:
                break
            a = a_next
        return 2.0 * float(norm_sf(a))
    if method == "hampel":
        w = 201 if window is None else window
        nodes, weights = np.polynomial.hermite_e.hermegauss(40)
        s = np.maximum(1.0 + 1.17 / math.sqrt(w) * nodes, 1e-3)
        return float(np.sum(weights * 2.0 * norm_sf(n_sigma * s)) / math.sqrt(2.0 * math.pi))
    if method == "grubbs":
        return float(alpha) / (100 if window is None else window)
    raise ValueError(f"unknown outlier method {method!r}; expected one of {', '.join(METHODS)}")


def detect_outliers(
    x: np.ndarray,
    method: str = "sigma",
    *,
    n_sigma: float = 3.0,
    alpha: float = 0.05,
    window: int | None = None,
) -> np.ndarray:
    """Outlier mask of a 1-D channel by the named method (see the module docstring).

    `window` is the block length for Grubbs (default 100) and the rolling window
    for Hampel (default 201); the sigma rule uses the whole array.
    """
    if method == "sigma":
        return sigma_mask(x, n_sigma)
    if method == "grubbs":
        return grubbs_mask(x, alpha, 100 if window is None else window)
    if method == "hampel":
        return hampel_mask(x, n_sigma, 201 if window is None else window)
    raise ValueError(f"unknown outlier method {method!r}; expected one of {', '.join(METHODS)}")


def _interpolate_runs(t: np.ndarray, x: np.ndarray, bad: np.ndarray) -> None:
    """Replace x[bad] (ascending indices) in place by linear interpolation in time
    between the nearest unflagged neighbours (the edge value beyond the first / last one).

    Works on the runs of flagged samples, so the cost grows with the number of
    outliers, not with the length of the record.
    """
    if bad.size == 0 or bad.size == x.size:
        return
    # Runs of consecutive flagged indices: [first, last] of each.
    breaks = np.flatnonzero(np.diff(bad) > 1)
    first = bad[np.concatenate([[0], breaks + 1])]
    last = bad[np.concatenate([breaks, [bad.size - 1]])]
    lo = first - 1  # last good sample before the run (-1: none)
    hi = last + 1  # first good sample after it (N: none)
    lo_ok, hi_ok = lo >= 0, hi < x.size
    lo_c, hi_c = (
        np.where(lo_ok, lo, hi),
        np.where(hi_ok, hi, lo),
    )  # an edge run copies its one neighbour
    run = np.repeat(np.arange(first.size), last - first + 1)
    t0, t1 = t[lo_c][run], t[hi_c][run]
    x0, x1 = x[lo_c][run], x[hi_c][run]
    w = np.where(t1 > t0, (t[bad] - t0) / np.where(t1 > t0, t1 - t0, 1.0), 0.0)
    x[bad] = x0 + w * (x1 - x0)


def remove_outliers(
    rec: Recording,
    method: str = "sigma",
    *,
    n_sigma: float = 3.0,
    alpha: float = 0.05,
    window: int | None = None,
    policy: str = "interpolate",
    channels: tuple[str, ...] = ("acc", "gyr"),
) -> tuple[Recording, StepRecord]:
    """Detect outliers per channel of a static segment and delete or interpolate them.

    Parameters
    ----------
    rec : a static segment (or rate plateau): constant signal plus noise.
    method : "sigma", "grubbs" or "hampel".
    n_sigma, alpha, window : detector settings (see `detect_outliers`).
    policy : "interpolate" replaces a flagged value by linear interpolation in
        time between the nearest unflagged samples of the same channel;
        "delete" drops every sample (row) flagged in any selected channel.
    channels : which of "acc", "gyr" to clean.

    Returns
    -------
    (cleaned recording, StepRecord with counts and sample indices per channel).
    """
    where = rec.source or "recording"
    if method not in METHODS:
        raise ValueError(
            f"remove_outliers ({where}): unknown method {method!r}; expected {METHODS}"
        )
    if policy not in POLICIES:
        raise ValueError(
            f"remove_outliers ({where}): unknown policy {policy!r}; expected {POLICIES}"
        )
    bad_channels = set(channels) - {"acc", "gyr"}
    if bad_channels:
        raise ValueError(f"remove_outliers ({where}): unknown channels {sorted(bad_channels)}")
    if len(rec) < 3:
        raise ValueError(f"remove_outliers ({where}): need >= 3 samples, got {len(rec)}")

    # All selected channels side by side, (N, 3 * len(channels)), so each
    # detector sees every column in one call.
    data = np.hstack([np.asarray(getattr(rec, name), dtype=float) for name in channels])
    names = [f"{name}.{axis}" for name in channels for axis in "xyz"]
    if method == "sigma":
        mask = sigma_mask(data, n_sigma)
    else:
        mask = np.column_stack(
            [
                detect_outliers(data[:, j], method, n_sigma=n_sigma, alpha=alpha, window=window)
                for j in range(data.shape[1])
            ]
        )
    cols, rows = np.nonzero(mask.T)  # channel by channel, sample indices ascending
    ends = np.searchsorted(cols, np.arange(len(names) + 1))
    flagged = [rows[ends[j] : ends[j + 1]] for j in range(len(names))]
    per_channel = {name: bad.tolist() for name, bad in zip(names, flagged, strict=True)}
    if policy == "delete":
        any_bad = mask.any(axis=1)
        out = rec.select(~any_bad)
        n_rows = int(any_bad.sum())
    else:
        for j, bad in enumerate(flagged):
            _interpolate_runs(rec.t, data[:, j], bad)
        out = replace(rec, **{name: data[:, 3 * k : 3 * k + 3] for k, name in enumerate(channels)})
        n_rows = 0
    record = StepRecord(
        name="remove_outliers",
        settings={
            "method": method,
            "n_sigma": n_sigma,
            "alpha": alpha,
            "window": window,
            "policy": policy,
            "channels": list(channels),
        },
        statistics={
            "source": where,
            "n_samples": len(rec),
            "n_flagged": {k: len(v) for k, v in per_channel.items()},
            "p_false_alarm": false_alarm_rate(method, n_sigma, alpha, window),
            "flagged_indices": per_channel,
            "n_rows_deleted": n_rows,
        },
    )
    return out, record
