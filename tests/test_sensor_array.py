"""Sensor-array single-position calibration: the six-IMU cube and general mountings."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib_core.checks import check_residuals
from calib_core.crlb import crlb_variances, fisher_information
from calib_core.procedures import solve
from calib_core.simulate.array import array_run
from calib_core.simulate.lab_run import Turns, random_errors
from calib_core.solvers.sensor_array import cube_mounts
from calib_core.tolerances import ToleranceProfile
from calib_testing.benchmark_cases import design

G = 9.80665
TURNS_QUICK = {"rotation_rate_dps": 360.0, "pause_s": 0.2}


def test_cube_mounts_point_the_vertical_along_every_axis():
    up = np.array([m @ [0, 0, 1.0] for m in cube_mounts().values()])
    np.testing.assert_allclose(
        up, np.vstack([np.eye(3), -np.eye(3)])[[0, 3, 1, 4, 2, 5]], atol=1e-15
    )
    for m in cube_mounts().values():
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-15)
        assert np.linalg.det(m) == pytest.approx(1.0)


def test_truth_and_uncertainty_over_seeds():
    """Six-IMU cube, 30 seeds: all 33 shared parameters within 4 reported standard
    uncertainties; per parameter, scatter over 30 seeds / mean reported std in
    [0.5, 2] (a 30-draw sample std is within +-40 % with probability > 0.999)."""
    errors, stds, names = [], [], None
    for seed in range(30):
        rng = np.random.default_rng(seed)
        truth = random_errors(rng)
        run = array_run(truth, cube_mounts(), rng, static_s=10.0, rate_hz=50.0)
        cal = solve("sensor_array", run.segments, run.gravity, {})
        assert cal.info["equations_acc"] == 18 and cal.info["turns"] == [1]
        assert not cal.warnings
        expected = truth.parameters()
        names = sorted(cal.parameters)
        assert len(names) == 33  # acc 12, gyro bias 3 + G 9, gyro scale/misalignment 9
        errors.append([cal.parameters[n].value - expected[n] for n in names])
        stds.append([cal.parameters[n].std for n in names])
    errors, stds = np.array(errors), np.array(stds)
    z = np.abs(errors / stds)
    assert z.max() < 4.0, names[int(np.argmax(z.max(axis=0)))]
    ratio = errors.std(axis=0, ddof=1) / stds.mean(axis=0)
    assert np.all((ratio > 0.5) & (ratio < 2.0)), dict(zip(names, np.round(ratio, 2), strict=True))


@pytest.mark.slow
def test_the_cramer_rao_bound_is_reached_but_for_the_on_axis_g_sensitivity():
    """The accelerometer's 12 are linear in the static means with white noise: the
    scatter over 200 runs equals the CRLB sigma^2 / n (A^T A)^-1, A = [1, f_s] stacked
    over the sensors (built here from the mountings). The gyro's bias and cross-axis
    g-sensitivity also take the turns' static data (their rests, the cross-axis channels
    less their share of the turn: `sensor_array._pooled_gyro`), so their bound is the
    whole run's (`calib_core.crlb` on the benchmark's model of this design); the on-axis
    g-sensitivity is informed by the turns only through their whole-turn angle, which
    the solver does not use, so it stays at the static bound. The gyro's scale and
    misalignment, from the turns read as the integral method's regression reads them
    (motion window, cross-axis slopes), are held to the whole run's bound too. 200 runs:
    a sample std scatters by 5 %, so 1.2 is 4 of those; 0.8 catches a wrong bound."""
    truth = random_errors(np.random.default_rng(7))
    mounts = cube_mounts()
    rate_hz, static_s = 50.0, 4.0
    quick = Turns(**TURNS_QUICK)  # the statics carry the accelerometer
    n = int(rate_hz * static_s)
    names = [
        *(f"acc.bias.{a}" for a in "xyz"),
        *(f"acc.scale.{a}" if a == b else f"acc.misalign.{a}{b}" for a in "xyz" for b in "xyz"),
        *(f"gyr.bias.{a}" for a in "xyz"),
        *(f"gyr.gsens.{a}{b}" for a in "xyz" for b in "xyz"),
        *(f"gyr.scale.{a}" if a == b else f"gyr.misalign.{a}{b}" for a in "xyz" for b in "xyz"),
    ]
    expected = truth.parameters()
    errors = []
    for seed in range(200):
        rng = np.random.default_rng(500 + seed)
        run = array_run(truth, mounts, rng, static_s=static_s, rate_hz=rate_hz, turns=quick)
        cal = solve("sensor_array", run.segments, G, {"turns": 1})
        errors.append([cal.parameters[k].value - expected[k] for k in names])
    observed = np.array(errors).std(axis=0, ddof=1)
    f = np.array([m @ [0, 0, G] for m in mounts.values()])
    cov = np.linalg.inv(np.column_stack([np.ones(6), f]).T @ np.column_stack([np.ones(6), f]))
    unit = np.sqrt(np.diag(cov))  # (4,): bias, then the three matrix columns
    crlb = [
        *(truth.acc_noise / np.sqrt(n) * unit[0]),
        *(truth.acc_noise[i] / np.sqrt(n) * unit[1 + j] for i in range(3) for j in range(3)),
        *(truth.gyr_noise / np.sqrt(n) * unit[0]),
        *(truth.gyr_noise[i] / np.sqrt(n) * unit[1 + j] for i in range(3) for j in range(3)),
        *[np.nan] * 9,  # the gyro matrix: the whole run's bound, below
    ]
    case = {
        "id": "test",
        "simulator": "array",
        "truth": {"grade": "mems", "seed": 7},
        "simulation": {"rate_hz": rate_hz, "static_s": static_s, "turns": TURNS_QUICK},
    }
    whole = design(case)
    assert all(whole.theta[k] == v for k, v in expected.items() if k in whole.theta)
    bound_names, info = fisher_information(whole.model, whole.theta, whole.steps, linear=True)
    bound = dict(zip(bound_names, np.sqrt(crlb_variances(info)), strict=True))
    on_axis = {f"gyr.gsens.{a}{a}" for a in "xyz"}
    for i, k in enumerate(names):
        if k.startswith("gyr.") and k not in on_axis:
            crlb[i] = bound[k]
    ratio = observed / np.array(crlb)
    assert np.all((ratio > 0.8) & (ratio < 1.2)), dict(zip(names, np.round(ratio, 3), strict=True))


def test_any_number_of_sensors_and_mountings():
    """Four random mountings (one IMU remounted four times) share the model as well; the
    estimates still hold the truth within 4 standard uncertainties."""
    rng = np.random.default_rng(11)
    truth = random_errors(rng)
    rots = Rotation.random(4, random_state=12).as_matrix()
    mounts = {f"m{k}": r for k, r in enumerate(rots)}
    run = array_run(truth, mounts, rng, static_s=20.0)
    cal = solve(
        "sensor_array", run.segments, G, {"mounts": {k: v.tolist() for k, v in mounts.items()}}
    )
    expected = truth.parameters()
    for name, p in cal.parameters.items():
        assert abs(p.value - expected[name]) < 4 * p.std, name
    assert all(c.passed for c in check_residuals(cal, ToleranceProfile("t", "1", "t", [])))


def test_degenerate_mountings_and_bad_input_are_explained():
    rng = np.random.default_rng(13)
    truth = random_errors(rng)
    # Every sensor z up, turned about z: only the z column of the gyro matrix is seen.
    same = {f"s{k}": Rotation.from_euler("z", 90 * k, degrees=True).as_matrix() for k in range(3)}
    run = array_run(truth, same, rng, static_s=5.0)
    with pytest.raises(ValueError, match="fewer than three sensor axes"):
        solve("sensor_array", run.segments, G, {"mounts": same})
    cube = array_run(truth, cube_mounts(), rng, static_s=5.0)
    segs = dict(cube.segments)
    del segs["s4_cw"]
    with pytest.raises(ValueError, match=r"sensor 's4' lacks segments s4_cw"):
        solve("sensor_array", segs, G, {})
    with pytest.raises(ValueError, match=r"settings.mounts.s1: expected a 3x3 rotation"):
        solve("sensor_array", cube.segments, G, {"mounts": {"s1": [[1, 0], [0, 1]]}})


def test_a_spike_in_a_turn_is_replaced_and_counted():
    """The turns' static data (pooled into the gyro bias and g-sensitivity) are despiked;
    the replaced sample is counted per record and channel (archived with the solve), not
    silently altered: a 200-sigma spike on s1's y channel in its ccw record, at rest."""
    rng = np.random.default_rng(3)
    truth = random_errors(rng)
    run = array_run(truth, cube_mounts(), rng, static_s=10.0, rate_hz=50.0)
    clean = solve("sensor_array", run.segments, run.gravity, {})
    rec = run.segments["s1_ccw"]
    gyr = rec.gyr.copy()
    gyr[3, 1] += 200.0 * truth.gyr_noise[1]
    segments = {**run.segments, "s1_ccw": replace(rec, gyr=gyr)}
    cal = solve("sensor_array", segments, run.gravity, {})
    counts = cal.info["replaced_samples"]["despike"]
    assert counts["s1_ccw"]["gyr.y"] >= 1
    assert clean.info["replaced_samples"]["despike"]["s1_ccw"]["gyr.y"] == 0
    for a in "xyz":
        name = f"gyr.bias.{a}"
        assert abs(cal.parameters[name].value - clean.parameters[name].value) < (
            0.5 * cal.parameters[name].std
        ), name
