"""Equipment-free calibration: attitude integration, simulated truth, the real Xsens session."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from calib_core.attitude import (
    integrate_rotation,
    integrate_rotations,
    quat_from_rotvec,
    quat_to_matrix,
    rot_x,
    rot_y,
)
from calib_core.checks import check_residuals
from calib_core.procedures import solve
from calib_core.recording import Recording
from calib_core.simulate.handheld import accelerometer_frame, handheld_run
from calib_core.simulate.lab_run import random_errors
from calib_core.tolerances import ToleranceProfile

XSENS = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "imutk_xsens"
XSENS_GRAVITY = 9.81744  # the value imu_tk's test application uses for this session


def _smooth_turn(axis: np.ndarray, angle: float, seconds: float, rate_hz: float) -> np.ndarray:
    """Body rates (N, 3) of a turn about a fixed axis with rate ~ sin^2: zero at both ends."""
    t = np.arange(int(seconds * rate_hz) + 1) / rate_hz
    return np.outer(2 * angle / seconds * np.sin(math.pi * t / seconds) ** 2, axis)


def test_rotation_integration_is_exact_for_non_commuting_turns():
    """90 deg about x, then 90 deg about y: R = Rx(90) Ry(90). Summing the rates as a
    small-angle rotation vector (90, 90, 0) deg instead misses it by tens of degrees."""
    rate_hz = 200.0
    w = np.vstack(
        [
            _smooth_turn(np.array([1.0, 0, 0]), math.pi / 2, 1.0, rate_hz),
            _smooth_turn(np.array([0, 1.0, 0]), math.pi / 2, 1.0, rate_hz)[1:],
        ]
    )
    t = np.arange(w.shape[0]) / rate_hz
    exact = rot_x(math.pi / 2) @ rot_y(math.pi / 2)
    got = integrate_rotation(t, w)
    # Trapezoid on a sin^2 rate is exact up to rounding; the composition is exact.
    np.testing.assert_allclose(got, exact, atol=1e-9)
    naive = quat_to_matrix(quat_from_rotvec(np.trapezoid(w, t, axis=0)))
    miss = math.degrees(math.acos((np.trace(naive.T @ exact) - 1) / 2))
    assert miss > 20.0
    # The batched form (padded with identity steps) equals the one-by-one form.
    pieces = [(t[:150], w[:150]), (t, w), (t[:3], w[:3])]
    batch = integrate_rotations(pieces)
    for k, (tk, wk) in enumerate(pieces):
        np.testing.assert_allclose(batch[k], integrate_rotation(tk, wk), atol=1e-12)


FAMILIES = ("acc.bias", "acc.scale", "acc.misalign", "gyr.bias", "gyr.scale", "gyr.misalign")


@pytest.mark.slow
def test_simulated_truth_within_uncertainty_over_seeds():
    """12 simulated hand-held sessions (30 poses, 100 Hz): every estimate within 4
    reported standard uncertainties; per parameter family the scatter of the errors
    over the mean reported std in [0.5, 2] (>= 33 degrees of freedom per family:
    a pooled std is within +-35 % of the truth with probability > 0.999)."""
    errors: dict[str, list[float]] = {}
    stds: dict[str, list[float]] = {}
    for seed in range(12):
        rng = np.random.default_rng(seed)
        truth = accelerometer_frame(random_errors(rng))
        run = handheld_run(truth, rng, poses=30)
        cal = solve("equipment_free", {"session": run.recording}, run.gravity, {})
        assert cal.info["acc_misalign_observable"] is True
        expected = truth.parameters()
        for name, p in cal.parameters.items():
            z = (p.value - expected[name]) / p.std
            assert abs(z) < 4.0, (seed, name, z)
            errors.setdefault(name, []).append(p.value - expected[name])
            stds.setdefault(name, []).append(p.std)
        assert len(cal.parameters) == 21  # 9 accelerometer + 3 gyro bias + 9 gyro matrix
    for family in FAMILIES:
        names = [n for n in errors if n.startswith(family + ".")]
        e = np.array([errors[n] for n in names])  # (P, seeds)
        scatter = math.sqrt(
            float((e - e.mean(axis=1, keepdims=True)).var() * e.size / (e.size - len(names)))
        )
        reported = float(np.sqrt(np.mean(np.square([stds[n] for n in names]))))
        assert 0.5 < scatter / reported < 2.0, (family, scatter, reported)


@pytest.mark.slow
def test_residual_check_and_robust_loss():
    """A pose held with a steady 0.3 m/s^2 push (0.3 m/s^2 >> sem ~ 1e-3) is down-weighted
    by the Huber loss and named in a warning; the Foundation's residual check passes on
    the honest poses."""
    rng = np.random.default_rng(40)
    truth = accelerometer_frame(random_errors(rng))
    run = handheld_run(truth, rng, poses=30)
    clean = solve("equipment_free", {"s": run.recording}, run.gravity, {})
    profile = ToleranceProfile("t", "1", "t", [])
    assert all(c.passed for c in check_residuals(clean, profile))
    # Push during the 10th rest (after the 20 s first rest and 9 poses of 5.5 s).
    acc = run.recording.acc.copy()
    t = run.recording.t
    push = (t > 20 + 9 * 5.5 + 2.0) & (t < 20 + 9 * 5.5 + 5.0)
    acc[push] += np.array([0.3, 0.0, 0.0])
    bad = Recording(t, acc, run.recording.gyr, source="pushed")
    cal = solve("equipment_free", {"s": bad}, run.gravity, {})
    assert cal.info["acc_outliers_huber"] >= 1
    assert any("miss the norm condition" in w for w in cal.warnings)
    expected = truth.parameters()
    for name, p in cal.parameters.items():
        if name.startswith("acc."):
            assert abs(p.value - expected[name]) < 4 * p.std, name


def test_bad_input_is_explained():
    rng = np.random.default_rng(41)
    run = handheld_run(accelerometer_frame(random_errors(rng)), rng, poses=4)
    with pytest.raises(ValueError, match=r"found 5 static intervals, need >= 9"):
        solve("equipment_free", {"s": run.recording}, run.gravity, {})
    with pytest.raises(ValueError, match="expected one continuous segment, got 2"):
        solve("equipment_free", {"a": run.recording, "b": run.recording}, run.gravity, {})
    with pytest.raises(ValueError, match="settings.k: expected a positive number"):
        solve("equipment_free", {"s": run.recording}, run.gravity, {"k": -1})


def _load_xsens() -> Recording:
    if not XSENS.is_dir():
        pytest.skip(f"real Xsens session not found at {XSENS} (shared/realdata is not checked out)")
    acc = np.loadtxt(XSENS / "xsens_acc.mat")
    gyr = np.loadtxt(XSENS / "xsens_gyro.mat")
    assert np.array_equal(acc[:, 0], gyr[:, 0]), "acc and gyro files must share timestamps"
    # Raw 16-bit counts to SI with nominal factors (mid-scale offset, mean datasheet gain);
    # the calibration measures the deviation from them.
    return Recording(
        acc[:, 0],
        (acc[:, 1:] - 32768.0) / ACC_GAIN,
        (gyr[:, 1:] - 32768.0) / GYR_GAIN,
        source=str(XSENS),
    )


# SOURCE.txt datasheet values: offsets in counts, gains in counts per SI unit.
DS_ACC_OFFSET = np.array([33123.0, 33276.0, 32360.0])
DS_ACC_GAIN = np.array([415.0, 413.0, 415.0])
DS_GYR_OFFSET = np.array([32768.0, 32466.0, 32485.0])
DS_GYR_GAIN = np.array([4778.0, 4758.0, 4766.0])
ACC_GAIN = float(DS_ACC_GAIN.mean())
GYR_GAIN = float(DS_GYR_GAIN.mean())


def test_real_xsens_session_against_the_datasheet(capsys):
    """imu_tk's hand-held Xsens MTi session (~38 rests). The datasheet values are
    approximate, so the bounds are the MTi's own stability figures: accelerometer
    bias 0.02 m/s^2 (~10 counts), gyro bias 1 deg/s (~80 counts), and 1 % on the gains
    (what "approximate" allows for a consumer datasheet). The differences are printed."""
    rec = _load_xsens()
    cal = solve("equipment_free", {"xsens": rec}, XSENS_GRAVITY, {"init_static_s": 40.0})
    assert cal.info["static_intervals"] >= 30
    acc_gain = ACC_GAIN * (1 + cal.vector("acc", "scale"))
    acc_offset = 32768.0 + cal.vector("acc", "bias") * ACC_GAIN
    gyr_gain = GYR_GAIN * (1 + np.diag(cal.matrix("gyr")))
    gyr_offset = 32768.0 + cal.vector("gyr", "bias") * GYR_GAIN
    with capsys.disabled():
        print("\nXsens MTi (imu_tk session): equipment-free vs datasheet (counts, counts/SI)")
        for label, ours, ds in (
            ("acc offset", acc_offset, DS_ACC_OFFSET),
            ("acc gain", acc_gain, DS_ACC_GAIN),
            ("gyr offset", gyr_offset, DS_GYR_OFFSET),
            ("gyr gain", gyr_gain, DS_GYR_GAIN),
        ):
            diff = np.round(ours - ds, 1)
            print(f"  {label:10s} ours {np.round(ours, 1)}  datasheet {ds}  diff {diff}")
        print(f"  acc misalign (lower) {np.round(cal.matrix('acc'), 4).tolist()}")
        print(f"  gyr matrix M_g {np.round(cal.matrix('gyr'), 4).tolist()}")
    np.testing.assert_array_less(np.abs(acc_offset - DS_ACC_OFFSET), 0.02 * ACC_GAIN)
    np.testing.assert_array_less(np.abs(gyr_offset - DS_GYR_OFFSET), math.radians(1.0) * GYR_GAIN)
    np.testing.assert_array_less(np.abs(acc_gain / DS_ACC_GAIN - 1), 0.01)
    np.testing.assert_array_less(np.abs(gyr_gain / DS_GYR_GAIN - 1), 0.01)
    # The calibration explains the data: |f| = g to the 0.002 g residual limit of
    # docs/methods.md 3.6 (from ~1 m/s^2 with the nominal factors), gravity carried between
    # rests at least twice as well as with the nominal gyro.
    assert cal.info["acc_norm_rms_before"] > 0.5
    assert cal.info["acc_norm_rms_after"] < 0.002 * 9.80665
    assert cal.info["gyr_residual_rms_rad_after"] < 0.5 * cal.info["gyr_residual_rms_rad_before"]


def test_threshold_search_reaches_rests_that_appear_only_at_large_k():
    """Holds trembling with 12 times the sensor's noise std after a first rest on the
    table (variance ~145 times the first rest's, both sensors): no rest but the first is
    below the grid's old end, k = 32; the search reaches them (k >= 128) and finds every
    rest, with each accelerometer parameter within 4 standard uncertainties of the truth
    (the tremor is white: the means' uncertainties see it)."""
    rng = np.random.default_rng(61)
    truth = accelerometer_frame(random_errors(rng))
    run = handheld_run(truth, rng, poses=20)
    r = run.recording
    n0 = int(20.0 * 100)  # handheld_run's first rest, 20 s at 100 Hz
    acc, gyr = r.acc.copy(), r.gyr.copy()
    acc[n0:] += rng.normal(0.0, 12 * truth.acc_noise, acc[n0:].shape)
    gyr[n0:] += rng.normal(0.0, 12 * truth.gyr_noise, gyr[n0:].shape)
    cal = solve("equipment_free", {"s": Recording(r.t, acc, gyr)}, run.gravity, {})
    assert cal.info["static_threshold_k"] >= 128 and cal.info["static_intervals"] == 21
    expected = truth.parameters()
    for name, p in cal.parameters.items():
        if name.startswith("acc."):
            assert abs(p.value - expected[name]) < 4 * p.std, name


def test_refusal_names_the_setting_that_would_work():
    """Holds of 1.3 s: shorter than the 1 s detector window plus its minimum duration, so
    no threshold finds them. The refusal names a shorter min_duration_s or window_s that
    does, and given to the run, that setting calibrates it. With too few poses instead
    (4), the refusal asks for the missing orientations."""
    rng = np.random.default_rng(42)
    run = handheld_run(accelerometer_frame(random_errors(rng)), rng, poses=20, hold_s=1.3)
    with pytest.raises(ValueError, match="the rests are shorter than the detector asks") as err:
        solve("equipment_free", {"s": run.recording}, run.gravity, {})
    key, value = re.search(r"settings\.(\w+) = ([\d.]+) \(instead", str(err.value)).groups()
    cal = solve("equipment_free", {"s": run.recording}, run.gravity, {key: float(value)})
    assert cal.info["static_intervals"] >= 9
    rng = np.random.default_rng(41)
    run = handheld_run(accelerometer_frame(random_errors(rng)), rng, poses=4)
    with pytest.raises(ValueError, match="hold the IMU still in at least 4 more orientations"):
        solve("equipment_free", {"s": run.recording}, run.gravity, {})
