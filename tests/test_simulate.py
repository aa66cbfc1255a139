"""The simulator: the test oracle must itself be right (shapes, model, noise, spikes, range)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from calib_core import params
from calib_core.simulate import (
    ROTATION_LABELS,
    STATIC_LABELS,
    TrueErrors,
    random_errors,
    rotation_profile,
    six_position_integral_run,
)
from calib_core.stats import trapezoid_weights
from calib_core.units import DEG, STANDARD_GRAVITY


def noiseless(truth: TrueErrors) -> TrueErrors:
    return TrueErrors(
        truth.acc_bias,
        truth.acc_M,
        truth.gyr_bias,
        truth.gyr_M,
        truth.gsens,
        np.zeros(3),
        np.zeros(3),
    )


def test_segments_labels_time_base_and_temperature():
    rng = np.random.default_rng(0)
    run = six_position_integral_run(random_errors(rng), rng, static_s=10.0, temp_c=25.0)
    assert list(run.segments) == list(STATIC_LABELS + ROTATION_LABELS)
    for label, rec in run.segments.items():
        assert rec.label == label
        assert rec.t[0] == 0.0
        assert rec.sample_rate == pytest.approx(50.0)
        assert rec.temp is not None and abs(rec.temp.mean() - 25.0) < 0.01
    assert len(run.segments["x_up"]) == 500


def test_parameters_are_canonical_and_truth_is_json():
    rng = np.random.default_rng(1)
    run = six_position_integral_run(random_errors(rng), rng)
    p = run.truth.parameters()
    for name in p:
        params.validate(name)
    expected = set(params.ACC_LINEAR + params.GYR_LINEAR + params.GSENS)
    expected |= {f"{s}.noise.{a}" for s in ("acc", "gyr") for a in params.AXES}
    assert set(p) == expected  # 12 + 12 + 9 + 6
    doc = json.loads(json.dumps(run.truth_dict()))
    assert doc["gravity"] == STANDARD_GRAVITY
    assert doc["parameters"]["gyr.misalign.xy"] == run.truth.gyr_M[0, 1]
    assert doc["settings"]["turns"] == 1


def test_random_errors_have_mems_magnitudes():
    for seed in range(20):
        e = random_errors(np.random.default_rng(seed))
        assert np.all((np.abs(e.acc_bias) >= 0.05) & (np.abs(e.acc_bias) <= 0.3))
        assert np.all((np.abs(np.diag(e.acc_M)) >= 0.005) & (np.abs(np.diag(e.acc_M)) <= 0.03))
        off = np.abs(e.gyr_M[~np.eye(3, dtype=bool)])
        assert np.all((off >= 0.001) & (off <= 0.01))
        assert np.all(np.abs(e.gyr_bias) <= 3 * DEG)
        gs_dps_per_g = np.abs(e.gsens) / DEG * STANDARD_GRAVITY
        assert np.all((gs_dps_per_g >= 0.01) & (gs_dps_per_g <= 0.1))
    with pytest.raises(ValueError, match="grade"):
        random_errors(np.random.default_rng(0), grade="navigation-ish")


def test_noise_free_output_is_the_model():
    rng = np.random.default_rng(2)
    truth = random_errors(rng)
    g = 9.81
    run = six_position_integral_run(noiseless(truth), rng, gravity=g, turns=2)
    # y_dn: true specific force (0, -g, 0), written out element by element.
    rec = run.segments["y_dn"]
    expected_acc = truth.acc_bias - g * truth.acc_M[:, 1]
    expected_acc[1] -= g
    np.testing.assert_allclose(rec.acc, np.broadcast_to(expected_acc, rec.acc.shape), atol=1e-12)
    np.testing.assert_allclose(rec.gyr[0], truth.gyr_bias - g * truth.gsens[:, 1], atol=1e-15)
    # z_cw: the z channel turns -2 turns scaled by (1 + M_zz) on top of the z_up static reading.
    rot = run.segments["z_cw"]
    static = run.segments["z_up"].gyr[0]
    angle = trapezoid_weights(rot.t) @ (rot.gyr - static)
    # The sin^2 profile is smooth, so the trapezoid rule is exact to ~1e-7 rad here.
    np.testing.assert_allclose(angle, -4 * math.pi * (np.eye(3) + truth.gyr_M)[:, 2], atol=1e-6)


def test_rotation_profile_turns_whole_turns_smoothly():
    for turns in (1, 3):
        t, rate = rotation_profile(200.0, turns, 90 * DEG, 1.0)
        angle = trapezoid_weights(t) @ rate
        assert angle == pytest.approx(2 * math.pi * turns, rel=1e-8)
        assert rate.max() == pytest.approx(90 * DEG, rel=1e-3)
        assert rate[0] == 0.0 and rate[-1] == 0.0


def test_noise_std_matches_truth():
    rng = np.random.default_rng(3)
    truth = random_errors(rng)
    run = six_position_integral_run(truth, rng, static_s=100.0)
    rec = run.segments["z_up"]
    n = len(rec)
    # A sample std of N white samples has relative std 1/sqrt(2(N-1)): allow 4 of them.
    tol = 4 / math.sqrt(2 * (n - 1))
    np.testing.assert_allclose(rec.acc.std(axis=0, ddof=1), truth.acc_noise, rtol=tol)
    np.testing.assert_allclose(rec.gyr.std(axis=0, ddof=1), truth.gyr_noise, rtol=tol)


def test_spikes_are_counted_and_sized():
    rng = np.random.default_rng(4)
    truth = random_errors(rng)
    run = six_position_integral_run(truth, rng, spike_fraction=0.01, spike_sigma=8.0)
    clean = six_position_integral_run(noiseless(truth), np.random.default_rng(0))
    rec, ref = run.segments["x_dn"], clean.segments["x_dn"]
    assert run.settings["spikes"]["x_dn"] == 10
    z = np.hstack([(rec.acc - ref.acc) / truth.acc_noise, (rec.gyr - ref.gyr) / truth.gyr_noise])
    # An 8 sigma spike plus unit noise exceeds 5 sigma unless the noise is below -3 sigma
    # (p = 0.0013 per spike); clean samples exceed 5 sigma with p = 6e-7: the count is exact
    # with overwhelming probability.
    assert int((np.abs(z) > 5).sum()) == 10


def test_gyro_saturates_at_range_and_unequal_pauses():
    rng = np.random.default_rng(5)
    run = six_position_integral_run(
        random_errors(rng), rng, rotation_rate_dps=300.0, gyro_range_dps=250.0, cw_pause_s=5.0
    )
    assert np.abs(run.segments["y_ccw"].gyr).max() == pytest.approx(250 * DEG)
    assert run.segments["y_cw"].duration == pytest.approx(run.segments["y_ccw"].duration + 6.0)


def test_bad_arguments():
    rng = np.random.default_rng(6)
    truth = random_errors(rng)
    with pytest.raises(ValueError, match="turns"):
        six_position_integral_run(truth, rng, turns=0)
    with pytest.raises(ValueError, match="spike_fraction"):
        six_position_integral_run(truth, rng, spike_fraction=1.5)
