"""Procedures end to end on simulated runs: each recovers the simulator's truth."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from calib_core.calibration import Calibration
from calib_core.procedures import PROCEDURES, solve, solve_step
from calib_core.simulate import (
    ROTATION_LABELS,
    STATIC_LABELS,
    axis_vector,
    random_errors,
    six_position_integral_run,
)

SEEDS = range(30)


def errors_over_seeds(procedure: str, settings: dict, **sim):
    errs: dict[str, list[float]] = {}
    stds: dict[str, list[float]] = {}
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        truth = random_errors(rng)
        run = six_position_integral_run(truth, rng, **sim)
        cal = solve(procedure, run.segments, run.gravity, settings)
        true = truth.parameters()
        for name, p in cal.parameters.items():
            errs.setdefault(name, []).append(p.value - true[name])
            stds.setdefault(name, []).append(p.std)
    return {n: np.array(v) for n, v in errs.items()}, {n: np.array(v) for n, v in stds.items()}


@pytest.mark.parametrize(
    "settings, sim",
    [
        ({}, {}),
        ({"accel_solver": "closed_form"}, {"turns": 2, "cw_pause_s": 4.0}),
    ],
)
def test_every_parameter_within_4_std_and_uncertainties_honest(settings, sim):
    errs, stds = errors_over_seeds("six_position_integral", settings, **sim)
    assert len(errs) == 12 + 12 + 9 + 6  # acc 12, gyro 12 + g-sensitivity 9, noise 6
    for name in errs:
        e, s = errs[name], stds[name]
        assert np.all(s > 0), name
        assert np.all(np.abs(e) <= 4 * s), (name, np.max(np.abs(e) / s))
        # Honest: the rms error over 30 seeds (known to ~13 %) vs the mean reported std.
        ratio = math.sqrt(np.mean(e**2)) / s.mean()
        assert 0.5 <= ratio <= 2.0, (name, ratio)


def test_reported_std_has_the_size_the_noise_predicts():
    """Closed-form check of the uncertainties the acceptance test relies on."""
    rng = np.random.default_rng(0)
    truth = random_errors(rng)
    run = six_position_integral_run(truth, rng)
    cal = solve("six_position", run.segments, run.gravity, {})
    # A bias averaged over six 1000-sample positions: sigma / sqrt(6 * 1000).
    predicted = truth.acc_noise / math.sqrt(1000 * 6)
    got = np.array([cal.parameters[f"acc.bias.{a}"].std for a in "xyz"])
    # sems use the sample std (relative std 2 %) and the weighted mean: within 10 %.
    np.testing.assert_allclose(got, predicted, rtol=0.1)


def test_six_position_statics_only():
    rng = np.random.default_rng(1)
    truth = random_errors(rng)
    run = six_position_integral_run(truth, rng)
    statics = {k: run.segments[k] for k in STATIC_LABELS}
    cal = solve("six_position", statics, run.gravity, {})
    assert not any(n.startswith(("gyr.scale", "gyr.misalign")) for n in cal.parameters)
    assert len(cal.parameters) == 12 + 12 + 6
    assert cal.info["condition_number"] == pytest.approx(math.sqrt(3))
    assert cal.info["sample_counts"] == {k: 1000 for k in STATIC_LABELS}


def test_missing_segments_are_named():
    rng = np.random.default_rng(2)
    run = six_position_integral_run(random_errors(rng), rng)
    segs = dict(run.segments)
    del segs["x_dn"], segs["z_cw"]
    with pytest.raises(ValueError, match=r"missing segments x_dn, z_cw"):
        solve("six_position_integral", segs, run.gravity, {})
    with pytest.raises(ValueError, match="x_dn"):
        solve("six_position", segs, run.gravity, {})


def test_bad_procedure_settings_and_gravity():
    rng = np.random.default_rng(3)
    run = six_position_integral_run(random_errors(rng), rng)
    with pytest.raises(ValueError, match="unknown procedure 'tumble'"):
        solve("tumble", run.segments, run.gravity, {})
    with pytest.raises(ValueError, match="settings.accel_solver"):
        solve("six_position", run.segments, run.gravity, {"accel_solver": "kalmann"})
    with pytest.raises(ValueError, match="settings.turns"):
        solve("six_position_integral", run.segments, run.gravity, {"turns": 1.5})
    with pytest.raises(ValueError, match="gravity"):
        solve("six_position", run.segments, 1.0, {})  # in g, not m/s^2
    assert {"six_position", "six_position_integral"} <= set(PROCEDURES)


def test_rotation_beyond_range_rejected_through_procedure():
    rng = np.random.default_rng(4)
    run = six_position_integral_run(
        random_errors(rng), rng, rotation_rate_dps=600.0, gyro_range_dps=500.0
    )
    with pytest.raises(ValueError, match="rotation x_ccw"):
        solve("six_position_integral", run.segments, run.gravity, {"gyro_range_dps": 500.0})


def test_residuals_info_and_json_round_trip():
    rng = np.random.default_rng(5)
    truth = random_errors(rng)
    run = six_position_integral_run(truth, rng, turns=2)
    cal = solve("six_position_integral", run.segments, run.gravity, {"turns": None})
    keys = {(r.segment, r.sensor) for r in cal.residuals}
    assert keys == {(s, sen) for s in STATIC_LABELS for sen in ("acc", "gyr")} | {
        (s, "acc") for s in ROTATION_LABELS
    }
    for r in cal.residuals:
        noise = truth.acc_noise if r.sensor == "acc" else truth.gyr_noise
        # Residual std is the noise (relative std ~ 1/sqrt(2N) <= 3 %); the mean is zero
        # to within noise / sqrt(N) (plus the fit's own error of similar size): 5 of those.
        np.testing.assert_allclose(r.std, noise, rtol=0.12)
        assert np.all(np.abs(r.mean) < 5 * noise / math.sqrt(r.n) * math.sqrt(2))
    assert cal.info["turns"] == 2
    assert cal.procedure == "six_position_integral"
    assert cal.info["sample_counts"]["z_cw"] == len(run.segments["z_cw"])
    back = Calibration.from_dict(json.loads(json.dumps(cal.to_dict())))
    assert back.parameters == cal.parameters


def test_applying_the_calibration_recovers_gravity():
    """Independent check: corrected statics read +-g on one axis, 0 on the others, at rest."""
    rng = np.random.default_rng(6)
    run = six_position_integral_run(random_errors(rng), rng)
    cal = solve("six_position_integral", run.segments, run.gravity, {})
    for label in STATIC_LABELS:
        corrected = cal.apply(run.segments[label])
        # Mean of 1000 samples with noise <= 0.012 m/s^2 plus calibration error: 2e-3 is
        # > 5 standard errors of either.
        np.testing.assert_allclose(
            corrected.acc.mean(axis=0), axis_vector(label, run.gravity), atol=2e-3
        )
        np.testing.assert_allclose(corrected.gyr.mean(axis=0), 0.0, atol=2e-4)


def test_solve_step_records_settings_and_counts():
    rng = np.random.default_rng(7)
    run = six_position_integral_run(random_errors(rng), rng)
    cal, step = solve_step(
        run.segments, {"procedure": "six_position_integral", "gravity": run.gravity}
    )
    assert step.name == "solve"
    assert step.settings["procedure"] == "six_position_integral"
    assert step.settings["gyro_range_dps"] == 2000.0
    assert step.statistics["turns"] == 1
    assert step.statistics["parameters"] == len(cal.parameters) == 39
