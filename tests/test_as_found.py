"""As found / as left (calib_core.as_found): the earlier calibration applied to
a recalibrated simulated unit's new raw samples, the error model solved again on them."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from calib_core import as_found, procedures
from calib_core.decision import FAIL, PASS
from calib_core.run_budget import run_budgets
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.simulate.lab_run import TrueErrors
from calib_core.tolerances import ToleranceProfile
from calib_core.units import STANDARD_GRAVITY

PROCEDURE = "six_position_integral"
DRIFT = -0.002  # acc.scale.x of the unit between its two calibrations
# The profile's limits: acc.scale.* within 0.001 (the drift leaves twice that as found),
# biases and the rest generous.
PROFILE = ToleranceProfile.from_dict({
    "name": "t", "version": "1", "device_model": "X",
    "limits": [{"pattern": "acc.scale.*", "bound": 0.001, "unit": "1"},
               {"pattern": "acc.bias.*", "bound": 0.05, "unit": "m/s^2"},
               {"pattern": "gyr.bias.*", "bound": 0.05, "unit": "deg/s"}],
})  # fmt: skip


def _solve(truth: TrueErrors, seed: int):
    run = six_position_integral_run(truth, np.random.default_rng(seed), static_s=5.0)
    segments = dict(run.segments)
    return procedures.solve(PROCEDURE, segments, STANDARD_GRAVITY, {}), segments


def _found_truth(old, new: TrueErrors) -> dict[str, float]:
    """The exact error model of `new` seen through the correction by calibration `old`
    (module docstring of calib_core.as_found): what the as-found solve should find."""
    A, Ag = np.eye(3) + old.matrix("acc"), np.eye(3) + old.matrix("gyr")
    acc_M = np.linalg.solve(A, np.eye(3) + new.acc_M) - np.eye(3)
    acc_b = np.linalg.solve(A, new.acc_bias - old.vector("acc", "bias"))
    # w_c = Ag^-1 (w_meas - bg_old - G_old f_c), f_c = (I + acc_M) f + acc_b
    gyr_M = np.linalg.solve(Ag, np.eye(3) + new.gyr_M) - np.eye(3)
    gsens = np.linalg.solve(Ag, new.gsens - old.gsens() @ (np.eye(3) + acc_M))
    gyr_b = np.linalg.solve(Ag, new.gyr_bias - old.vector("gyr", "bias") - old.gsens() @ acc_b)
    return TrueErrors(acc_b, acc_M, gyr_b, gyr_M, gsens, new.acc_noise, new.gyr_noise).parameters()


@pytest.fixture(scope="module")
def unit():
    """A simulated unit calibrated once (the earlier calibration) and its truth."""
    truth = random_errors(np.random.default_rng(21))
    earlier, _ = _solve(truth, 1)
    return truth, earlier


def _as_found(unit, drift: float):
    truth, earlier = unit
    new = copy.deepcopy(truth)
    new.acc_M[0, 0] += drift
    as_left, segments = _solve(new, 2)
    found = as_found.evaluate(earlier, segments, PROCEDURE, STANDARD_GRAVITY, {})
    budgets = run_budgets(as_left, segments, {}, None)
    rows = {r.parameter: r for r in as_found.judge(found, earlier, as_left, budgets, PROFILE)}
    return rows, found, _found_truth(earlier, new), earlier


def test_as_found_error_of_a_drifted_unit_is_its_drift(unit) -> None:
    rows, found, expected, earlier = _as_found(unit, DRIFT)
    assert ".noise." not in " ".join(rows) and len(rows) == 33  # 3 + 9 + 3 + 9 + 9 (G)
    for name, r in rows.items():
        # The as-found solve on 5-s attitudes estimates `expected` with its fit's standard
        # uncertainty `r.std` (white noise, unbiased least squares): |error| <= 5 std fails
        # with probability 6e-7 per parameter.
        assert abs(r.error - expected[name]) <= 5 * r.std, (name, r.error, expected[name])
    # Against the known drift alone: the as-found acc.scale.x is d [(I + M_old)^-1]_00 =
    # d / (1 + s_old) up to second order in the earlier misalignments (|d| 0.01), plus the
    # noise of both fits (the earlier estimate's error stays in the corrected data).
    scale = rows["acc.scale.x"]
    s_old, std_old = earlier.value("acc.scale.x"), earlier.parameters["acc.scale.x"].std
    bound = 5 * np.hypot(scale.std, std_old) + abs(DRIFT) * 0.01
    assert abs(scale.error - DRIFT / (1 + s_old)) <= bound, (scale.error, bound)
    assert abs(scale.error) > 5 * bound  # far from zero: no drift would fail this
    # 0.002 outside the 0.001 limit with U ~ 1e-4: fail as found.
    assert scale.verdict == FAIL
    assert scale.earlier == earlier.value("acc.scale.x") and scale.U > 0 and scale.k >= 1.96


def test_as_found_of_a_unit_that_did_not_drift_is_within_tolerance(unit) -> None:
    rows, *_ = _as_found(unit, 0.0)
    _, earlier = unit
    for name, r in rows.items():
        # Zero error as found, up to the noise of both fits: the earlier estimate's error
        # (its std) stays in the corrected data, the new fit adds its own.
        bound = 5 * np.hypot(r.std, earlier.parameters[name].std)
        assert abs(r.error) <= bound, (name, r.error, bound)
        assert r.verdict in (None, PASS), (name, r.verdict)
    assert rows["acc.scale.x"].verdict == PASS


def test_as_found_refused_as_the_solve_is() -> None:
    truth = random_errors(np.random.default_rng(3))
    earlier, segments = _solve(truth, 4)
    del segments["x_up"]
    with pytest.raises(ValueError, match="x_up"):
        as_found.evaluate(earlier, segments, PROCEDURE, STANDARD_GRAVITY, {})
