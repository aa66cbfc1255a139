"""Zero-phase low-pass: no delay, exact DC, the designed magnitude, clear errors."""

import numpy as np
import pytest
from scipy.signal import sosfreqz

from calib_core.preprocess.filters import cutoff_from_bandwidth, design_lowpass, lowpass
from calib_core.recording import Recording

FS = 100.0


def _recording(signal, fs=FS, source="run.csv"):
    n = signal.shape[0]
    sig3 = np.column_stack([signal] * 3)
    return Recording(t=np.arange(n) / fs, acc=sig3, gyr=0.01 * sig3, source=source)


def _phase(x, t, f):
    """Phase (rad) of the f-Hz component of x by least squares on sin and cos."""
    A = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)])
    (s, c), *_ = np.linalg.lstsq(A, x, rcond=None)
    return np.arctan2(c, s), np.hypot(s, c)


@pytest.mark.parametrize("f", [1.0, 5.0, 8.0])
def test_no_delay_on_a_sinusoid(f):
    # Cutoff 10 Hz, order 4. Delay of the f-Hz component = phase difference / (2 pi f).
    t = np.arange(20_000) / FS
    x = np.sin(2 * np.pi * f * t + 0.3)
    out, _ = lowpass(_recording(x), cutoff_hz=10.0)
    core = slice(2000, -2000)  # away from the padded edges
    p_in, _ = _phase(x[core], t[core], f)
    p_out, amp = _phase(out.acc[core, 0], t[core], f)
    delay_samples = (p_in - p_out) / (2 * np.pi * f) * FS
    assert abs(delay_samples) < 0.1
    # The magnitude is |H|^2 of one pass (forward-backward squares it).
    _, h = sosfreqz(design_lowpass(FS, 10.0, 4), worN=[f], fs=FS)
    assert amp == pytest.approx(abs(h[0]) ** 2, rel=1e-6)


def test_no_delay_by_cross_correlation_of_noise():
    # Band-limited noise: the cross-correlation of input and output peaks at lag 0;
    # the parabolic vertex gives the sub-sample lag.
    rng = np.random.default_rng(1)
    x = rng.normal(size=50_000)
    out, _ = lowpass(_recording(x), cutoff_hz=10.0)
    y = out.acc[:, 0]
    lags = np.arange(-3, 4)
    c = np.array([np.dot(x[5 + k : -5 + k], y[5:-5]) for k in lags])
    k = int(np.argmax(c))
    vertex = lags[k] + 0.5 * (c[k - 1] - c[k + 1]) / (c[k - 1] - 2 * c[k] + c[k + 1])
    assert abs(vertex) < 0.1


def test_dc_passes_exactly():
    x = np.full(1000, 9.80665)
    out, _ = lowpass(_recording(x), cutoff_hz=2.0)
    assert np.max(np.abs(out.acc - 9.80665)) < 1e-12 * 9.80665 * 100


def test_half_power_at_the_cutoff():
    # Forward-backward: gain exactly 1/2 at the one-pass -3 dB cutoff (Butterworth).
    t = np.arange(40_000) / FS
    x = np.sin(2 * np.pi * 10.0 * t)
    out, _ = lowpass(_recording(x), cutoff_hz=10.0)
    _, amp = _phase(out.acc[4000:-4000, 0], t[4000:-4000], 10.0)
    assert amp == pytest.approx(0.5, abs=1e-3)


def test_cutoff_from_bandwidth_rule_and_record():
    assert cutoff_from_bandwidth(40.0, 0.25) == 10.0
    out, record = lowpass(_recording(np.zeros(500)), bandwidth_hz=40.0, fraction=1 / 3)
    assert record.settings["cutoff_hz"] == pytest.approx(40.0 / 3)
    assert record.statistics["sample_rate_hz"] == pytest.approx(FS)
    with pytest.raises(ValueError, match="1/5 .. 1/3"):
        lowpass(_recording(np.zeros(500)), bandwidth_hz=40.0, fraction=0.5)


def test_validation_errors_are_clear():
    rec = _recording(np.zeros(500))
    with pytest.raises(ValueError, match=r"Nyquist.*run\.csv"):
        lowpass(rec, cutoff_hz=60.0)
    with pytest.raises(ValueError, match="exactly one"):
        lowpass(rec)
    # order 4 = 2 sections; sosfiltfilt pads 3 * (2 * 2 + 1) = 15 samples at each end.
    with pytest.raises(ValueError, match=r"12 samples are too few.*need more than 15"):
        lowpass(_recording(np.zeros(12)), cutoff_hz=10.0)
    gap = _recording(np.zeros(500))
    t = gap.t.copy()
    t[300:] += 1.0
    with pytest.raises(ValueError, match="gap.*sample 300"):
        lowpass(Recording(t=t, acc=gap.acc, gyr=gap.gyr, source="run.csv"), cutoff_hz=10.0)
