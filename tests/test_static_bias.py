"""Static bias and noise against simulated truth."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from calib_core.earth import EARTH_RATE
from calib_core.noise import FLICKER_FACTOR
from calib_core.simulate.noise import NoiseSpec, level_frame_earth_rate, simulate_static
from calib_core.solvers.static_bias import earth_rate_level_frame, solve_static_bias
from calib_core.units import DEG

RATE = 20.0  # Hz: keeps 1 h records small; the procedure asks >= 100 Hz, not the science
HOUR = 3600.0
TRUE_BIAS = np.array([0.02, -0.01, 0.005])  # rad/s

# MEMS-like mix with white/flicker crossover at 5 s and flicker/random-walk at 60 s.
# The random walk dominates the record mean (K^2 T/3 is 10x the white part at 1 h),
# and 1 h holds 60 crossover times, enough to fit K to ~20 % from one record
# (measured: u scatters by 20 % over 30 seeds; with the crossover at 300 s it
# scatters by 50 % and single records then miss by > 4 u).
_B = 2e-4
MEMS = NoiseSpec(
    arw=math.sqrt((FLICKER_FACTOR * _B) ** 2 * 5.0),
    bias_instability=_B,
    rrw=math.sqrt(3 * (FLICKER_FACTOR * _B) ** 2 / 60.0),
)


def test_bias_within_4u_and_uncertainty_matches_scatter():
    """16 seeds of a 1 h record with white + flicker + random-walk noise.

    The record mean scatters about the starting bias by the Allan deviation at
    tau = T (that is what the reported u models). 16 seeds x 3 channels estimate
    the scatter to ~ +-10 %, so the factor-2 acceptance is well outside sampling error.
    """
    errors, u = [], []
    for seed in range(16):
        rec = simulate_static(
            HOUR, RATE, gyro_bias=TRUE_BIAS, gyro_noise=MEMS, rng=np.random.default_rng(seed)
        )
        cal = solve_static_bias(rec)
        est = cal.vector("gyr", "bias")
        std = np.array([cal.parameters[f"gyr.bias.{a}"].std for a in "xyz"])
        assert np.all(np.abs(est - TRUE_BIAS) <= 4 * std), (seed, est - TRUE_BIAS, std)
        errors.append(est - TRUE_BIAS)
        u.append(std)
    scatter = np.sqrt(np.mean(np.square(errors)))
    ratio = np.mean(u) / scatter
    assert 0.5 < ratio < 2.0, ratio
    # the white-noise sem alone would be far too small here
    white_sem = MEMS.arw / math.sqrt(HOUR)
    assert scatter > 3 * white_sem


def test_noise_std_and_parameters_white():
    """White noise only: std = arw sqrt(f_s), shrunk by the one-pass 3-sigma clip.

    A Gaussian truncated at +-3 sigma has std 0.98664 sigma; the sample std of
    n = 72000 samples scatters by sigma / sqrt(2 n) = 0.26 %, test at 4x that.
    """
    arw = 1e-3
    rec = simulate_static(
        HOUR, RATE, gyro_bias=TRUE_BIAS, gyro_noise=NoiseSpec(arw=arw), rng=np.random.default_rng(5)
    )
    cal = solve_static_bias(rec)
    sigma = arw * math.sqrt(RATE)
    n = len(rec)
    for a in "xyz":
        assert cal.value(f"gyr.noise.{a}") == pytest.approx(
            0.98664 * sigma, rel=4 / math.sqrt(2 * n)
        )
        # white noise: u(bias) is the classical sem (the white term, a ~ N^2, known to
        # well under 1 % from the short taus; the clip shrinks it by 1.3 %)
        assert cal.parameters[f"gyr.bias.{a}"].std > 0.95 * sigma / math.sqrt(n)
    # Over seeds: a flicker or random-walk term the curve does not support (fitted from the
    # noisy long-tau points, then extrapolated to tau = T) stays out of u, which then is
    # the white sem (median within 5 %); a spurious term kept at 3 of its standard errors
    # is rare (at most 2 of the 24). Before the terms were tested, u averaged 1.5 to 1.8
    # times the sem on white noise (the benchmark's static_bias case: coverage 0.975).
    ratios = []
    for seed in range(20, 28):
        other = simulate_static(
            HOUR,
            RATE,
            gyro_bias=TRUE_BIAS,
            gyro_noise=NoiseSpec(arw=arw),
            rng=np.random.default_rng(seed),
        )
        c = solve_static_bias(other)
        ratios += [c.parameters[f"gyr.bias.{a}"].std / (sigma / math.sqrt(n)) for a in "xyz"]
    assert 0.95 < np.median(ratios) < 1.05, ratios
    assert sum(r > 1.3 for r in ratios) <= 2, ratios
    arw_fit = [p["arw"] for p in cal.info["noise_parameters"]["gyr"]]
    np.testing.assert_allclose(arw_fit, arw, rtol=0.02)  # edf at tau = 1 sample ~ 1e5
    assert not cal.warnings
    json.dumps(cal.to_dict())  # info is JSON-able


@pytest.mark.parametrize("heading", [0.0, 37.0, 200.0])
def test_earth_rate_removed_for_fog_grade(heading):
    """FOG-grade: ARW 0.001 deg/sqrt(h) -> sem over 1 h ~ 5e-9 rad/s << Earth rate 7e-5 rad/s."""
    arw = 0.001 * DEG / 60.0
    lat = 48.1
    rec = simulate_static(
        HOUR,
        RATE,
        gyro_bias=np.array([1e-6, -2e-6, 3e-6]),
        gyro_noise=NoiseSpec(arw=arw),
        latitude_deg=lat,
        heading_deg=heading,
        rng=np.random.default_rng(7),
    )
    truth = np.array([1e-6, -2e-6, 3e-6])
    cal = solve_static_bias(rec, latitude_deg=lat, heading_deg=heading, remove_earth_rate=True)
    u = np.array([cal.parameters[f"gyr.bias.{a}"].std for a in "xyz"])
    assert np.all(np.abs(cal.vector("gyr", "bias") - truth) <= 4 * u)
    raw = solve_static_bias(rec)
    projection = raw.vector("gyr", "bias") - truth
    np.testing.assert_allclose(projection, earth_rate_level_frame(lat, heading), atol=4 * u.max())


def test_earth_rate_projection_closed_forms():
    # solver's closed form against the simulator's rotation-matrix construction
    for lat in (-60.0, 0.0, 45.0, 89.0):
        for hdg in (0.0, 90.0, 123.0, 270.0):
            np.testing.assert_allclose(
                earth_rate_level_frame(lat, hdg), level_frame_earth_rate(lat, hdg), atol=1e-18
            )
    np.testing.assert_allclose(earth_rate_level_frame(90.0, 0.0), [0, 0, EARTH_RATE], atol=1e-18)
    # at the equator facing East, North (the whole Earth rate) is along -y
    np.testing.assert_allclose(earth_rate_level_frame(0.0, 90.0), [0, EARTH_RATE, 0], atol=1e-18)


def test_outliers_rejected_and_acc_bias_with_orientation():
    arw = 1e-3
    sigma = arw * math.sqrt(RATE)
    acc_bias = np.array([0.05, -0.03, 0.02])
    rec = simulate_static(
        HOUR,
        RATE,
        gyro_bias=TRUE_BIAS,
        gyro_noise=NoiseSpec(arw=arw),
        acc_bias=acc_bias,
        acc_noise=NoiseSpec(arw=1e-3),
        up_axis="-y",
        outliers=50,
        outlier_size=50 * sigma,
        rng=np.random.default_rng(9),
    )
    cal = solve_static_bias(rec, up_axis="-y")
    n = len(rec)
    # 50 spikes + the Gaussian tail beyond 3 sigma (0.27 % of n, binomial +- 4 std)
    tail = 0.0027 * n
    for count in cal.info["outliers"]["gyr"]:
        assert 50 <= count <= 50 + tail + 4 * math.sqrt(tail)
    for a in "xyz":
        p = cal.parameters[f"gyr.bias.{a}"]
        assert abs(p.value - TRUE_BIAS["xyz".index(a)]) <= 4 * p.std
        q = cal.parameters[f"acc.bias.{a}"]
        assert abs(q.value - acc_bias["xyz".index(a)]) <= 4 * q.std
    no_orientation = solve_static_bias(rec.window(0, 600))
    assert "acc.bias.x" not in no_orientation.parameters
    assert "acc.noise.x" in no_orientation.parameters
    assert any("60 min" in w for w in no_orientation.warnings)


def test_bad_input():
    rec = simulate_static(
        60.0,
        RATE,
        gyro_bias=TRUE_BIAS,
        gyro_noise=NoiseSpec(arw=1e-3),
        rng=np.random.default_rng(1),
    )
    with pytest.raises(ValueError, match="latitude_deg"):
        solve_static_bias(rec, remove_earth_rate=True)
    with pytest.raises(ValueError, match="z-up"):
        solve_static_bias(rec, remove_earth_rate=True, latitude_deg=45, heading_deg=0, up_axis="+x")
    with pytest.raises(ValueError, match="up_axis"):
        solve_static_bias(rec, up_axis="z")
