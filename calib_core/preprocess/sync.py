"""Time alignment of IMU samples with rate-table feedback.

The two logs run on different clocks. We model the table clock against the
IMU clock as a constant offset plus a clock-rate difference (drift):

    t_ref = t_imu + offset_s + drift_ppm * 1e-6 * (t_imu - t0_s)

and estimate both from the signals themselves: the IMU gyro about the table
axis and the table's rate (or the derivative of its angle) are the same motion,
so the lag that maximises their normalised cross-correlation is the local clock
offset. Local offsets measured in windows along the run, refined to sub-sample
precision by a parabola through the correlation peak, are fitted by a straight
line: its value at t0 is the offset and its slope the drift.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.fft import irfft, next_fast_len, rfft

from calib_core.calibration import StepRecord
from calib_core.recording import Recording


@dataclass(frozen=True)
class ClockModel:
    """Table clock as a function of the IMU clock (see module docstring).

    offset_s : t_ref - t_imu at t_imu = t0_s, s.
    drift_ppm : clock-rate difference, parts per million.
    t0_s : IMU time the offset refers to, s.
    residual_ms : RMS of the local offsets about the fitted line, ms (estimates only).
    n_windows : number of windows used in the fit (estimates only).
    """

    offset_s: float
    drift_ppm: float = 0.0
    t0_s: float = 0.0
    residual_ms: float = 0.0
    n_windows: int = 0

    def to_ref(self, t_imu: np.ndarray) -> np.ndarray:
        """Table-clock time of IMU-clock times `t_imu` (any shape), s."""
        return t_imu + self.offset_s + self.drift_ppm * 1e-6 * (np.asarray(t_imu) - self.t0_s)

    def to_imu(self, t_ref: np.ndarray) -> np.ndarray:
        """IMU-clock time of table-clock times `t_ref`, s (inverse of `to_ref`)."""
        k = self.drift_ppm * 1e-6
        return (np.asarray(t_ref) - self.offset_s + k * self.t0_s) / (1.0 + k)


# --- timestamps ---------------------------------------------------------------


def repair_timestamps(
    t: np.ndarray, *, reverse_tolerance_s: float | None = None, source: str = "timestamps"
) -> tuple[np.ndarray, StepRecord]:
    """Make timestamps strictly increasing, or refuse with a clear error.

    Duplicated timestamps keep their first sample. A sample whose time goes back
    by no more than `reverse_tolerance_s` (a late-delivered or re-sent sample) is
    dropped; a larger backward jump means the log is broken (clock reset,
    concatenated files) and raises ValueError naming the sample.

    Parameters
    ----------
    t : (N,) timestamps, s.
    reverse_tolerance_s : largest backward step that is repaired, s; default two
        median sample intervals.
    source : file or channel name used in messages.

    Returns
    -------
    (keep, record) : boolean mask (N,) of the samples to keep, and the decision.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"{source}: need a 1-D array of >= 2 timestamps, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.isfinite(t))[0])
        raise ValueError(f"{source}: timestamp at sample {bad} is not finite ({t[bad]})")
    dt = np.diff(t)
    if reverse_tolerance_s is None:
        reverse_tolerance_s = 2.0 * float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
    back = np.flatnonzero(dt < -reverse_tolerance_s)
    if back.size:
        i = int(back[0]) + 1
        raise ValueError(
            f"{source}: timestamp goes back by {-dt[i - 1]:.6g} s at sample {i} "
            f"({t[i - 1]:.6f} -> {t[i]:.6f} s), more than the tolerance "
            f"{reverse_tolerance_s:.6g} s; "
            "expected increasing times (split the log at the reset)"
        )
    # Keep a sample only if it is later than every sample before it.
    running_max = np.maximum.accumulate(t)
    keep = np.ones(t.size, dtype=bool)
    keep[1:] = t[1:] > running_max[:-1]
    duplicates = int(np.sum(dt == 0))
    dropped = np.flatnonzero(~keep)
    record = StepRecord(
        name="repair_timestamps",
        settings={"reverse_tolerance_s": reverse_tolerance_s},
        statistics={
            "source": source,
            "n_samples": int(t.size),
            "n_dropped": int(dropped.size),
            "n_duplicates": duplicates,
            "n_reversed": int(dropped.size - duplicates),
            "dropped_indices": dropped.tolist(),
            "decision": "unchanged" if dropped.size == 0 else "dropped",
        },
    )
    return keep, record


def find_gaps(t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """(K, 2) array of (start, end) times where consecutive samples are > max_gap_s apart."""
    t = np.asarray(t, dtype=float)
    i = np.flatnonzero(np.diff(t) > max_gap_s)
    return np.column_stack([t[i], t[i + 1]])


# --- clock estimation ---------------------------------------------------------


def _ncc_peak(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Lag (in samples, sub-sample) and value of the normalised cross-correlation peak.

    x : (W,) window; y : (W + 2L,) longer signal. Lag 0 means x aligns with
    y[L:L+W]; a positive lag means x matches y later.
    """
    w = x.size
    x0 = x - x.mean()
    # num[k] = sum_n x0[n] y[n + k] for k = 0 .. 2L, by FFT. A circular
    # correlation of length >= y.size never wraps for these lags (n + k <= y.size - 1),
    # so the transform needs only y's length, not the full linear w + y.size - 1.
    nfft = next_fast_len(y.size, real=True)
    num = irfft(rfft(y, nfft) * np.conj(rfft(x0, nfft)), nfft)[: y.size - w + 1]
    # Energy of each y window about its own mean, via cumulative sums.
    c1 = np.concatenate([[0.0], np.cumsum(y)])
    c2 = np.concatenate([[0.0], np.cumsum(y * y)])
    s1 = c1[w:] - c1[:-w]
    s2 = c2[w:] - c2[:-w]
    energy = s2 - s1 * s1 / w
    # Where y is (numerically) constant the ratio is round-off, not similarity.
    flat = energy <= 1e-9 * max(float(np.max(energy)), 1e-300)
    ncc = np.where(flat, 0.0, num / np.sqrt(np.where(flat, 1.0, energy) * np.sum(x0 * x0)))
    k = int(np.argmax(ncc))
    frac = 0.0
    if 0 < k < ncc.size - 1:
        # Vertex of the parabola through the peak and its neighbours.
        a, b, c = ncc[k - 1], ncc[k], ncc[k + 1]
        denom = a - 2.0 * b + c
        frac = 0.5 * (a - c) / denom if denom < 0 else 0.0
    half = (ncc.size - 1) // 2
    return k + frac - half, float(ncc[k])


def _on_grid(t: np.ndarray, x: np.ndarray, grid: np.ndarray, gaps: np.ndarray):
    """x resampled at `grid` by linear interpolation, and a mask of valid grid points
    (inside the data and not strictly inside one of the (K, 2) `gaps`)."""
    # Only the stretch of (t, x) around the grid goes to np.interp: it copies
    # non-contiguous inputs whole, which for short windows of a long run costs
    # far more than the interpolation.
    lo = max(int(np.searchsorted(t, grid[0], side="right")) - 1, 0)
    hi = min(int(np.searchsorted(t, grid[-1], side="left")) + 1, t.size)
    values = np.interp(grid, t[lo:hi], x[lo:hi])
    valid = (grid >= t[0]) & (grid <= t[-1])
    # A grid point is in a gap if the nearest gap start at or before it has its end after it.
    k = np.searchsorted(gaps[:, 0], grid, side="right") - 1
    in_gap = (k >= 0) & (grid < gaps[np.maximum(k, 0), 1]) if gaps.size else np.zeros_like(valid)
    return values, valid & ~in_gap


def estimate_clock(
    imu_t: np.ndarray,
    imu_rate: np.ndarray,
    ref_t: np.ndarray,
    ref_rate: np.ndarray,
    *,
    max_offset_s: float = 1.0,
    max_drift_ppm: float = 200.0,
    window_s: float = 30.0,
    max_gap_s: float | None = None,
    min_correlation: float = 0.9,
    max_windows: int = 64,
) -> ClockModel:
    """Offset and drift of the table clock against the IMU clock.

    Parameters
    ----------
    imu_t, imu_rate : (N,) IMU times (s) and the IMU's rate about the table axis.
    ref_t, ref_rate : (M,) table times (s, table clock) and the table rate. Any
        scale and bias between the two are irrelevant (correlation is normalised).
    max_offset_s : largest |offset| searched, s.
    max_drift_ppm : largest |drift| expected; sets the local search range.
    window_s : length of the windows whose local offsets are fitted, s.
    max_gap_s : a spacing larger than this in either log is a gap; windows that
        touch a gap are skipped. Default: 5 IMU sample intervals.
    min_correlation : windows whose correlation peak is lower (no motion, wrong
        signal) are skipped.
    max_windows : at most this many windows, evenly spread over the run (a
        line fit needs a few dozen; more only costs time on long runs).

    Returns
    -------
    ClockModel with t0_s = imu_t[0] and the RMS fit residual.

    Steps: `_coarse_offset` over the whole run, `_window_offsets` (the local
    offsets in windows, searched around it), `_fit_line` through them; all on
    one uniform time grid of the IMU's median sample interval.
    """
    imu_t, imu_rate = _checked_series("imu", imu_t, imu_rate)
    ref_t, ref_rate = _checked_series("reference", ref_t, ref_rate)
    dt = float(np.median(np.diff(imu_t)))
    if max_gap_s is None:
        max_gap_s = 5.0 * dt
    grid = np.arange(imu_t[0], imu_t[-1], dt)
    # A grid of at most ~5 ms seeds the windows (the drift only smears the coarse peak).
    q = max(1, int(0.005 / dt))
    coarse = _coarse_offset(grid, dt, q, (imu_t, imu_rate), (ref_t, ref_rate), max_offset_s)
    # The window search covers the drift over the run and the coarse step.
    search = int(np.ceil(max_drift_ppm * 1e-6 * (grid[-1] - grid[0]) / dt)) + 2 * q + 2
    centres, offsets = _window_offsets(
        grid,
        dt,
        coarse,
        search,
        (imu_t, imu_rate, find_gaps(imu_t, max_gap_s)),
        (ref_t, ref_rate, find_gaps(ref_t, max_gap_s)),
        window_s=window_s,
        min_correlation=min_correlation,
        max_windows=max_windows,
    )
    t0 = float(imu_t[0])
    coef, rms, n_windows = _fit_line(centres, offsets, t0, dt)
    return ClockModel(
        offset_s=float(coef[0]),
        drift_ppm=float(coef[1] * 1e6),
        t0_s=t0,
        residual_ms=rms * 1e3,
        n_windows=n_windows,
    )


def _checked_series(name: str, t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,) times and values as float arrays; ValueError unless same shape, 1-D, increasing."""
    t, x = np.asarray(t, float), np.ascontiguousarray(x, float)
    if t.shape != x.shape or t.ndim != 1:
        raise ValueError(f"estimate_clock: {name} times {t.shape} and values {x.shape} differ")
    if np.any(np.diff(t) <= 0):
        raise ValueError(
            f"estimate_clock: {name} times are not strictly increasing (use repair_timestamps)"
        )
    return t, x


def _coarse_offset(
    grid: np.ndarray,
    dt: float,
    q: int,
    imu: tuple[np.ndarray, np.ndarray],
    ref: tuple[np.ndarray, np.ndarray],
    max_offset_s: float,
) -> float:
    """Offset (s) of the whole run, correlated over +-max_offset_s on every q-th grid point.

    `grid` is uniform with step `dt` (s); `imu` and `ref` are (times, values).
    """
    # The IMU rate is put on the uniform grid only where it is used: here
    # every q-th point, below the windows (not the whole run at full rate).
    grid_c = grid[::q]
    x_c = np.interp(grid_c, *imu)
    lag_max = int(np.ceil(max_offset_s / (q * dt))) + 1
    inner = slice(lag_max, grid_c.size - lag_max)
    if grid_c[inner].size < 10 * lag_max:
        raise ValueError(
            f"estimate_clock: run of {grid[-1] - grid[0]:.1f} s is too short for offsets "
            f"up to {max_offset_s} s (need > 20 x max_offset_s)"
        )
    lag0, _ = _ncc_peak(x_c[inner], np.interp(grid_c, *ref))
    return lag0 * q * dt


def _window_offsets(
    grid: np.ndarray,
    dt: float,
    coarse: float,
    search: int,
    imu: tuple[np.ndarray, np.ndarray, np.ndarray],
    ref: tuple[np.ndarray, np.ndarray, np.ndarray],
    *,
    window_s: float,
    min_correlation: float,
    max_windows: int,
) -> tuple[np.ndarray, np.ndarray]:
    """(weighted centre time, offset) in s of every window that correlates well.

    `imu` and `ref` are (times, values, gaps) of each clock; the reference is
    searched +-`search` grid points around the coarse offset. Windows touching a
    gap, without motion or below `min_correlation` are skipped.
    """
    from scipy.ndimage import uniform_filter1d  # slow to import: only where clocks are synced

    w = max(int(round(window_s / dt)), 8)
    smooth = max(1, int(round(0.25 / dt)))  # 0.25 s moving average for the slope weights
    centres, offsets = [], []
    starts = np.arange(search, grid.size - w - search, w // 2)
    if starts.size > max_windows:
        starts = starts[np.unique(np.linspace(0, starts.size - 1, max_windows).astype(int))]
    for start in starts:
        sl = slice(start, start + w)
        x, x_valid = _on_grid(imu[0], imu[1], grid[sl], imu[2])
        if not x_valid.all() or np.ptp(x) == 0:
            continue
        g = grid[start - search : start + w + search] + coarse
        y, y_valid = _on_grid(ref[0], ref[1], g, ref[2])
        if not y_valid.all():
            continue
        lag, peak = _ncc_peak(x, y)
        if peak < min_correlation or abs(lag) >= search - 1:
            continue
        # A window measures the offset where its signal changes (the ramps), not
        # at its middle: with drift the two differ by up to drift * window / 2.
        # Weight times by the squared slope of the (noise-averaged) signal.
        slope = np.gradient(uniform_filter1d(x, smooth, mode="nearest"))
        weight = slope * slope
        centres.append(np.sum(grid[sl] * weight) / np.sum(weight))
        offsets.append(coarse + lag * dt)
    if len(centres) < 2:
        raise ValueError(
            f"estimate_clock: only {len(centres)} window(s) of {window_s} s with a correlation "
            f">= {min_correlation}; the signals need motion (ramps) in several windows"
        )
    return np.array(centres), np.array(offsets)


def _fit_line(
    centres: np.ndarray, offsets: np.ndarray, t0: float, dt: float
) -> tuple[np.ndarray, float, int]:
    """offset = c0 + c1 (t - t0): (c0, c1), the RMS residual (s) and the windows kept.

    One pass of outlier rejection (5 robust sigmas): a window hit by a spike or
    an unmodelled event should not tilt the drift.
    """
    keep = np.ones(centres.size, dtype=bool)
    for _ in range(2):
        A = np.column_stack([np.ones(keep.sum()), centres[keep] - t0])
        coef, *_ = np.linalg.lstsq(A, offsets[keep], rcond=None)
        resid = offsets - (coef[0] + coef[1] * (centres - t0))
        scale = 1.4826 * np.median(np.abs(resid[keep])) + 0.01 * dt
        keep = np.abs(resid) <= 5.0 * scale
        if keep.sum() < 2:
            keep[:] = True
    return coef, float(np.sqrt(np.mean(resid[keep] ** 2))), int(keep.sum())


def align_reference(
    imu_t: np.ndarray,
    ref_t: np.ndarray,
    ref_values: np.ndarray,
    clock: ClockModel,
    *,
    max_gap_s: float | None = None,
) -> np.ndarray:
    """Reference values resampled onto the IMU time base.

    Parameters
    ----------
    imu_t : (N,) IMU times, s.
    ref_t : (M,) table times (table clock), strictly increasing, s.
    ref_values : (M,) or (M, C) table channel(s).
    clock : the table clock against the IMU clock.
    max_gap_s : a spacing in the table log larger than this is a gap; IMU samples
        falling in a gap, or outside the table log, get NaN. Default: 5 median
        table sample intervals.

    Returns
    -------
    (N,) or (N, C) values at the IMU times (linear interpolation).
    """
    ref_t = np.asarray(ref_t, float)
    values = np.asarray(ref_values, float)
    if values.shape[0] != ref_t.size:
        raise ValueError(
            f"align_reference: {ref_t.size} reference times but {values.shape[0]} values"
        )
    if max_gap_s is None:
        max_gap_s = 5.0 * float(np.median(np.diff(ref_t)))
    tq = clock.to_ref(np.asarray(imu_t, float))
    cols = values.reshape(ref_t.size, -1)
    out = np.empty((tq.size, cols.shape[1]))
    for j in range(cols.shape[1]):
        out[:, j] = np.interp(tq, ref_t, cols[:, j])
    bad = (tq < ref_t[0]) | (tq > ref_t[-1])
    # Samples strictly inside a gap (the gap's end points are real table samples):
    # the last gap starting before the sample ends after it. One search for all
    # gaps, so many dropped samples do not cost one pass each.
    gaps = find_gaps(ref_t, max_gap_s)
    if gaps.size:
        k = np.searchsorted(gaps[:, 0], tq, side="left") - 1
        bad |= (k >= 0) & (tq < gaps[np.maximum(k, 0), 1])
    out[bad] = np.nan
    return out.reshape((-1,) + values.shape[1:])


def synchronise(
    rec: Recording,
    ref_t: np.ndarray,
    ref_channels: dict[str, np.ndarray],
    *,
    signal: str = "table_rate",
    signal_kind: str = "rate",
    imu_axis: int | None = None,
    max_offset_s: float = 1.0,
    max_drift_ppm: float = 200.0,
    window_s: float = 30.0,
    max_gap_s: float | None = None,
) -> tuple[Recording, StepRecord]:
    """Estimate the table clock and put the table channels on the IMU time base.

    Parameters
    ----------
    rec : the IMU recording (strictly increasing times).
    ref_t : (M,) table timestamps (table clock), s; duplicates and small
        reversals are repaired, the decision recorded.
    ref_channels : {name: (M,) values}, e.g. "table_angle" rad, "table_rate" rad/s.
    signal : the channel correlated with the gyro.
    signal_kind : "rate" (rad/s) or "angle" (rad; differentiated to a rate).
    imu_axis : gyro axis (0, 1, 2) along the table axis; default: the axis with
        the largest gyro variance (the one the table turns).
    Other parameters: see `estimate_clock` and `align_reference`.

    Returns
    -------
    (recording with the table channels in `reference`, StepRecord with the
    estimated offset/drift, fit residual, gaps and NaN counts).
    """
    where = rec.source or "recording"
    if signal not in ref_channels:
        raise ValueError(
            f"synchronise ({where}): reference channel {signal!r} missing; "
            f"have {sorted(ref_channels)}"
        )
    if signal_kind not in ("rate", "angle"):
        raise ValueError(f"synchronise: signal_kind must be 'rate' or 'angle', got {signal_kind!r}")
    keep, repair = repair_timestamps(ref_t, source=f"{where}: reference timestamps")
    ref_t = np.asarray(ref_t, float)[keep]
    channels = {k: np.asarray(v, float)[keep] for k, v in ref_channels.items()}
    ref_signal = channels[signal]
    if signal_kind == "angle":
        ref_signal = np.gradient(ref_signal, ref_t)
    if imu_axis is None:
        imu_axis = int(np.argmax(rec.gyr[::10].var(axis=0)))  # every 10th sample is plenty
    clock = estimate_clock(
        rec.t,
        rec.gyr[:, imu_axis],
        ref_t,
        ref_signal,
        max_offset_s=max_offset_s,
        max_drift_ppm=max_drift_ppm,
        window_s=window_s,
        max_gap_s=max_gap_s,
    )
    ref_gap = 5.0 * float(np.median(np.diff(ref_t)))
    # One interpolation pass for all channels (the index search is shared).
    columns = {k: v.reshape(ref_t.size, -1) for k, v in channels.items()}
    stacked = align_reference(
        rec.t, ref_t, np.hstack(list(columns.values())), clock, max_gap_s=ref_gap
    )
    edges = np.cumsum([0] + [c.shape[1] for c in columns.values()])
    aligned = {
        k: stacked[:, a:b].reshape((len(rec),) + channels[k].shape[1:])
        for k, a, b in zip(columns, edges[:-1], edges[1:], strict=True)
    }
    n_nan = {
        k: int(np.isnan(v).reshape(len(rec), -1).any(axis=1).sum()) for k, v in aligned.items()
    }
    gaps = find_gaps(ref_t, ref_gap)
    record = StepRecord(
        name="synchronise",
        settings={
            "signal": signal,
            "signal_kind": signal_kind,
            "imu_axis": imu_axis,
            "max_offset_s": max_offset_s,
            "max_drift_ppm": max_drift_ppm,
            "window_s": window_s,
            "max_gap_s": max_gap_s,
            "reference_max_gap_s": ref_gap,
        },
        statistics={
            "offset_s": clock.offset_s,
            "drift_ppm": clock.drift_ppm,
            "t0_s": clock.t0_s,
            "residual_ms": clock.residual_ms,
            "n_windows": clock.n_windows,
            "reference_gaps_s": gaps.tolist(),
            "n_nan_samples": n_nan,
            "timestamp_repair": repair.statistics,
        },
    )
    return replace(rec, reference={**rec.reference, **aligned}), record
