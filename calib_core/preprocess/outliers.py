"""Outlier (spike) removal on static segments, per channel.

Three detectors, all returning a boolean mask of the flagged samples:

- `sigma_mask`: iterative n-sigma clipping about the mean (methods.md: 3-sigma).
- `grubbs_mask`: Grubbs' two-sided test at significance `alpha`, iterated,
  applied in blocks of `window` samples (the test's critical value grows with
  the sample count, so a block keeps its power against single spikes).
- `hampel_mask`: Hampel filter, |x - rolling median| > n_sigma * 1.4826 * rolling
  MAD; robust for heavy-tailed data and slowly varying signals.

They assume the signal is constant plus noise inside the stretch they see, so
apply them to static segments (or rate plateaus), never across a rotation.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import stats
from scipy.ndimage import median_filter

from calib_core.calibration import StepRecord
from calib_core.recording import Recording

MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): MAD of a Gaussian -> its std
METHODS = ("sigma", "grubbs", "hampel")
POLICIES = ("delete", "interpolate")


def sigma_mask(x: np.ndarray, n_sigma: float = 3.0, max_iter: int = 20) -> np.ndarray:
    """Iterative n-sigma clipping.

    Repeats: flag |x - mean| > n_sigma * std over the samples not yet flagged,
    until nothing new is flagged.

    Parameters
    ----------
    x : (N,) samples of one channel.
    n_sigma : threshold in standard deviations. Note: on pure Gaussian noise
        3-sigma flags 0.27 % of the samples (2 * Q(3)); 3.5 flags 0.05 %.

    Returns
    -------
    (N,) bool, True for outliers.
    """
    x = np.asarray(x, dtype=float)
    flagged = np.zeros(x.size, dtype=bool)
    for _ in range(max_iter):
        good = x[~flagged]
        if good.size < 3:
            break
        new = np.abs(x - good.mean()) > n_sigma * good.std(ddof=1)
        if np.array_equal(new | flagged, flagged):
            break
        flagged |= new
    return flagged


def grubbs_critical(n: np.ndarray | int, alpha: float) -> np.ndarray:
    """Two-sided Grubbs critical value G_crit for n samples at significance alpha.

    G_crit = (n-1)/sqrt(n) * sqrt(t^2 / (n - 2 + t^2)), t = t_{1 - alpha/(2n), n-2}.
    """
    n = np.asarray(n, dtype=float)
    t = stats.t.isf(alpha / (2.0 * n), n - 2.0)
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
    x = np.asarray(x, dtype=float)
    if window < 3:
        raise ValueError(f"hampel_mask: window must be >= 3 samples, got {window}")
    largest_odd = x.size if x.size % 2 else x.size - 1
    window = min(window | 1, largest_odd)  # median_filter wants an odd size <= N
    med = median_filter(x, size=window, mode="nearest")
    dev = np.abs(x - med)
    mad = median_filter(dev, size=window, mode="nearest")
    return dev > n_sigma * MAD_TO_SIGMA * mad


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

    arrays = {name: np.array(getattr(rec, name), dtype=float) for name in channels}
    masks = {
        name: np.column_stack(
            [
                detect_outliers(a[:, i], method, n_sigma=n_sigma, alpha=alpha, window=window)
                for i in range(3)
            ]
        )
        for name, a in arrays.items()
    }
    per_channel = {
        f"{name}.{axis}": np.flatnonzero(m[:, i]).tolist()
        for name, m in masks.items()
        for i, axis in enumerate("xyz")
    }
    if policy == "delete":
        any_bad = np.zeros(len(rec), dtype=bool)
        for m in masks.values():
            any_bad |= m.any(axis=1)
        out = rec.select(~any_bad)
        n_rows = int(any_bad.sum())
    else:
        for name, a in arrays.items():
            for i in range(3):
                m = masks[name][:, i]
                if m.any() and not m.all():
                    a[m, i] = np.interp(rec.t[m], rec.t[~m], a[~m, i])
        out = replace(rec, **arrays)
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
            "flagged_indices": per_channel,
            "n_rows_deleted": n_rows,
        },
    )
    return out, record
