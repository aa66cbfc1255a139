"""Six-position closed form, multi-position least squares, and the uncertainty of a mean."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib_core.simulate import STATIC_LABELS, axis_vector, random_errors
from calib_core.solvers.multi_position import solve_accel_linear, solve_gyro_static
from calib_core.solvers.six_position import accel_closed_form, accel_closed_form_std
from calib_core.stats import (
    channel_stats,
    effective_sample_size,
    integrated_autocorrelation_time,
    largest_std,
)

G = 9.80665


def six_f(g: float = G) -> np.ndarray:
    return np.array([axis_vector(label, g) for label in STATIC_LABELS])


def ideal_means(truth, f: np.ndarray) -> np.ndarray:
    return truth.acc_measured(f)


@pytest.mark.parametrize("seed", range(5))
def test_closed_form_equals_least_squares_on_ideal_data(seed):
    truth = random_errors(np.random.default_rng(seed))
    f = six_f()
    means = ideal_means(truth, f)
    closed = accel_closed_form(dict(zip(STATIC_LABELS, means, strict=True)), G)
    fit = solve_accel_linear(f, means, np.full((6, 3), 1e-3))
    assert set(closed) == set(fit.params)
    for name, value in closed.items():
        assert abs(value - fit.params[name]) < 1e-9, name
        assert abs(value - truth.parameters()[name]) < 1e-9, name
    assert fit.condition_number == pytest.approx(math.sqrt(3))
    np.testing.assert_allclose(fit.residual_means, 0.0, atol=1e-12)


def test_closed_form_maps_the_paper_convention():
    """Build the means from the paper's signed-angle model, independently of the matrix form."""
    rng = np.random.default_rng(11)
    Axx, Ayy, Azz, Axz, Axy, Ayz, Ayx, Azy, Azx = rng.uniform(-0.02, 0.02, 9)
    a0 = rng.uniform(-0.3, 0.3, 3)

    def paper(ax, ay, az):
        return np.array(
            [
                (1 + Axx) * ax + Axz * ay - Axy * az + a0[0],
                -Ayz * ax + (1 + Ayy) * ay + Ayx * az + a0[1],
                Azy * ax - Azx * ay + (1 + Azz) * az + a0[2],
            ]
        )

    means = {label: paper(*axis_vector(label, G)) for label in STATIC_LABELS}
    out = accel_closed_form(means, G)
    expected = {
        "acc.scale.x": Axx,
        "acc.scale.y": Ayy,
        "acc.scale.z": Azz,
        "acc.misalign.xy": Axz,
        "acc.misalign.xz": -Axy,
        "acc.misalign.yx": -Ayz,
        "acc.misalign.yz": Ayx,
        "acc.misalign.zx": Azy,
        "acc.misalign.zy": -Azx,
        "acc.bias.x": a0[0],
        "acc.bias.y": a0[1],
        "acc.bias.z": a0[2],
    }
    for name, value in expected.items():
        assert out[name] == pytest.approx(value, abs=1e-12), name


def test_closed_form_missing_position_is_named():
    means = {label: np.zeros(3) for label in STATIC_LABELS if label != "y_dn"}
    with pytest.raises(ValueError, match="y_dn"):
        accel_closed_form(means, G)


def test_closed_form_std_equals_least_squares_std_with_equal_weights():
    rng = np.random.default_rng(3)
    sem = rng.uniform(1e-4, 1e-3, 3)
    sems = np.broadcast_to(sem, (6, 3))
    truth = random_errors(rng)
    fit = solve_accel_linear(six_f(), ideal_means(truth, six_f()), sems)
    std = accel_closed_form_std(dict(zip(STATIC_LABELS, sems, strict=True)), G)
    for name, u in std.items():
        assert u == pytest.approx(fit.std[name], rel=1e-10), name


def test_least_squares_on_many_attitudes():
    """24 random attitudes (as read from a two-axis table): exact on ideal data, and the
    reported covariance matches the scatter of the estimates over noise draws."""
    rng = np.random.default_rng(7)
    truth = random_errors(rng)
    f = Rotation.random(24, random_state=8).apply(np.array([0.0, 0.0, G]))
    fit = solve_accel_linear(f, ideal_means(truth, f), np.full((24, 3), 1e-3))
    for name, value in fit.params.items():
        assert abs(value - truth.parameters()[name]) < 1e-10, name
    assert fit.condition_number < 10
    sem = 2e-3
    draws = np.array(
        [
            [
                solve_accel_linear(
                    f, ideal_means(truth, f) + rng.normal(0, sem, (24, 3)), np.full((24, 3), sem)
                ).params[n]
                for n in fit.names
            ]
            for _ in range(400)
        ]
    )
    # std of a std estimate from 400 draws is 1/sqrt(800) = 3.5 %: allow 4 of them.
    np.testing.assert_allclose(
        draws.std(axis=0), np.sqrt(np.diag(fit.cov)) * (sem / 1e-3), rtol=0.15
    )


def test_ill_conditioned_positions_are_refused():
    f = np.array([axis_vector(label, G) for label in ("z_up", "z_dn", "z_up", "z_dn")])
    with pytest.raises(ValueError, match="condition number"):
        solve_accel_linear(f, f, np.full((4, 3), 1e-3))
    with pytest.raises(ValueError, match="at least 4"):
        solve_accel_linear(f[:3], f[:3], np.full((3, 3), 1e-3))


def test_gyro_bias_and_g_sensitivity_formula():
    truth = random_errors(np.random.default_rng(9))
    f = six_f()
    w = f @ truth.gsens.T + truth.gyr_bias
    fit = solve_gyro_static(f, w, np.full((6, 3), 1e-4))
    W = dict(zip(STATIC_LABELS, w, strict=True))
    for i, a in enumerate("xyz"):
        assert fit.params[f"gyr.bias.{a}"] == pytest.approx(w[:, i].mean(), abs=1e-15)
        for j, c in enumerate("xyz"):
            formula = (W[f"{c}_up"][i] - W[f"{c}_dn"][i]) / (2 * G)
            assert fit.params[f"gyr.gsens.{a}{c}"] == pytest.approx(formula, abs=1e-15)
            assert fit.params[f"gyr.gsens.{a}{c}"] == pytest.approx(truth.gsens[i, j], abs=1e-15)


def test_effective_sample_size_white_and_correlated():
    rng = np.random.default_rng(12)
    white = rng.standard_normal((4000, 3))
    np.testing.assert_array_equal(effective_sample_size(white), 4000)
    # AR(1) with rho = 0.8: N_eff = N (1 - rho) / (1 + rho) = N / 9.
    rho, n = 0.8, 40000
    e = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = e[0]
    for k in range(1, n):
        x[k] = rho * x[k - 1] + e[k]
    # tau's estimator has relative std ~ sqrt(2 (2M + 1) / N) ~ 5 % at window M ~ 45: 4 of them.
    assert effective_sample_size(x) == pytest.approx(n / 9, rel=0.2)


def test_autocorrelation_time_is_the_windowed_lag_sum():
    """tau by FFT (zero-padded to a 5-smooth length) equals the direct sum over lags, and a
    series with lag-1 autocorrelation within 3/sqrt(N) of zero is white (tau = 1 exactly)."""
    rng = np.random.default_rng(21)
    for n, rho in ((3001, 0.6), (4096, 0.95), (777, -0.5)):
        e = rng.standard_normal(n)
        x = np.empty(n)
        x[0] = e[0]
        for k in range(1, n):
            x[k] = rho * x[k - 1] + e[k]
        d = x - x.mean()
        acf = np.array([d[: n - k] @ d[k:] for k in range(n)]) / (d @ d)
        taus = 1.0 + 2.0 * np.cumsum(acf[1:])
        window = np.nonzero(np.arange(1, n) >= 5.0 * taus)[0]
        expected = max(taus[window[0]] if window.size else taus[-1], 1.0)
        assert integrated_autocorrelation_time(x) == pytest.approx(expected, rel=1e-12)
    assert integrated_autocorrelation_time(rng.standard_normal(5000)) == 1.0


def test_sem_is_honest_for_filtered_data():
    """Moving-average filtered noise: the reported sem must match the scatter of the mean."""
    means, sems = [], []
    for seed in range(100):
        raw = np.random.default_rng(100 + seed).standard_normal((2009, 3))
        filtered = np.cumsum(raw, axis=0)
        filtered = (filtered[10:] - filtered[:-10]) / 10  # 10-sample moving average
        s = channel_stats(filtered)
        means.append(s.mean)
        sems.append(s.sem)
    ratio = np.std(means, axis=0) / np.mean(sems, axis=0)
    # The scatter of 100 means is known to ~7 % (1/sqrt(200)); 3 of those either side.
    # Treating the samples as independent would give ratio ~ sqrt(10) = 3.2.
    assert np.all((ratio > 0.78) & (ratio < 1.25)), ratio


def test_largest_std_uncertainty_covers_the_upward_bias():
    sigma, n, errs, us = 2.0, 500, [], []
    for seed in range(300):
        x = np.random.default_rng(seed).normal(0, sigma, (6, n, 3))
        value, u = largest_std(x.std(axis=1, ddof=1), np.full((6, 3), n))
        errs.append(value - sigma)
        us.append(u)
    rms = np.sqrt(np.mean(np.square(errs), axis=0))
    # The rms over 300 draws is known to ~4 %; the max of 6 is biased by ~1.27 single stds.
    np.testing.assert_allclose(rms / np.mean(us, axis=0), 1.0, rtol=0.15)
    assert np.all(np.mean(errs, axis=0) > 0)
