"""Zero-phase low-pass filtering (forward-backward Butterworth in second-order sections).

Running the filter forward and then backward squares its magnitude response
and cancels its phase, so the output has no group delay at any frequency (the
timing of a rotation's start and end is untouched). Second-order sections keep
high orders and low cutoffs numerically stable.

Cutoff rule (docs/methods.md 3.2): 1/5 .. 1/3 of the IMU bandwidth.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib_core.calibration import StepRecord
from calib_core.recording import Recording

BANDWIDTH_FRACTION_RANGE = (0.2, 1.0 / 3.0)
MAX_GAP_FACTOR = 1.5  # a spacing > 1.5 median intervals is a dropped sample / gap


def cutoff_from_bandwidth(bandwidth_hz: float, fraction: float = 0.25) -> float:
    """Cutoff (Hz) as a fraction of the IMU bandwidth, within the 1/5 .. 1/3 rule."""
    lo, hi = BANDWIDTH_FRACTION_RANGE
    if not lo - 1e-12 <= fraction <= hi + 1e-12:
        raise ValueError(
            f"lowpass: fraction {fraction} of the bandwidth is outside the 1/5 .. 1/3 rule"
        )
    if bandwidth_hz <= 0:
        raise ValueError(f"lowpass: bandwidth_hz must be > 0, got {bandwidth_hz}")
    return fraction * bandwidth_hz


def design_lowpass(fs_hz: float, cutoff_hz: float, order: int = 4) -> np.ndarray:
    """Butterworth low-pass as second-order sections, shape (ceil(order/2), 6).

    The cutoff is the -3 dB point of one pass; the forward-backward pass has
    gain 1/2 (-6 dB) there.
    """
    nyquist = 0.5 * fs_hz
    if not 0 < cutoff_hz < nyquist:
        raise ValueError(
            f"lowpass: cutoff {cutoff_hz} Hz must be between 0 and the Nyquist frequency "
            f"{nyquist} Hz (sample rate {fs_hz} Hz)"
        )
    if order < 1:
        raise ValueError(f"lowpass: order must be >= 1, got {order}")
    # scipy.signal imports scipy.stats (slow): loaded only when a run is filtered.
    from scipy.signal import butter

    return butter(order, cutoff_hz, btype="low", fs=fs_hz, output="sos")


def padlen(sos: np.ndarray) -> int:
    """Edge padding sosfiltfilt uses by default (its formula); the data must be longer."""
    zeros_at_end = min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum()))
    return 3 * (2 * len(sos) + 1 - zeros_at_end)


def zero_phase(x: np.ndarray, sos: np.ndarray, axis: int = 0) -> np.ndarray:
    """Forward-backward filtering of `x` along `axis`, with a length check."""
    need = padlen(sos)
    if x.shape[axis] <= need:
        raise ValueError(
            f"lowpass: {x.shape[axis]} samples are too few for this filter; "
            f"need more than {need} (3 x filter length for the edge padding)"
        )
    from scipy.signal import sosfiltfilt

    return sosfiltfilt(sos, x, axis=axis)


def lowpass(
    rec: Recording,
    cutoff_hz: float | None = None,
    *,
    bandwidth_hz: float | None = None,
    fraction: float = 0.25,
    order: int = 4,
    channels: tuple[str, ...] = ("acc", "gyr"),
) -> tuple[Recording, StepRecord]:
    """Zero-phase Butterworth low-pass of the IMU channels.

    Parameters
    ----------
    rec : recording with uniform sampling (no gaps: filter each side separately).
    cutoff_hz : explicit cutoff, Hz; or
    bandwidth_hz : the IMU's bandwidth, Hz, with `fraction` (1/5 .. 1/3) of it
        as the cutoff. Give exactly one of the two.
    order : Butterworth order of one pass (the forward-backward pass doubles it).
    channels : which of "acc", "gyr" to filter.

    Returns
    -------
    (filtered recording, StepRecord with the cutoff, order, sample rate).
    """
    where = rec.source or "recording"
    if (cutoff_hz is None) == (bandwidth_hz is None):
        raise ValueError(f"lowpass ({where}): give exactly one of cutoff_hz and bandwidth_hz")
    if cutoff_hz is None:
        cutoff_hz = cutoff_from_bandwidth(bandwidth_hz, fraction)
    if len(rec) < 2:
        raise ValueError(f"lowpass ({where}): need samples, got {len(rec)}")
    dt = np.diff(rec.t)
    median_dt = float(np.median(dt))
    gaps = np.flatnonzero(dt > MAX_GAP_FACTOR * median_dt)
    if gaps.size:
        i = int(gaps[0])
        raise ValueError(
            f"lowpass ({where}): {gaps.size} gap(s) in the timestamps, first at sample {i + 1} "
            f"(t = {rec.t[i]:.6f} -> {rec.t[i + 1]:.6f} s); expected uniform sampling, "
            "filter each gap-free stretch separately"
        )
    fs = 1.0 / median_dt
    try:
        sos = design_lowpass(fs, cutoff_hz, order)
        filtered = {
            name: zero_phase(np.asarray(getattr(rec, name), float), sos) for name in channels
        }
    except ValueError as err:
        raise ValueError(f"{err} ({where})") from None
    record = StepRecord(
        name="lowpass",
        settings={
            "cutoff_hz": float(cutoff_hz),
            "bandwidth_hz": bandwidth_hz,
            "fraction": fraction if bandwidth_hz is not None else None,
            "order": order,
            "design": "butterworth, second-order sections, forward-backward (zero phase)",
            "channels": list(channels),
        },
        statistics={
            "source": where,
            "sample_rate_hz": fs,
            "n_samples": len(rec),
            "padlen": padlen(sos),
        },
    )
    return replace(rec, **filtered), record
