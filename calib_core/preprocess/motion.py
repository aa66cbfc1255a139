"""Motion in a static record: scatter far above the noise the record shows at its quietest.

A static position's numbers (biases, the accelerometer fit) assume the unit was still.
A record that moves (a vehicle driving, a hand-held "static", a turn in the middle)
shows it as windows whose scatter is far above that of the record's quietest windows,
on the gyro or the accelerometer. The check cuts the record into windows of
MOTION_WINDOW_S (or a 16th of a shorter record), takes the noise variance from its
quietest quarter of windows, and tests every window of every channel against it at a
false-alarm rate of MOTION_ALPHA per record (Bonferroni over windows and channels);
"far above" also asks for MOTION_MIN_RATIO times the quiet variance. A window's
variance is about its own mean, so a slow drift of the bias is no motion, and leaves
out its 2 % of samples farthest from its median, so an isolated spike is none either
(motion lasts).

Under still white noise a window's variance over the quiet variance follows about
F(nu, nu_ref), the trimming narrowing both alike (which makes the limit conservative):
nu the window's degrees of freedom (its samples less one, divided by the noise's
integrated autocorrelation time, so a low-passed record is judged by the information it
holds), nu_ref those of the quiet reference.
"""

from __future__ import annotations

import math

import numpy as np

from calib_core.distributions import chi2_ppf, f_ppf
from calib_core.recording import Recording
from calib_core.stats import integrated_autocorrelation_time

CHECK_PREFIX = "motion:"
MOTION_ALPHA = 1e-3  # probability that a still record fails, all windows and channels
MOTION_WINDOW_S = 1.0
MIN_WINDOW_SAMPLES = 16
MIN_WINDOWS = 8  # fewer: the record is too short to know its quiet noise from its motion
QUIET_FRACTION = 0.25
# "Far above" the quiet noise: at least an order of magnitude in variance (3.2 x the
# std) besides the statistical limit. A still unit's noise is not quite stationary (a
# lab bench vibrates at times: imucal's example session doubles its accelerometer std for
# 0.3 s while its gyro stays at noise); a unit that moves scatters 100 to 10^4 times its
# noise variance (a vehicle's gyro at 0.05 rad/s, a hand's tremor at ~1 deg/s).
MOTION_MIN_RATIO = 10.0
# Fraction of each window's samples farthest from its median left out of its variance.
SPIKE_TRIM = 0.02


def _window_variances(x: np.ndarray, width: int) -> np.ndarray:
    """(K, C) variance of each whole window of `width` rows about its own mean, its
    SPIKE_TRIM farthest samples from the window's median left out: an isolated spike is
    no motion (the quiet reference is trimmed alike, so the ratio stays ~1 when still)."""
    k = x.shape[0] // width
    w = x[: k * width].reshape(k, width, -1)
    dev = np.abs(w - np.median(w, axis=1, keepdims=True))
    drop = max(1, int(math.ceil(SPIKE_TRIM * width)))
    keep = np.argsort(dev, axis=1)[:, : width - drop, :]
    return np.take_along_axis(w, keep, axis=1).var(axis=1, ddof=1)


def _quantisation_variance(x: np.ndarray) -> np.ndarray:
    """(C,) variance of rounding to the channel's smallest step (Delta^2 / 12), 0 if none."""
    out = np.zeros(x.shape[1])
    for c in range(x.shape[1]):
        steps = np.abs(np.diff(np.unique(x[:, c])))
        if steps.size:
            out[c] = steps.min() ** 2 / 12.0
    return out


def motion_statistics(rec: Recording) -> dict | None:
    """The worst window's scatter over the record's quietest noise, and its limit.

    Returns
    -------
    None for a record too short for MIN_WINDOWS windows or without a varying channel;
    else {"ratio": worst window variance / quiet variance, "limit": the F quantile at
    MOTION_ALPHA, "channel": "gyr.x" ..., "t_s": the worst window's start, s,
    "window_s": its length, s}.
    """
    n = len(rec)
    rate = rec.sample_rate if n > 1 else 0.0
    # 1 s windows, shorter in a short record (a face held 5 s still gets 16 windows).
    width = max(MIN_WINDOW_SAMPLES, min(int(round(MOTION_WINDOW_S * rate)), n // 16))
    windows = n // width
    if windows < MIN_WINDOWS:
        return None
    x = np.hstack([np.asarray(rec.gyr, dtype=float), np.asarray(rec.acc, dtype=float)])
    names = [f"{s}.{a}" for s in ("gyr", "acc") for a in "xyz"]
    var = _window_variances(x, width)  # (K, 6)
    n_quiet = max(2, int(math.ceil(QUIET_FRACTION * windows)))
    order = np.argsort(var, axis=0)
    limits = np.empty(x.shape[1])
    ratios = np.empty((windows, x.shape[1]))
    q_var = _quantisation_variance(x)
    for c in range(x.shape[1]):
        quiet = order[:n_quiet, c]
        # Degrees of freedom: correlated noise (a low-pass) holds fewer than samples - 1.
        tau = np.median(
            [integrated_autocorrelation_time(x[k * width : (k + 1) * width, c]) for k in quiet]
        )
        nu = max((width - 1) / max(float(tau), 1.0), 1.0)
        # The quietest quarter's mean variance is biased low: divide by the mean of the
        # lowest quarter of chi2(nu) / nu, taken as its quantile at QUIET_FRACTION / 2.
        low = chi2_ppf(QUIET_FRACTION / 2.0, nu) / nu
        ref = max(float(var[quiet, c].mean()) / low, q_var[c])
        if ref <= 0.0:
            ratios[:, c] = 0.0  # a channel that does not vary cannot show motion
            limits[c] = math.inf
            continue
        ratios[:, c] = var[:, c] / ref
        nu_ref = nu * n_quiet
        limits[c] = max(
            f_ppf(1.0 - MOTION_ALPHA / (windows * x.shape[1]), nu, nu_ref), MOTION_MIN_RATIO
        )
    if not np.isfinite(limits).any():
        return None
    excess = ratios / limits[None, :]
    k, c = np.unravel_index(int(np.argmax(excess)), excess.shape)
    return {
        "ratio": float(ratios[k, c]),
        "limit": float(limits[c]),
        "channel": names[c],
        "t_s": float(rec.t[k * width] - rec.t[0]),
        "window_s": width / rate,
    }


def motion_check(label: str, rec: Recording) -> dict | None:
    """The ``motion:<label>`` check of one static record (CheckResult fields), or None
    when the record is too short to judge (fewer than MIN_WINDOWS windows)."""
    st = motion_statistics(rec)
    if st is None:
        return None
    passed = st["ratio"] <= st["limit"]
    detail = (
        f"worst {st['window_s']:.3g} s window (at {st['t_s']:.1f} s): {st['channel']} "
        f"variance {st['ratio']:.3g} x the record's quietest noise; limit {st['limit']:.3g} "
        f"(a still record exceeds it with probability < {MOTION_ALPHA:g})"
    )
    if not passed:
        detail += ": the unit moved during this static record; repeat it without motion"
    return {
        "name": f"{CHECK_PREFIX}{label}",
        "value": st["ratio"],
        "limit": st["limit"],
        "passed": bool(passed),
        "detail": detail,
    }


def motion_checks(segments: dict[str, Recording], static: list[str]) -> list[dict]:
    """``motion:<label>`` checks of the named static segments (too-short ones left out)."""
    out = []
    for label in static:
        check = motion_check(label, segments[label])
        if check is not None:
            out.append(check)
    return out


def is_rotation(label: str) -> bool:
    """A turn of the integral method (``x_ccw``, ``z_cw``): not an attitude."""
    return label.endswith(("_cw", "_ccw"))


def static_motion_checks(static_segments: str, segments: dict[str, Recording]) -> list[dict]:
    """``motion:<label>`` checks of a procedure's static segments.

    Parameters
    ----------
    static_segments : the procedure's `Procedure.static_segments`: "all", "all but turns"
        (labels ending ``_cw``/``_ccw`` left out) or "none" (it moves on purpose: no check).
    segments : label -> Recording (SI units).
    """
    if static_segments == "none":
        return []
    if static_segments not in ("all", "all but turns"):
        raise ValueError(
            f"static_segments: expected 'all', 'all but turns' or 'none', got {static_segments!r}"
        )
    static = [label for label in segments if static_segments == "all" or not is_rotation(label)]
    return motion_checks(segments, static)
