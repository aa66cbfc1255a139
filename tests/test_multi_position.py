"""Multi-position least squares from table attitudes: rotations, schemes, models, statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib_core.attitude import pitch_roll_from_direction, specific_force, table_attitude
from calib_core.checks import check_residuals
from calib_core.procedures import solve
from calib_core.simulate.attitudes import multi_position_run, scheme_angles
from calib_core.simulate.lab_run import random_errors
from calib_core.solvers.accel_models import solve_accel_multi
from calib_core.solvers.multi_position import solve_accel_linear
from calib_core.tolerances import ToleranceProfile
from calib_core.units import DEG

G = 9.80665
K2 = np.array([2e-4, -3e-4, 1.5e-4])  # 1/(m/s^2): 0.02 .. 0.03 m/s^2 at 1 g
K3 = np.array([-2e-5, 1e-5, 3e-5])  # 1/(m/s^2)^2: 0.01 .. 0.03 m/s^2 at 1 g
PROFILE = ToleranceProfile("test", "1", "test", [])


def test_table_rotations_match_scipy():
    """Pitch/roll and azimuth/pitch tables against scipy's intrinsic Euler rotations."""
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-math.pi, math.pi, (2, 20))
    np.testing.assert_allclose(
        table_attitude(a, b, "pitch_roll"),
        Rotation.from_euler("YX", np.column_stack([a, b])).as_matrix(),
        atol=1e-14,
    )
    np.testing.assert_allclose(
        table_attitude(a, b, "azimuth_pitch"),
        Rotation.from_euler("ZY", np.column_stack([a, b])).as_matrix(),
        atol=1e-14,
    )
    # The closed form of the module docstring, and its inverse.
    f = specific_force(table_attitude(a, b), 1.0)
    np.testing.assert_allclose(
        f, np.column_stack([-np.sin(a), np.cos(a) * np.sin(b), np.cos(a) * np.cos(b)]), atol=1e-14
    )
    p, r = pitch_roll_from_direction(f)
    np.testing.assert_allclose(specific_force(table_attitude(p, r), 1.0), f, atol=1e-12)
    # Azimuth does not move gravity in the body; a mounting does.
    f_az = specific_force(table_attitude(a, np.zeros(20), "azimuth_pitch"), G)
    np.testing.assert_allclose(f_az, np.tile([0, 0, G], (20, 1)), atol=1e-12)
    mount = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    np.testing.assert_allclose(
        specific_force(table_attitude(0.0, 0.0, mount=mount), G), [0, G, 0], atol=1e-12
    )


def test_position_schemes():
    faces = specific_force(table_attitude(*scheme_angles(6).T), 1.0)
    np.testing.assert_allclose(np.sort(np.abs(faces).max(axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(faces).sum(axis=0), [2, 2, 2], atol=1e-12)
    edges = specific_force(table_attitude(*scheme_angles(12).T), 1.0)
    np.testing.assert_allclose(np.sort(np.abs(edges), axis=1)[:, 1:], 1 / math.sqrt(2), atol=1e-12)
    f18 = specific_force(table_attitude(*scheme_angles(18).T), 1.0)
    assert len({tuple(np.round(v, 9)) for v in f18}) == 18
    f24 = specific_force(table_attitude(*scheme_angles(24).T), 1.0)
    # The last six repeat the faces through the other angle solution.
    np.testing.assert_allclose(f24[18:], f24[:6], atol=1e-12)
    assert not np.allclose(scheme_angles(24)[18:], scheme_angles(24)[:6])
    with pytest.raises(ValueError, match="scheme 7"):
        scheme_angles(7)


def test_full_model_equals_linear_solver_on_six_positions():
    rng = np.random.default_rng(1)
    truth = random_errors(rng)
    f = specific_force(table_attitude(*scheme_angles(6).T), G)
    means = truth.acc_measured(f) + rng.normal(0, 1e-3, (6, 3))
    sem = rng.uniform(5e-4, 2e-3, (6, 3))
    multi = solve_accel_multi(f, means, sem, "full")
    linear = solve_accel_linear(f, means, sem)
    for name, v in linear.params.items():
        assert multi.params[name] == pytest.approx(v, abs=1e-12)
        assert multi.std[name] == pytest.approx(linear.std[name], rel=1e-10)
    assert not multi.warnings and not multi.not_separable


def _run(seed: int, n_positions: int, **kw):
    rng = np.random.default_rng(seed)
    truth = random_errors(rng)
    run = multi_position_run(truth, scheme_angles(n_positions), rng, k2=K2, k3=K3, **kw)
    return run


@pytest.mark.parametrize("n_positions", [18, 24])
def test_nonlinear_model_truth_and_uncertainty_over_seeds(n_positions):
    """18-coefficient model (plus gyro bias and g-sensitivity) from 30 simulated runs.

    Every estimate within 4 reported standard uncertainties; per parameter the
    scatter of the errors over 30 seeds / mean reported std in [0.5, 2]: with 30
    draws a sample std is within +-40 % of the truth with probability > 0.999.
    """
    errors, stds = [], []
    for seed in range(30):
        run = _run(seed, n_positions, static_s=5.0)
        settings = {"model": "nonlinear", "attitudes": run.attitudes_setting()}
        cal = solve("multi_position", run.segments, run.gravity, settings)
        assert not cal.warnings, cal.warnings
        assert cal.info["separable"] is True
        truth = run.truth.parameters()
        names = [n for n in cal.parameters if ".noise." not in n]
        assert len([n for n in names if n.startswith("acc.")]) == 18
        errors.append([cal.parameters[n].value - truth[n] for n in names])
        stds.append([cal.parameters[n].std for n in names])
    errors, stds = np.array(errors), np.array(stds)
    z = errors / stds
    assert np.abs(z).max() < 4.0, names[int(np.argmax(np.abs(z).max(axis=0)))]
    ratio = errors.std(axis=0, ddof=1) / stds.mean(axis=0)
    assert np.all((ratio > 0.5) & (ratio < 2.0)), dict(zip(names, np.round(ratio, 2), strict=True))


@pytest.mark.slow
@pytest.mark.parametrize("model", ["full", "reduced", "nonlinear"])
def test_linear_models_reach_the_cramer_rao_bound(model):
    """White noise: the scatter of the estimates is the CRLB sigma^2 / n (A^T A)^-1.

    The bound is computed here from the design matrix of each axis (its columns
    written out independently of the solver) and the true per-sample noise.
    200 runs: a sample std scatters by 1/sqrt(400) = 5 %, so 1.2 is 4 of those
    (worst of up to 18 parameters); 0.8 below catches a bound computed wrongly.
    """
    n_runs, n_positions, static_s, rate_hz = 200, 18, 2.0, 100.0
    n = int(static_s * rate_hz)
    k2 = K2 if model == "nonlinear" else None
    k3 = K3 if model == "nonlinear" else None
    truth = random_errors(np.random.default_rng(99))
    angles = scheme_angles(n_positions)
    f = specific_force(table_attitude(*angles.T), G)
    errors = []
    for seed in range(n_runs):
        rng = np.random.default_rng(1000 + seed)
        run = multi_position_run(
            truth, angles, rng, k2=k2, k3=k3, static_s=static_s, rate_hz=rate_hz
        )
        if model == "reduced":
            # The reduced model is exact only without cross-axis terms.
            for rec, fk in zip(run.segments.values(), f, strict=True):
                rec.acc[:] += fk @ (np.diag(np.diag(truth.acc_M)) - truth.acc_M).T
        settings = {"model": model, "attitudes": run.attitudes_setting(), "gyro_gsens": False}
        cal = solve("multi_position", run.segments, G, settings)
        params = run.truth.parameters()
        names = [p for p in cal.parameters if ".noise." not in p]
        errors.append([cal.parameters[p].value - params[p] for p in names])
    observed = np.array(errors).std(axis=0, ddof=1)
    crlb = []
    for i in range(3):
        cols = [np.ones(len(f))]
        cols += [f[:, i]] if model == "reduced" else [f[:, 0], f[:, 1], f[:, 2]]
        if model == "nonlinear":
            cols += [f[:, i] ** 2, f[:, i] ** 3]
        a = np.column_stack(cols)
        crlb += list(np.sqrt(np.diag(np.linalg.inv(a.T @ a)) * truth.acc_noise[i] ** 2 / n))
    # The solver lists per axis: bias, matrix row (or scale), k2, k3 - the order above.
    ratio = observed / np.array(crlb)
    assert np.all(ratio < 1.2), dict(zip(names, np.round(ratio, 3), strict=True))
    assert np.all(ratio > 0.8), dict(zip(names, np.round(ratio, 3), strict=True))


def test_position_sets_that_cannot_separate_terms_are_flagged():
    """k3 f^3 = g^2 f on +-1 g faces (the scale column again); on the 45 deg edges
    f_i^3 = (g^2 / 2) f_i for every nonzero f_i: both are flagged and archived."""
    for n_positions in (6, 12):
        run = _run(3, n_positions)
        cal = solve(
            "multi_position",
            run.segments,
            G,
            {"model": "nonlinear", "attitudes": run.attitudes_setting()},
        )
        assert cal.info["separable"] is False
        assert cal.info["not_separable"] == ["acc.k3.x", "acc.k3.y", "acc.k3.z"]
        assert any("cannot separate acc.k3.x, acc.k3.y, acc.k3.z" in w for w in cal.warnings)
        assert "acc.k3.x" not in cal.parameters and "acc.k2.x" in cal.parameters
        assert cal.to_dict()["info"]["separable"] is False  # archived with the calibration
    # Own-axis quadratic terms are separable from the faces (the other faces read 0 g
    # on that axis), a fact the flag must not hide.
    six = _run(3, 6)
    cal = solve(
        "multi_position",
        six.segments,
        G,
        {"model": "quadratic", "attitudes": six.attitudes_setting()},
    )
    assert cal.info["separable"] is True
    # Nearly collinear positions: the condition number is reported and warned about.
    angles = np.column_stack([np.zeros(6), np.linspace(-1, 1, 6) * 0.01 * DEG])
    rng = np.random.default_rng(4)
    near = multi_position_run(random_errors(rng), angles, rng)
    cal = solve(
        "multi_position",
        near.segments,
        G,
        {"model": "reduced", "attitudes": near.attitudes_setting()},
    )
    assert cal.info["not_separable"]


def test_attitudes_from_reference_channels_and_faces():
    run = _run(5, 18, reference_channels=True)
    by_settings = solve("multi_position", run.segments, G, {"attitudes": run.attitudes_setting()})
    by_channels = solve("multi_position", run.segments, G, {})
    for name, p in by_settings.parameters.items():
        assert by_channels.parameters[name].value == pytest.approx(p.value, abs=1e-12)
    # Face labels need no attitude at all.
    six = _run(6, 6)
    faces = {
        lab: rec.with_label(lab)
        for lab, rec in zip(
            ("x_up", "x_dn", "y_up", "y_dn", "z_up", "z_dn"), six.segments.values(), strict=True
        )
    }
    a = solve("multi_position", faces, G, {})
    b = solve("multi_position", six.segments, G, {"attitudes": six.attitudes_setting()})
    for name, p in b.parameters.items():
        assert a.parameters[name].value == pytest.approx(p.value, abs=1e-9)


def test_missing_or_bad_attitude_is_named():
    run = _run(7, 12)
    att = run.attitudes_setting()
    del att["p03"]
    with pytest.raises(ValueError, match=r"segment 'p03'.*settings.attitudes.p03"):
        solve("multi_position", run.segments, G, {"attitudes": att})
    att = run.attitudes_setting()
    att["p05"] = {"pitch_deg": 10.0}
    with pytest.raises(
        ValueError, match=r"settings.attitudes.p05: expected numbers pitch_deg and roll_deg"
    ):
        solve("multi_position", run.segments, G, {"attitudes": att})
    with pytest.raises(ValueError, match="settings.model"):
        solve(
            "multi_position",
            run.segments,
            G,
            {"model": "cubic", "attitudes": run.attitudes_setting()},
        )


def test_residual_check_flags_an_unmodelled_quadratic_term():
    """The Foundation's residual check on the per-position residuals: the linear model
    passes on linear data and fails when a large k2 is left out."""
    rng = np.random.default_rng(8)
    truth = random_errors(rng)
    angles = scheme_angles(18)
    clean = multi_position_run(truth, angles, rng)
    checks = check_residuals(
        solve("multi_position", clean.segments, G, {"attitudes": clean.attitudes_setting()}),
        PROFILE,
    )
    assert checks and all(c.passed for c in checks)
    # k2 = 1e-3 puts ~0.1 m/s^2 at 1 g, five times the 0.002 g limit on the residual mean.
    bent = multi_position_run(truth, angles, rng, k2=np.array([1e-3, 0, 0]))
    checks = check_residuals(
        solve("multi_position", bent.segments, G, {"attitudes": bent.attitudes_setting()}), PROFILE
    )
    assert not all(c.passed for c in checks)
    fixed = solve(
        "multi_position",
        bent.segments,
        G,
        {"model": "quadratic", "attitudes": bent.attitudes_setting()},
    )
    assert all(c.passed for c in check_residuals(fixed, PROFILE))


def test_rate_table_and_static_bias_are_selectable_procedures():
    """The registry wrappers give exactly what the solvers give when called directly."""
    from calib_core.simulate.noise import NoiseSpec, simulate_static
    from calib_core.simulate.rate_table import GyroTruth, simulate_rate_table
    from calib_core.solvers.rate_table import rate_points, solve_rate_table
    from calib_core.solvers.static_bias import solve_static_bias

    rng = np.random.default_rng(21)
    truth = GyroTruth(bias=np.array([0.01, -0.02, 0.005]), M=np.diag([0.01, -0.02, 0.015]))
    run = simulate_rate_table(truth, rate_hz=100.0, gyro_noise_density=0.01 * DEG, rng=rng)
    segments = {rec.label: rec for rec in run.recordings}
    via_registry = solve("rate_table", segments, G, {})
    direct = solve_rate_table(rate_points(run.recordings))
    assert via_registry.parameters == direct.parameters
    for i, a in enumerate("xyz"):
        p = via_registry.parameters[f"gyr.scale.{a}"]
        assert abs(p.value - truth.M[i, i]) < 4 * p.std
    rec = simulate_static(
        120.0,
        100.0,
        gyro_bias=np.array([1e-3, -2e-3, 5e-4]),
        gyro_noise=NoiseSpec(arw=1e-4),
        rng=rng,
    )
    via_registry = solve("static_bias", {"long": rec}, G, {"up_axis": "+z"})
    direct = solve_static_bias(rec, up_axis="+z", gravity=G)
    assert via_registry.parameters == direct.parameters
    assert any("procedure asks for >= 60 min" in w for w in via_registry.warnings)
    with pytest.raises(ValueError, match="static_bias: expected one static segment, got 2"):
        solve("static_bias", {"a": rec, "b": rec}, G, {})


def test_archived_covariance_matches_the_reported_uncertainties():
    run = _run(9, 18)
    cal = solve(
        "multi_position",
        run.segments,
        G,
        {"model": "nonlinear", "attitudes": run.attitudes_setting()},
    )
    cov = cal.info["acc_covariance"]
    assert len(cov["names"]) == 18
    for k, name in enumerate(cov["names"]):
        assert math.sqrt(cov["matrix"][k][k]) == pytest.approx(cal.parameters[name].std, rel=1e-12)


def test_a_mean_without_scatter_is_refused_before_its_uncertainty() -> None:
    """One position's sem at the rounding of its mean (its samples one repeated reading)
    leaves the weighted fit without defined variances: refused, naming the position,
    before a square root makes a NaN; `Calibration.add_fit` refuses such a variance too."""
    import warnings

    from calib_core.calibration import Calibration

    g = 9.80665
    f_true = np.array([[g, 0, 0], [-g, 0, 0], [0, g, 0], [0, -g, 0], [0, 0, g], [0, 0, -g]])
    means = f_true + 0.01
    sem = np.full((6, 3), 3e-5)  # m/s^2
    sem[0] = np.spacing(g)  # position 1: no scatter above rounding
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"no defined uncertainty.*position 1, axis x"):
            solve_accel_linear(f_true, means, sem)
        with pytest.raises(ValueError, match=r"acc\.bias\.y: the fit gives it the variance -1"):
            cal = Calibration("six_position", g)
            cal.add_fit(["acc.bias.x", "acc.bias.y"], {}, np.diag([1.0, -1.0]))
