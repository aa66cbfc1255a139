"""The sequential (Kalman) estimator of the static accelerometer model against least squares."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from calib_core.procedures import solve
from calib_core.simulate import STATIC_LABELS, axis_vector, random_errors, six_position_integral_run
from calib_core.solvers.kalman import kalman_accel_linear
from calib_core.solvers.multi_position import solve_accel_linear
from calib_core.stats import channel_stats
from calib_core.units import STANDARD_GRAVITY

G = STANDARD_GRAVITY
# docs/methods.md 2.4: record >= 10 s at >= 100 Hz per attitude; six positions x up .. z down.
RATE_HZ, RECORD_S = 100.0, 10.0
# Errors of the size the MPU-6000 protocol tolerates (scale 0.03, misalignment 0.02,
# bias 0.5 m/s^2), noise 0.02 m/s^2 per sample.
M_TRUE = np.array([[0.02, 0.01, -0.015], [-0.012, -0.025, 0.018], [0.008, -0.01, 0.03]])
B_TRUE = np.array([0.3, -0.4, 0.7])
NOISE = 0.02


def _positions(rng, colour: float = 0.0):
    """Six positions of samples; colour > 0 gives AR(1) noise (n_eff < n)."""
    f_true = np.array([axis_vector(label, G) for label in STATIC_LABELS])
    n = int(RATE_HZ * RECORD_S)
    samples = []
    for f in f_true:
        e = rng.normal(0.0, NOISE, (n, 3))
        if colour:
            e = lfilter([1.0], [1.0, -colour], e, axis=0)
        samples.append(f @ (np.eye(3) + M_TRUE).T + B_TRUE + e)
    return f_true, samples


def _least_squares(f_true, samples):
    stats = [channel_stats(s) for s in samples]
    means = np.array([s.mean for s in stats])
    sems = np.array([s.sem for s in stats])
    return solve_accel_linear(f_true, means, sems)


@pytest.mark.parametrize("colour", [0.0, 0.8])
def test_kalman_agrees_with_least_squares_within_its_uncertainty(colour):
    """Same samples, white and correlated noise.

    Tolerance: with no process noise the filter is recursive least squares, so
    the two differ only by the prior's weight, posterior variance / prior
    variance <= (2e-4 / 10)^2 = 4e-10 of a standard deviation, and rounding
    over 6000 updates (~1e-12 relative). 1e-3 of the reported std bounds both
    with room; a filter with a wrong gain or a missing sample is off by O(1) std.
    The stds agree as closely: R = std^2 n / n_eff per sample gives each position
    the information 1 / sem^2 that least squares gives its mean (with colour 0.8,
    n / n_eff ~ 9: without the inflation the filter's std would be 3 times too small).
    """
    rng = np.random.default_rng(22)
    f_true, samples = _positions(rng, colour)
    kf, ls = kalman_accel_linear(f_true, samples), _least_squares(f_true, samples)
    assert kf.names == ls.names
    for name in ls.names:
        assert abs(kf.params[name] - ls.params[name]) <= 1e-3 * ls.std[name], name
        assert kf.std[name] == pytest.approx(ls.std[name], rel=1e-3), name
    np.testing.assert_allclose(kf.chi2, ls.chi2, rtol=1e-3, atol=1e-6)
    # and both recover the truth: every parameter within 4 std (6e-5 false-alarm each)
    for i, a in enumerate("xyz"):
        assert abs(kf.params[f"acc.scale.{a}"] - M_TRUE[i, i]) <= 4 * kf.std[f"acc.scale.{a}"]
        assert abs(kf.params[f"acc.bias.{a}"] - B_TRUE[i]) <= 4 * kf.std[f"acc.bias.{a}"]


def test_kalman_is_a_procedure_setting():
    """accel_solver = "kalman" in six_position: the same parameters as least squares
    (same 1e-3 std tolerance as above), the filter's covariance archived, the setting recorded."""
    rng = np.random.default_rng(5)
    run = six_position_integral_run(random_errors(rng), rng)
    ls = solve("six_position", run.segments, run.gravity, {})
    kf = solve("six_position", run.segments, run.gravity, {"accel_solver": "kalman"})
    assert kf.info["accel_solver"] == "kalman"
    for name, p in ls.parameters.items():
        q = kf.parameters[name]
        assert abs(q.value - p.value) <= 1e-3 * p.std, name
        assert q.std == pytest.approx(p.std, rel=1e-3), name
    assert kf.covariance.shape == ls.covariance.shape


def test_undetermined_positions_are_refused():
    """All positions z up: the filter would return its prior for x and y; refused instead."""
    rng = np.random.default_rng(1)
    f_true, samples = _positions(rng)
    f_same = np.tile(f_true[4], (6, 1))
    with pytest.raises(ValueError, match="do not determine the linear model"):
        kalman_accel_linear(f_same, samples)
    with pytest.raises(ValueError, match="one sample array per position"):
        kalman_accel_linear(f_true, samples[:5])
    flat = [*samples[:5], np.tile(samples[5][:1], (100, 1))]
    with pytest.raises(ValueError, match="position 5: .* no noise"):
        kalman_accel_linear(f_true, flat)
