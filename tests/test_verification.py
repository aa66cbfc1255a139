"""Residual diagnosis, held-out verification and repeatability against simulated truth."""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest

from calib_core import procedures
from calib_core.calibration import CheckResult
from calib_core.checks import check_residuals, overall_verdict
from calib_core.recording import Recording
from calib_core.simulate import TrueErrors, axis_vector, random_errors, six_position_integral_run
from calib_core.tolerances import (
    DEFAULT_REPEATABILITY,
    DEFAULT_VERIFICATION_LIMITS,
    ToleranceProfile,
)
from calib_core.units import DEG, STANDARD_GRAVITY
from calib_core.verification import (
    FAIL,
    NEEDS_REVIEW,
    PASS,
    RunValues,
    comparable_runs,
    diagnose_residuals,
    reference_point,
    repeatability,
    verify_points,
)
from pipelines.tolerances import load_profile

SEEDS = (11, 12, 13)
G = STANDARD_GRAVITY
STATIC_N = 1000  # samples per static position of the simulator (20 s at 50 Hz)


@pytest.fixture(scope="module")
def profile() -> ToleranceProfile:
    return load_profile("mpu6000")


def _mean_sigma(truth: TrueErrors) -> float:
    """Standard deviation of one position's residual mean, m/s^2 (white noise / sqrt(n))."""
    return float(truth.acc_noise.max()) / math.sqrt(STATIC_N)


@pytest.mark.parametrize("seed", SEEDS)
def test_missing_cross_coupling_fails_residuals_and_is_named(seed, profile):
    rng = np.random.default_rng(seed)
    truth = random_errors(rng)
    truth.acc_M[0, 1] = 0.01  # true y leaks into measured x: 0.01 g = 10 mg at y up/down
    run = six_position_integral_run(truth, rng)

    full = procedures.solve("six_position_integral", run.segments, run.gravity, {})
    assert all(c.passed for c in check_residuals(full, profile))
    assert diagnose_residuals(full, profile).suspects == []

    reduced = procedures.solve(
        "six_position_integral", run.segments, run.gravity, {"accel_model": "per_axis"}
    )
    assert not any(n.startswith("acc.misalign") for n in reduced.parameters)
    failed = {c.name for c in check_residuals(reduced, profile) if not c.passed}
    assert {"residual:y_up:acc:mean", "residual:y_dn:acc:mean"} <= failed
    diag = diagnose_residuals(reduced, profile)
    assert not diag.passed
    top = diag.suspects[0]  # the largest pattern is the planted 0.01
    assert top.term == "acc.misalign.xy" and not top.in_model and top.kind == "linear"
    # estimate = (R_x(y up) - R_x(y dn)) / (2 g): two position means, each +-sigma
    sigma = _mean_sigma(truth) / math.sqrt(2) / G
    assert abs(top.estimate - 0.01) < 5 * sigma
    # every off-diagonal term the reduced model lacks and that exceeds half the
    # residual-mean limit (0.5 * 2 mg = 0.001 as a misalignment) is named
    big = {
        f"acc.misalign.{r}{c}"
        for i, r in enumerate("xyz")
        for j, c in enumerate("xyz")
        if i != j and abs(truth.acc_M[i, j]) > 0.001 + 5 * sigma
    }
    assert big <= {s.term for s in diag.suspects}
    assert "acc.misalign.xy" in diag.advice[0] and "cross-coupling" in diag.advice[0]
    assert diag.worst[0].segment in {"y_up", "y_dn", "y_ccw", "y_cw"} and diag.worst[0].ratio > 1


@pytest.mark.parametrize("seed", SEEDS)
def test_strong_quadratic_term_is_named(seed, profile):
    """An error the linear model lacks: acc x gets k2 f_x^2 (1e-3 / (m/s^2) = 9.6 mg/g^2)."""
    rng = np.random.default_rng(seed)
    truth = random_errors(rng)
    run = six_position_integral_run(truth, rng)
    k2 = 1e-3
    segments = {}
    for label, rec in run.segments.items():
        f = np.broadcast_to(axis_vector(label, run.gravity), rec.acc.shape)
        acc = rec.acc.copy()
        acc[:, 0] += k2 * f[:, 0] ** 2
        segments[label] = dataclasses.replace(rec, acc=acc)
    cal = procedures.solve("six_position_integral", segments, run.gravity, {})
    # x up/down residual = 2/3 k2 g^2 = 64 mg... far beyond the 2 mg limit
    assert not all(c.passed for c in check_residuals(cal, profile))
    diag = diagnose_residuals(cal, profile)
    assert [s.term for s in diag.suspects] == ["acc.k2.x"]
    # even part of two means minus the median of three such parts: within 3 sigma / g^2
    assert abs(diag.suspects[0].estimate - k2) < 5 * 3 * _mean_sigma(truth) / run.gravity**2
    assert any("quadratic" in a and "tilted positions" in a for a in diag.advice)


def _static_segment(
    truth: TrueErrors, rng: np.random.Generator, f_true: np.ndarray, label: str, n: int = 1000
) -> Recording:
    """A held-out static attitude with specific force f_true (m/s^2), simulator noise."""
    f = np.broadcast_to(f_true, (n, 3))
    acc = truth.acc_measured(f) + rng.standard_normal((n, 3)) * truth.acc_noise
    gyr = truth.gyr_measured(np.zeros((n, 3)), f) + rng.standard_normal((n, 3)) * truth.gyr_noise
    return Recording(np.arange(n) / 50.0, acc, gyr, np.full(n, 20.0), label=label)


@pytest.mark.parametrize("seed", SEEDS)
def test_verification_point_with_002_g_error_fails(seed, profile):
    rng = np.random.default_rng(seed)
    truth = random_errors(rng)
    run = six_position_integral_run(truth, rng)
    cal = procedures.solve("six_position_integral", run.segments, run.gravity, {})
    a = math.radians(35.0)
    f_tilt = run.gravity * np.array(
        [math.sin(a) * math.cos(0.4), math.sin(a) * math.sin(0.4), math.cos(a)]
    )
    segments = {"tilt_35": _static_segment(truth, rng, f_tilt, "tilt_35")}
    good = verify_points(cal, segments, [reference_point("tilt_35", run.gravity, f_tilt)], profile)
    assert [c.name for c in good] == ["verify:tilt_35:acc", "verify:tilt_35:gyr"]
    # clean: error ~ parameter uncertainty + noise / sqrt(n) ~ 1e-3 m/s^2, limit 0.098
    assert all(c.passed for c in good) and good[0].value < 0.01 * profile.verification_limits["acc"]
    assert good[0].limit == pytest.approx(0.01 * G)
    assert good[1].limit == pytest.approx(0.5 * DEG)

    # the reference is off by 0.02 g along y (a wrongly set tilt): the check must fail
    wrong = f_tilt + np.array([0.0, 0.02 * G, 0.0])
    bad = verify_points(cal, segments, [reference_point("tilt_35", run.gravity, wrong)], profile)
    assert not bad[0].passed and bad[1].passed
    assert bad[0].value == pytest.approx(0.02 * G, abs=0.01 * 0.02 * G + good[0].value)
    assert overall_verdict(bad) == FAIL


def test_reference_point_from_label_and_errors():
    ref = reference_point("z_dn_2", 9.8)
    np.testing.assert_array_equal(ref.acc, [0.0, 0.0, -9.8])
    np.testing.assert_array_equal(ref.gyr, [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="tilt_1.*reference_acc"):
        reference_point("tilt_1", 9.8)
    with pytest.raises(ValueError, match="3 finite numbers"):
        reference_point("tilt_1", 9.8, np.array([1.0, 2.0]))


def _run_values(truth: TrueErrors, rng: np.random.Generator, run_id: str) -> RunValues:
    run = six_position_integral_run(truth, rng)
    cal = procedures.solve("six_position_integral", run.segments, run.gravity, {})
    return RunValues(run_id, 20.0, {n: (p.value, p.std) for n, p in cal.parameters.items()})


@pytest.mark.parametrize("seed", SEEDS)
def test_repeatability_clean_passes_and_2_percent_scale_change_fails(seed, profile):
    rng = np.random.default_rng(seed)
    truth = random_errors(rng)
    runs = [_run_values(truth, rng, f"R{i}") for i in range(3)]
    checks = repeatability(runs, profile)
    assert len(checks) == 39  # 6 scale (cv) + 33 other parameters with uncertainties (scatter)
    assert all(c.passed for c in checks), [c for c in checks if not c.passed]
    assert overall_verdict(checks) == PASS
    rules = {c.name: c.detail.split(":")[0] for c in checks}
    assert rules["repeat:acc.scale.y"] == "rule cv" and rules["repeat:acc.bias.x"] == "rule scatter"

    changed = copy.deepcopy(truth)
    changed.acc_M[1, 1] = (1.0 + truth.acc_M[1, 1]) * 1.02 - 1.0  # K_y 2 % larger
    runs[1] = _run_values(changed, rng, "R1b")
    checks = repeatability(runs, profile)
    failed = [c for c in checks if not c.passed]
    assert [c.name for c in failed] == ["repeat:acc.scale.y"]
    # CV of (K, K, 1.02 K) = 0.02 / sqrt(3) / (1 + 0.02 / 3); the estimation noise of K
    # (~2e-5) moves it by far less than 1e-3
    assert failed[0].value == pytest.approx(0.02 / math.sqrt(3) / (1 + 0.02 / 3), abs=1e-3)
    assert overall_verdict(checks + [CheckResult("param:acc.bias.x", 0.1, 0.5, True)]) == (
        NEEDS_REVIEW
    )


def test_repeatability_needs_min_runs_and_scatter_rule_catches_bias_jump(profile):
    rng = np.random.default_rng(5)
    truth = random_errors(rng)
    runs = [_run_values(truth, rng, f"R{i}") for i in range(3)]
    assert repeatability(runs[:2], profile) == []
    # a bias jump of 20 reported uncertainties in one run
    name = "acc.bias.z"
    value, std = runs[2].values[name]
    runs[2].values[name] = (value + 20 * std, std)
    failed = [c.name for c in repeatability(runs, profile) if not c.passed]
    assert failed == [f"repeat:{name}"]


def test_comparable_runs_by_temperature():
    cur = RunValues("A", 20.0, {})
    temps = {"B": 21.5, "C": 25.0, "A": 20.0, "D": None, "E": 19.0, "F": 20.0}
    others = [RunValues(run_id, t, {}) for run_id, t in temps.items()]
    assert [r.run_id for r in comparable_runs(cur, others, 2.0, 5)] == ["A", "B", "E", "F"]
    assert [r.run_id for r in comparable_runs(cur, others, 2.0, 2)] == ["A", "B"]
    unknown = RunValues("U", None, {})
    assert [r.run_id for r in comparable_runs(unknown, others, 2.0, 5)] == ["U", "D"]


def test_profile_verification_and_repeatability_fields(profile):
    assert profile.version == "3"
    assert profile.verification_limits["acc"] == pytest.approx(0.01 * G)
    assert profile.verification_limits["gyr"] == pytest.approx(0.5 * DEG)
    assert profile.repeatability["cv_max"] == 0.01 and profile.repeatability["min_runs"] == 3
    # an older profile without the new sections gets the defaults (backward compatible)
    old = ToleranceProfile.from_dict({"name": "old", "version": "1", "device_model": "X"})
    assert old.verification_limits == DEFAULT_VERIFICATION_LIMITS
    assert old.repeatability == DEFAULT_REPEATABILITY
    again = ToleranceProfile.from_dict(profile.to_dict())
    assert again.verification_limits == pytest.approx(profile.verification_limits)
    assert again.repeatability == profile.repeatability
    base = {"name": "p", "version": "1", "device_model": "X"}
    with pytest.raises(ValueError, match=r"verification_limits\.acc\.unit.*acceleration"):
        ToleranceProfile.from_dict(
            {**base, "verification_limits": {"acc": {"value": 1, "unit": "deg/s"}}}
        )
    with pytest.raises(
        ValueError, match=r"repeatability\.cv_max: expected a number in \(0, 1\), got 5"
    ):
        ToleranceProfile.from_dict({**base, "repeatability": {"cv_max": 5}})
    with pytest.raises(
        ValueError, match=r"repeatability\.bogus: unknown setting of \[repeatability\]"
    ):
        ToleranceProfile.from_dict({**base, "repeatability": {"bogus": 1}})
