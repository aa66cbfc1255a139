"""The motion check's compiled window statistics against a plain NumPy implementation of
the same definition: median, variance of the samples less the SPIKE_TRIM farthest from it
(of the samples tied at the threshold the later left out), integrated autocorrelation time.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from calib_core.preprocess.motion import SPIKE_TRIM, window_statistics
from calib_core.stats import centred_iats

EPS = np.finfo(float).eps


def reference(x: np.ndarray, width: int) -> tuple[np.ndarray, ...]:
    """(median, variance, its rounding bound, iat, rho_1) of each window and channel, one
    window at a time in NumPy: a stable sort of the distances keeps, of the samples tied
    at the threshold, the earlier."""
    k, channels = x.shape[0] // width, x.shape[1]
    keep = width - max(1, int(math.ceil(SPIKE_TRIM * width)))
    out = [np.empty((k, channels)) for _ in range(5)]
    for w in range(k):
        for c in range(channels):
            col = x[w * width : (w + 1) * width, c]
            med = np.median(col)
            d = col - med
            kept = d[np.argsort(np.abs(d), kind="stable")[:keep]]
            # the kernel sums d and d^2 of the kept in one pass (var = (s2 - s1^2 / keep) /
            # (keep - 1)): each sum within width eps of its terms' magnitudes, the
            # difference within that of s2 and of 2 |s1| sum|d| / keep; x2 for margin.
            bound = (
                4.0 * width * EPS * (np.sum(kept**2) + abs(kept.sum()) * np.abs(kept).sum() / keep)
            ) / (keep - 1)
            centred = d - d.mean()
            sum_sq = np.dot(centred, centred)
            rho = np.dot(centred[:-1], centred[1:]) / sum_sq if sum_sq else 0.0
            out[0][w, c], out[1][w, c], out[2][w, c] = med, kept.var(ddof=1), bound
            out[3][w, c] = centred_iats(centred[None, :])[0]
            out[4][w, c] = rho
    return tuple(out)


def check(x: np.ndarray, width: int) -> None:
    med, var, bound, iat, rho = reference(x, width)
    k, channels = var.shape
    got_med, got_var = np.empty((k, channels)), np.empty((k, channels))
    white = np.empty((k, channels), dtype=bool)
    trim = max(1, int(math.ceil(SPIKE_TRIM * width)))
    limit = 3.0 / math.sqrt(width)  # centred_iats' white-noise test
    # imported here: the kernel's module loads Numba (the tier collects without it)
    from calib_core.preprocess.motion_windows import trimmed_windows

    trimmed_windows(np.ascontiguousarray(x), width, trim, limit, got_med, got_var, white)
    np.testing.assert_array_equal(got_med, med)  # np.median's, bit for bit
    assert np.all(np.abs(got_var - var) <= bound), np.max(np.abs(got_var - var) / bound)
    v, t = window_statistics(x, width)
    np.testing.assert_array_equal(v, got_var)
    # The kernel's white-noise test decides which windows get centred_iats' FFT; it
    # takes rho_1 from sums about the median, within rounding of NumPy's: the data's
    # windows are kept off the limit by far more than that, so the times are NumPy's.
    assert np.all(np.abs(np.abs(rho) - 3.0 / math.sqrt(width)) > 1e-9)
    np.testing.assert_allclose(t, iat, rtol=1e-12, atol=0.0)


def still(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 6): white noise on offsets, a low-passed channel (its windows take the FFT),
    a spike."""
    x = rng.normal(0.0, 1e-3, (n, 6)) + np.array([0.01, -0.02, 0.003, 0.1, -0.2, 9.81])
    x[:, 1] = 0.01 + np.convolve(rng.normal(0.0, 1e-3, n + 9), np.ones(10) / 10.0, "valid")
    x[n // 3, 2] += 0.5
    return x


@pytest.mark.parametrize("width", [16, 17, 100, 1000, 1001])
def test_kernel_is_the_definition_on_noise(width):
    check(still(np.random.default_rng(width), 12 * width), width)


@pytest.mark.parametrize("width", [16, 17, 100, 1000, 1001])
def test_kernel_is_the_definition_on_quantised_data_with_ties(width):
    """Values on a grid of about the noise's std: many samples tie at the threshold."""
    x = still(np.random.default_rng(width + 1), 12 * width)
    x = np.round(x / 1e-3) * 1e-3
    check(x, width)
    assert _split_ties(x, width) > 0  # the tie rule is exercised


def _split_ties(x: np.ndarray, width: int) -> int:
    """Windows and channels where samples of both signs tie at the threshold and some
    of them are left out: where which are left out changes the sum."""
    keep = width - max(1, int(math.ceil(SPIKE_TRIM * width)))
    rows = 0
    for w in range(x.shape[0] // width):
        for c in range(x.shape[1]):
            d = x[w * width : (w + 1) * width, c] - np.median(x[w * width : (w + 1) * width, c])
            a = np.abs(d)
            thr = np.sort(a)[keep - 1]
            at = d[a == thr]
            # left out among ties, and the ties differ in sign: the rule changes the sum
            if np.sum(a <= thr) > keep and np.any(at > 0) and np.any(at < 0):
                rows += 1
    return rows


def test_ties_at_the_threshold_leave_out_the_later():
    """One sample left out (width 50), two tied at the threshold +-2 from the median 0:
    the later is left out, whichever its sign."""
    col = np.zeros(50)
    col[:11] = [1, -1, 1, -1, 1, -1, 0.5, -0.5, 0.25, -0.25, 0.75]
    for first in (2.0, -2.0):
        col[20], col[40] = first, -first
        var, _ = window_statistics(col[:, None], 50)
        # 50 terms summed: within 4 x 50 eps (see reference)
        assert var[0, 0] == pytest.approx(np.delete(col, 40).var(ddof=1), rel=200 * EPS)
        assert abs(var[0, 0] - np.delete(col, 20).var(ddof=1)) > 1e-3  # the rule matters


def test_a_constant_window_and_a_spike():
    x = np.full((300, 2), 9.81)
    x[150, 1] += 1.0  # one spike in the second window of channel 1: trimmed
    var, iat = window_statistics(x, 100)
    np.testing.assert_array_equal(var, 0.0)
    np.testing.assert_array_equal(iat, 1.0)


def test_a_window_whose_sample_misses_the_bracket():
    """Every STEP-th value far from the rest: the sampled bracket misses the median and
    the threshold, and the whole window is selected instead."""
    from calib_core.preprocess.motion_windows import STEP

    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 1.0, (2000, 2))
    x[::STEP, 0] += 100.0
    x[::STEP, 1] = np.round(x[::STEP, 1])
    check(x, 1000)


def test_a_non_finite_window_is_nan_and_the_others_unchanged():
    x = still(np.random.default_rng(9), 400)
    v0, t0 = window_statistics(x, 100)
    for bad in (np.nan, np.inf):
        y = x.copy()
        y[150, 4] = bad
        v, t = window_statistics(y, 100)
        assert np.isnan(v[1, 4]) and np.isnan(t[1, 4])
        mask = np.ones_like(v, dtype=bool)
        mask[1, 4] = False
        np.testing.assert_array_equal(v[mask], v0[mask])
        np.testing.assert_array_equal(t[mask], t0[mask])


FERRARIS = (
    Path(__file__).resolve().parents[2]
    / "shared"
    / "realdata"
    / "imucal_ferraris"
    / "example_ferraris_session.csv"
)


@pytest.mark.parametrize("width", [16, 101])
def test_kernel_is_the_definition_on_a_real_quantised_record(width):
    """imucal's Ferraris session (a real unit's counts, hand-turned and still): ties at
    the threshold in most windows."""
    if not FERRARIS.exists():
        pytest.skip(f"imucal Ferraris session not found at {FERRARIS} (shared/realdata missing)")
    x = np.loadtxt(FERRARIS, delimiter=",", skiprows=1)[:, 1:]
    check(x, width)
    assert _split_ties(x, width) > 0
