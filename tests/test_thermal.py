"""Thermal compensation fits against a simulator with known polynomial truth."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from calib_core import params, procedures
from calib_core.simulate.thermal import random_thermal_truth, soak_sweep, thermal_campaign
from calib_core.solvers.six_position import axis_vector
from calib_core.thermal import (
    COOLING,
    HEATING,
    CampaignPoint,
    ThermalModel,
    ThermalPoint,
    ThermalRangeError,
    campaign_points,
    directions_from_sequence,
    fit_campaign,
    fit_model,
    shift_polynomial,
    sweep_points,
)

SEEDS = range(10)
ORDERS = {"acc.bias": 2, "gyr.bias": 3, "acc.scale": 1, "gyr.scale": 1}
TEMPS = (-10.0, 0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
T_REF = 25.0


def _campaign(seed: int):
    rng = np.random.default_rng(seed)
    truth = random_thermal_truth(rng, ORDERS, t_ref=T_REF)
    runs = thermal_campaign(truth, rng, TEMPS)
    points = [
        CampaignPoint(
            r.temperature,
            procedures.solve("six_position_integral", r.run.segments, r.run.gravity, {}),
            r.direction,
        )
        for r in runs
    ]
    return truth, points, fit_campaign(points, t_ref=T_REF)


@pytest.fixture(scope="module")
def campaigns():
    """Ten simulated campaigns (8 temperature points each), solved and fitted (~10 s)."""
    return [_campaign(seed) for seed in SEEDS]


def test_chosen_order_equals_true_order_in_9_of_10_seeds(campaigns):
    thermal_names = [f"{fam}.{a}" for fam in ORDERS for a in params.AXES]
    for name in thermal_names:
        right = sum(model.curves[name].order == truth.order(name) for truth, _, model in campaigns)
        assert right >= 9, f"{name}: true order chosen in {right} of {len(campaigns)} seeds"
    # Parameters without thermal dependence: each step down from the cap is one test at
    # alpha = 0.01 (3 steps), so order 0 should come out ~97 % of the time; 90 % leaves room
    # for the binomial scatter of ~300 cases (sd ~1 %) and fails if the test were mis-sized.
    constant = [
        model.curves[n].order == 0
        for truth, _, model in campaigns
        for n in model.curves
        if truth.order(n) == 0 and not n.endswith("noise")
    ]
    assert len(constant) > 200
    assert np.mean(constant) >= 0.90, np.mean(constant)


def test_coefficients_and_curve_within_their_uncertainties(campaigns):
    """|coef - truth| <= t_0.975(dof) std for ~95 % of the coefficients (required: >= 88 %).

    With ~500 coefficients the binomial sd of the fraction is ~1 %, so 88 % is far
    below the expectation if the uncertainties are right and fails if they are
    understated by about a quarter. The fitted curve's own std is checked the
    same way at five temperatures.
    """
    inside, curve_inside = [], []
    for truth, _, model in campaigns:
        for name, curve in model.curves.items():
            if curve.order != truth.order(name):
                continue
            dof = curve.n_points - curve.order - 1
            k = stats.t.ppf(0.975, dof)
            z = (curve.coef - truth.polynomial(name)) / np.sqrt(np.diag(curve.cov))
            inside += list(np.abs(z) <= k)
            T = np.linspace(model.t_min, model.t_max, 5)
            err = model.value(name, T) - truth.value(name, T)
            curve_inside += list(np.abs(err) <= k * model.std(name, T))
    assert len(inside) > 400
    assert np.mean(inside) >= 0.88, np.mean(inside)
    assert np.mean(curve_inside) >= 0.88, np.mean(curve_inside)


def test_compensated_bias_error_below_twice_the_noise_floor(campaigns):
    """Noise floor: the solver's standard uncertainty of one calibration's bias.

    Compensated: the fitted curve. Uncompensated: the 20 deg C calibration used at
    every temperature. Both are compared with the true bias over the whole range.
    """
    for truth, points, model in campaigns:
        T = np.linspace(model.t_min, model.t_max, 71)
        room = next(p for p in points if p.temperature == 20.0).calibration
        for name in [params.bias(s, a) for s in ("acc", "gyr") for a in params.AXES]:
            floor = np.median([p.calibration.parameters[name].std for p in points])
            true = truth.value(name, T)
            compensated = np.sqrt(np.mean((model.value(name, T) - true) ** 2))
            uncompensated = np.sqrt(np.mean((room.value(name) - true) ** 2))
            assert compensated < 2.0 * floor, (name, compensated / floor)
            assert uncompensated > 2.0 * floor, (name, uncompensated / floor)


def test_benefit_on_held_out_temperatures(campaigns):
    from calib_core.thermal import benefit

    truth, points, model = campaigns[0]
    gains = {b.name: b for b in benefit(model, campaign_points(points))}
    for name in ("acc.bias.x", "gyr.bias.z", "gyr.scale.y"):
        b = gains[name]
        floor = np.median([p.calibration.parameters[name].std for p in points])
        assert b.rms_before > 10 * floor  # the thermal change is large...
        assert b.rms_after < 2 * floor  # ...and the fit removes it,
        assert b.rms_holdout < 4 * floor  # also at temperatures the fit did not see


def test_hysteresis_of_known_size_is_detected_on_a_soak_sweep():
    rng = np.random.default_rng(7)
    h = 0.02 * np.pi / 180.0  # rad/s: 0.02 deg/s, cooling minus heating on gyro x
    truth = random_thermal_truth(rng, {"gyr.bias": 2}, hysteresis={"gyr.bias.x": h})
    sweep = soak_sweep(truth, rng)
    pts = sweep_points(sweep, axis_vector("z_up", 9.80665))
    model = fit_model({n: p for n, p in pts.items() if n.startswith("gyr")}, t_ref=T_REF)
    hx = model.curves["gyr.bias.x"].hysteresis
    assert hx.detected
    assert abs(hx.value - h) < 4 * hx.std, (hx.value, h, hx.std)
    # No hysteresis on y and z in the truth: the same test must stay quiet there.
    for name in ("gyr.bias.y", "gyr.bias.z"):
        assert not model.curves[name].hysteresis.detected
    assert model.curves["gyr.bias.x"].order == 2


def test_too_narrow_range_gives_a_clear_error():
    pts = {"gyr.bias.x": [ThermalPoint(t, 1e-3 * t, 1e-5) for t in (20.0, 23.0, 28.0)]}
    with pytest.raises(ThermalRangeError, match=r"spans 8\.00 deg C.*at least 10 deg C"):
        fit_model(pts)


def test_campaign_fit_needs_every_parameter_in_every_point(campaigns):
    _, points, _ = campaigns[0]
    broken = [CampaignPoint(p.temperature, p.calibration) for p in points]
    del broken[3].calibration.parameters["gyr.bias.x"]
    with pytest.raises(ValueError, match=r"20.0 deg C\) has no gyr.bias.x"):
        campaign_points(broken, ["gyr.bias.x"])


def test_json_round_trip_and_clipping(campaigns):
    _, _, model = campaigns[1]
    doc = json.loads(json.dumps(model.to_dict()))
    back = ThermalModel.from_dict(doc)
    for T in (-30.0, 0.0, 37.5, 90.0):
        assert back.parameters_at(T) == model.parameters_at(T)
    # Outside the fitted range the compensation is held at the edge value.
    assert model.parameters_at(model.t_max + 20) == model.parameters_at(model.t_max)
    assert model.parameters_at(model.t_min - 20) == model.parameters_at(model.t_min)
    doc["schema_version"] = 99
    with pytest.raises(ValueError, match="schema_version 99"):
        ThermalModel.from_dict(doc)


def test_correct_matches_the_calibration_inverse_at_one_temperature(campaigns):
    """The per-sample inverse equals Calibration.correct with the parameters at that T."""
    _, points, model = campaigns[2]
    base = points[3].calibration
    rng = np.random.default_rng(0)
    acc, gyr = rng.normal(0, 9.8, (5, 3)), rng.normal(0, 1.0, (5, 3))
    moved = model.calibration_at(base, 41.0, base_temperature=20.0)
    want = moved.correct(acc, gyr)
    got = model.correct(acc, gyr, 41.0, base, base_temperature=20.0)
    np.testing.assert_allclose(got[0], want[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-12, atol=1e-12)


def test_directions_from_the_run_sequence():
    assert directions_from_sequence([-10, 0, 20, 40, 20, 0]) == [
        HEATING,
        HEATING,
        HEATING,
        HEATING,
        COOLING,
        COOLING,
    ]
    assert directions_from_sequence([60, 60.2, 40, 20]) == [COOLING] * 4


def test_shift_polynomial_is_exact():
    c = np.array([0.1, -2e-3, 3e-5, -4e-7])
    d = shift_polynomial(c, 25.0, 35.0)
    T = np.linspace(-20, 80, 11)
    np.testing.assert_allclose(
        np.polynomial.polynomial.polyval(T - 35.0, d),
        np.polynomial.polynomial.polyval(T - 25.0, c),
        rtol=1e-12,
        atol=1e-15,
    )
