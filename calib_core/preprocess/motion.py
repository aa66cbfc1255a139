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
from collections.abc import Callable, Iterable

import numpy as np

from calib_core.distributions import chi2_ppf, f_ppf
from calib_core.recording import Recording
from calib_core.stats import centred_iats, white_rho1_limit

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


def motion_width(n: int | None, rate: float) -> int:
    """Samples a window of a record of `n` samples at `rate` Hz: MOTION_WINDOW_S, shorter
    in a short record (a face held 5 s still gets 16 windows); n None: a record long
    enough for MOTION_WINDOW_S (its length not known yet)."""
    width = int(round(MOTION_WINDOW_S * rate))
    return max(MIN_WINDOW_SAMPLES, width if n is None else min(width, n // 16))


def window_statistics(x: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Each whole window of `width` rows of x (n, C): (K, C) variance about the window's
    mean, its SPIKE_TRIM farthest samples from the window's median left out (an isolated
    spike is no motion; the quiet reference is trimmed alike, so the ratio stays ~1 when
    still), and (K, C) integrated autocorrelation time, samples.

    The median is ``np.median``'s. Samples tied at the trim's threshold (quantised data:
    +d and -d from the median) are left out latest first: of the samples whose distance
    from the median equals the threshold, the earliest are kept, as many as the window
    keeps. A window holding a non-finite value: variance and time NaN.

    Local to each window: a record pushed in chunks of whole windows gives the same rows.
    Compiled per window (`motion_windows`); only the windows whose lag-1 autocorrelation
    is not white noise's get their time from `centred_iats`'s FFT.
    """
    from calib_core.preprocess.motion_windows import trimmed_windows  # Numba: when used

    k = x.shape[0] // width
    channels = x.shape[1]
    trim = max(1, int(math.ceil(SPIKE_TRIM * width)))
    med, var = np.empty((k, channels)), np.empty((k, channels))
    white = np.empty((k, channels), dtype=bool)
    rows = np.ascontiguousarray(x[: k * width], dtype=float)
    trimmed_windows(rows, width, trim, white_rho1_limit(width), med, var, white)
    iat = np.ones((k, channels))
    if width >= 8:
        win, ch = np.nonzero(~white)
        if win.size:
            # (m, width) deviations from the median, centred on their mean
            d = rows.reshape(k, width, channels)[win, :, ch] - med[win, ch, None]
            d -= d.mean(axis=1, keepdims=True)
            iat[win, ch] = centred_iats(d)
    return var, iat


def smallest_steps(x: np.ndarray) -> np.ndarray:
    """(C,) smallest difference between distinct values of each column of x, inf if none."""
    out = np.full(x.shape[1], math.inf)
    for c in range(x.shape[1]):
        steps = np.diff(np.unique(x[:, c]))
        if steps.size:
            out[c] = steps.min()
    return out


def quantisation_variance(steps: np.ndarray) -> np.ndarray:
    """(C,) variance of rounding to each channel's smallest step (Delta^2 / 12), 0 if none."""
    steps = np.asarray(steps, dtype=float)
    return np.where(np.isfinite(steps), steps**2 / 12.0, 0.0)


def quiet_noise(var: np.ndarray, iat: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The noise variance of each channel from its quietest quarter of windows, and the
    windows' degrees of freedom: ((C,) variance, (C,) nu), from `window_statistics`."""
    windows = var.shape[0]
    n_quiet = max(2, int(math.ceil(QUIET_FRACTION * windows)))
    quiet = np.argsort(var, axis=0)[:n_quiet]
    noise, nus = np.empty(var.shape[1]), np.empty(var.shape[1])
    for c in range(var.shape[1]):
        # Degrees of freedom: correlated noise (a low-pass) holds fewer than samples - 1.
        tau = float(np.median(iat[quiet[:, c], c]))
        nu = max((width - 1) / max(tau, 1.0), 1.0)
        # The quietest quarter's mean variance is biased low: divide by the mean of the
        # lowest quarter of chi2(nu) / nu, taken as its quantile at QUIET_FRACTION / 2.
        low = chi2_ppf(QUIET_FRACTION / 2.0, nu) / nu
        noise[c], nus[c] = float(var[quiet[:, c], c].mean()) / low, nu
    return noise, nus


def motion_from_windows(
    var: np.ndarray,
    iat: np.ndarray,
    q_var: np.ndarray,
    width: int,
    rate: float,
    starts: np.ndarray,
) -> dict | None:
    """`motion_statistics` from the windows' statistics (`window_statistics`), the
    channels' quantisation variance (C,) and the windows' start times (K,), s from the
    record's first sample."""
    windows, channels = var.shape
    if windows < MIN_WINDOWS:
        return None
    names = [f"{s}.{a}" for s in ("gyr", "acc") for a in "xyz"]
    n_quiet = max(2, int(math.ceil(QUIET_FRACTION * windows)))
    noise, nus = quiet_noise(var, iat, width)
    limits = np.empty(channels)
    ratios = np.empty((windows, channels))
    for c in range(channels):
        ref = max(noise[c], q_var[c])
        if ref <= 0.0:
            ratios[:, c] = 0.0  # a channel that does not vary cannot show motion
            limits[c] = math.inf
            continue
        ratios[:, c] = var[:, c] / ref
        alpha = MOTION_ALPHA / (windows * channels)
        limits[c] = max(f_ppf(1.0 - alpha, nus[c], nus[c] * n_quiet), MOTION_MIN_RATIO)
    if not np.isfinite(limits).any():
        return None
    excess = ratios / limits[None, :]
    k, c = np.unravel_index(int(np.argmax(excess)), excess.shape)
    return {
        "ratio": float(ratios[k, c]),
        "limit": float(limits[c]),
        "channel": names[c],
        "t_s": float(starts[k]),
        "window_s": width / rate,
    }


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
    width = motion_width(n, rate)
    windows = n // width
    if windows < MIN_WINDOWS:
        return None
    x = np.hstack([np.asarray(rec.gyr, dtype=float), np.asarray(rec.acc, dtype=float)])
    var, iat = window_statistics(x, width)  # (K, 6) each
    starts = rec.t[: windows * width : width] - rec.t[0]
    q_var = quantisation_variance(smallest_steps(x))
    return motion_from_windows(var, iat, q_var, width, rate, starts)


class StreamedMotion:
    """`motion_statistics` of a record pushed in chunks of [gyr | acc] rows (any sizes):
    the windows' statistics as the record arrives (the rows of a window split by a chunk's
    end carried to the next), (K, C) arrays of a few floats per second of record.

    Parameters
    ----------
    n : the record's samples; None while they are not known (a record's first pass): the
        window is then a long record's (`motion_width`), every whole window pushed is kept,
        and `settle` says at the end whether they are the record's windows.
    rate : the record's median sample rate, Hz (provisional when n is None).
    channels : columns of the rows pushed.

    The quantisation variance needs the record's smallest step between distinct values,
    which no chunk holds (neighbouring values may fall in different chunks). A sample of
    each chunk's rows gives an upper bound on it (fewer values: steps no smaller); when the
    bound's variance is within the quiet noise, the reference max(noise, Delta^2 / 12) is
    the noise whatever the exact step, so the check is the in-memory one. Only a channel
    where it is not asks for the exact steps (`result`'s `exact_steps`: a pass over the
    record, `streamed_smallest_steps`).
    """

    SAMPLE_ROWS = 4096  # rows of each chunk whose steps bound the record's smallest step
    WINDOW_ROWS = 1 << 16  # rows of whole windows whose statistics are taken at once

    def __init__(self, n: int | None, rate: float, channels: int = 6) -> None:
        self.rate = rate
        self.width = motion_width(n, rate)
        self.windows = None if n is None else n // self.width
        self.rows = 0  # rows pushed
        self._rest = np.empty((0, channels))
        self._rest_t = np.empty(0)
        self._t0: float | None = None
        self._var: list[np.ndarray] = []
        self._iat: list[np.ndarray] = []
        self._starts: list[np.ndarray] = []
        self._done = 0
        self.steps_bound = np.full(channels, math.inf)

    def push(self, t: np.ndarray, x: np.ndarray) -> None:
        """Take the next rows: t (m,) s, x (m, C)."""
        self.rows += x.shape[0]
        if x.shape[0] == 0 or (self.windows is not None and self.windows < MIN_WINDOWS):
            return
        stride = max(1, x.shape[0] // self.SAMPLE_ROWS)
        np.minimum(self.steps_bound, smallest_steps(x[::stride]), out=self.steps_bound)
        if self._t0 is None:
            self._t0 = float(t[0])
        if self._rest.shape[0]:  # first the window split by the previous chunk's end
            need = self.width - self._rest.shape[0]
            head_t = np.concatenate([self._rest_t, t[:need]])
            head_x = np.concatenate([self._rest, x[:need]])
            t, x = t[need:], x[need:]
            self._whole_windows(head_t, head_x)
            if x.shape[0] == 0:
                return
        self._whole_windows(t, x)

    def _whole_windows(self, t: np.ndarray, x: np.ndarray) -> None:
        """The statistics of the whole windows at the front of rows t (m,), x (m, C)
        (WINDOW_ROWS at a time: bounded temporaries), the rows after them kept for the
        next push (none after the record's last window)."""
        k = x.shape[0] // self.width
        if self.windows is not None:
            k = min(k, self.windows - self._done)
        step = max(1, self.WINDOW_ROWS // self.width)
        for a in range(0, k, step):
            rows = slice(a * self.width, min(a + step, k) * self.width)
            var, iat = window_statistics(x[rows], self.width)
            self._var.append(var)
            self._iat.append(iat)
            self._starts.append(t[rows][:: self.width] - self._t0)
        self._done += k
        rest = k * self.width if self._done != self.windows else x.shape[0]
        self._rest, self._rest_t = x[rest:].copy(), t[rest:].copy()

    def settle(self, n: int, rate: float) -> bool:
        """Whether the windows pushed are those of ``StreamedMotion(n, rate)`` given the
        same rows: the record's `n` samples all pushed and its window (`motion_width` at
        its median rate, Hz) the one used. If so, the record's n and rate are taken for
        `result`; if not (a short record, a first chunk whose steps were not the
        record's), the windows must be computed again at the record's width."""
        if self.rows != n or motion_width(n, rate) != self.width:
            return False
        self.rate, self.windows = rate, n // self.width
        return True

    def result(self, exact_steps: Callable[[np.ndarray], np.ndarray]) -> dict | None:
        """`motion_statistics` of the record pushed. exact_steps(channels) -> the record's
        smallest steps of those channels (an index array), called only when needed."""
        if self.windows is None:
            raise ValueError("motion: the record's length is not known (settle first)")
        if self.windows < MIN_WINDOWS:
            return None
        if self._done != self.windows:
            raise ValueError(f"motion: {self._done} of {self.windows} windows pushed")
        var, iat = np.concatenate(self._var), np.concatenate(self._iat)
        q_var = quantisation_variance(self.steps_bound)
        noise, _ = quiet_noise(var, iat, self.width)
        need = np.nonzero(~(q_var <= noise))[0]
        if need.size:
            q_var[need] = quantisation_variance(exact_steps(need))
        return motion_from_windows(
            var, iat, q_var, self.width, self.rate, np.concatenate(self._starts)
        )


def streamed_smallest_steps(columns: Iterable[np.ndarray]) -> np.ndarray:
    """`smallest_steps` of a record's columns (m, C') given in chunks: the distinct values
    seen so far merged with each chunk's (what a quantised channel has is a short grid)."""
    seen: np.ndarray | None = None
    for x in columns:
        distinct = [np.unique(x[:, c]) for c in range(x.shape[1])]
        if seen is not None:
            distinct = [np.union1d(a, b) for a, b in zip(seen, distinct, strict=True)]
        seen = distinct
    if seen is None:
        return np.empty(0)
    out = np.full(len(seen), math.inf)
    for c, values in enumerate(seen):
        if values.size > 1:
            out[c] = np.diff(values).min()
    return out


def motion_check(label: str, rec: Recording) -> dict | None:
    """The ``motion:<label>`` check of one static record (CheckResult fields), or None
    when the record is too short to judge (fewer than MIN_WINDOWS windows)."""
    return motion_check_of(label, motion_statistics(rec))


def motion_check_of(label: str, st: dict | None) -> dict | None:
    """The ``motion:<label>`` check (CheckResult fields) of `motion_statistics`' result,
    None for None."""
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
    return motion_checks(segments, static_labels(static_segments, segments))


def static_labels(static_segments: str, labels) -> list[str]:
    """The labels among `labels` a procedure holds still, by its
    `Procedure.static_segments`: "all", "all but turns" or "none"."""
    if static_segments == "none":
        return []
    if static_segments not in ("all", "all but turns"):
        raise ValueError(
            f"static_segments: expected 'all', 'all but turns' or 'none', got {static_segments!r}"
        )
    return [label for label in labels if static_segments == "all" or not is_rotation(label)]
