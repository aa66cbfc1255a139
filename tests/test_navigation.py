"""Navigation performance, the science (calib_core.navigation, docs/navigation.md): the
covariance against the closed forms of Titterton & Weston (2004, ch. 12) and against a
Monte Carlo run of the same profile (calib_core.simulate.nav_errors).

Tolerances. Closed forms: the issue's 2 %. The covariance itself is deterministic; what
separates it from a closed form is the coupling the closed form leaves out (Earth rate,
Schuler feedback, the vertical channel), each bounded in the test's comment and far below
2 %; a wrong sign or factor in F moves a figure by tens of percent or more. Monte Carlo:
the standard deviation of n normal draws scatters about the true one with a relative
standard deviation 1 / sqrt(2 (n - 1)) (2.24 % for n = 1000); the issue's 10 % is 4.5 of
those, so with 18 comparisons a false failure has a chance below 1e-4, while a
discretisation or Kalman-update error of more than 10 % fails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from calib_core.mission import Aiding, MissionProfile, Trajectory
from calib_core.navigation import error_model, performance, propagate, radius_95
from calib_core.simulate.nav_errors import monte_carlo
from pipelines.navigation import load_profile

MC_RUNS = 1000
MC_TOL = 0.10
# The fast tier's Monte Carlo: the sample std of N runs has a relative standard error of
# 1 / sqrt(2 (N - 1)), 3.5 % at 400; the test's bound is 4 of those or MC_TOL, the larger.
FAST_RUNS = 400


def mc_tol(runs: int) -> float:
    """The bound on |sample std / propagated std - 1| for `runs` Monte Carlo runs."""
    return max(MC_TOL, 4 / math.sqrt(2 * (runs - 1)))


CLOSED_TOL = 0.02


def static(duration: float, latitude_deg: float = 0.0, step: float = 1.0) -> MissionProfile:
    """At rest, level, heading North, no fixes, no initial error."""
    traj = Trajectory(np.array([0.0, duration]), np.zeros((2, 3)), np.zeros((2, 3)))
    return MissionProfile("rest", duration, traj, latitude=math.radians(latitude_deg), step=step)


def schuler(profile: MissionProfile) -> tuple[float, float, float]:
    """(omega_s, R, g) of the model at the profile's start."""
    from calib_core.earth import gravity_wgs84, radii_of_curvature

    rn, re = radii_of_curvature(profile.latitude)
    r = math.sqrt(rn * re) + profile.height
    g = gravity_wgs84(math.degrees(profile.latitude), profile.height)
    return math.sqrt(g / r), r, g


def at(prop, t: float) -> int:
    i = int(np.argmin(abs(prop.t - t)))
    assert abs(prop.t[i] - t) < 1e-6, (t, prop.t[i])
    return i


def test_gyro_white_noise_gives_arw_sqrt_t():
    # Heading: the Earth rate couples the tilt errors' own random walk into heading,
    # +0.7 % at 600 s (45 deg N). Tilt at 60 s: the Schuler feedback, -0.09 %.
    n = 2.0e-4  # rad/sqrt(s)
    model = error_model({}, {"gyr": [{"arw": n}] * 3})
    prop = propagate(static(600.0, 45.0), model, records=10_000)
    sig = prop.sigma()
    for t in (60.0, 600.0):
        assert sig[at(prop, t), 2] == pytest.approx(n * math.sqrt(t), rel=CLOSED_TOL)
    assert sig[at(prop, 60.0), 0] == pytest.approx(n * math.sqrt(60.0), rel=CLOSED_TOL)
    assert sig[at(prop, 60.0), 1] == pytest.approx(n * math.sqrt(60.0), rel=CLOSED_TOL)


def test_accelerometer_bias_gives_t2_then_the_schuler_oscillation():
    # North accelerometer bias at the equator (no Foucault turn of the oscillation; the
    # Earth rate along North leaves the North channel alone): T&W eq. 12.33,
    # dr_N = b (1 - cos(omega_s t)) / omega_s^2, which is b t^2 / 2 for t << 84.4 min.
    b = 1.0e-3  # m/s^2
    prof = static(5400.0, 0.0, step=2.0)
    prop = propagate(prof, error_model({"acc.bias.x": b}), records=10_000)
    ws, _, _ = schuler(prof)
    period = 2 * math.pi / ws
    assert period / 60 == pytest.approx(84.4, abs=0.05)
    sig = prop.sigma()[:, 6]
    for t in (10.0, 60.0):  # short: b t^2 / 2 to better than (omega_s t)^2 / 12 = 0.05 %
        assert sig[at(prop, t)] == pytest.approx(b * t * t / 2, rel=CLOSED_TOL)
    for t in (1266.0, 2532.0, 3798.0):  # a quarter, a half, three quarters of a period
        expected = b * (1 - math.cos(ws * t)) / ws**2
        assert sig[at(prop, t)] == pytest.approx(expected, rel=CLOSED_TOL)
    # bounded: its largest value, at half a period, is 2 b / omega_s^2 ...
    peak = int(np.argmax(sig))
    assert sig[peak] == pytest.approx(2 * b / ws**2, rel=CLOSED_TOL)
    assert prop.t[peak] == pytest.approx(period / 2, rel=CLOSED_TOL)
    # ... and a full period brings it back (near zero, where a relative test means nothing)
    assert sig[int(np.argmin(abs(prop.t - period)))] < 0.02 * sig[peak]


def test_gyro_bias_gives_heading_and_position_growth():
    # Vertical gyro bias: heading error b t (T&W eq. 12.36; the Earth-rate coupling over
    # 600 s at 45 deg: -0.02 %).
    b = 1.0e-5  # rad/s
    prop = propagate(static(600.0, 45.0), error_model({"gyr.bias.z": b}))
    assert prop.sigma()[-1, 2] == pytest.approx(b * 600.0, rel=CLOSED_TOL)
    # North gyro bias at the equator: the tilt is Schuler-bounded, b sin(omega_s t) / omega_s,
    # and the East position error R b (t - sin(omega_s t) / omega_s) (T&W eq. 12.35), which
    # is g b t^3 / 6 short-term. At half a period the free vertical channel (time constant
    # sqrt(R / 2 g) = 570 s, coupled through the Coriolis term) has added 1.2 %.
    prof = static(2600.0, 0.0, step=2.0)
    prop = propagate(prof, error_model({"gyr.bias.x": b}), records=10_000)
    ws, r, g = schuler(prof)
    sig = prop.sigma()
    assert sig[at(prop, 60.0), 7] == pytest.approx(g * b * 60.0**3 / 6, rel=CLOSED_TOL)
    for t in (600.0, 1266.0, 2532.0):
        expected = r * b * (t - math.sin(ws * t) / ws)
        assert sig[at(prop, t), 7] == pytest.approx(expected, rel=CLOSED_TOL)
    quarter = at(prop, 1266.0)
    assert sig[quarter, 0] == pytest.approx(b * abs(math.sin(ws * 1266.0)) / ws, rel=CLOSED_TOL)


def test_radius_95_of_a_line_and_a_circle():
    # 1.95996 sigma for a line (normal quantile), sqrt(-2 ln 0.05) = 2.44775 sigma for a
    # circle (Rayleigh): the quadrature's own error is far below the printed digits.
    cov = np.array([[[4.0, 0.0], [0.0, 0.0]], [[4.0, 0.0], [0.0, 4.0]]])
    r = radius_95(cov)
    assert r[0] == pytest.approx(1.959964 * 2.0, rel=1e-4)
    assert r[1] == pytest.approx(math.sqrt(-2 * math.log(0.05)) * 2.0, rel=1e-4)


# A MEMS-grade unit with every kind of source: constants in each family (with a correlated
# pair), white noise, bias instability, rate random walk.
UNIT = {
    "gyr.bias.x": 2e-4, "gyr.bias.y": 2e-4, "gyr.bias.z": 3e-4,
    "acc.bias.x": 5e-3, "acc.bias.y": 5e-3, "acc.bias.z": 8e-3,
    "gyr.scale.x": 2e-3, "gyr.scale.y": 2e-3, "gyr.scale.z": 3e-3,
    "gyr.misalign.xy": 1e-3, "gyr.misalign.zx": 1e-3,
    "acc.scale.x": 1e-3, "acc.misalign.xz": 1e-3, "acc.misalign.yz": 1e-3,
    "gyr.gsens.xz": 1e-4, "gyr.gsens.yz": 1e-4,
}  # fmt: skip
NOISE = {
    s: [{"arw": n, "bias_instability": bi, "rrw": k, "bias_instability_tau": tau}] * 3
    for s, n, bi, k, tau in (("gyr", 3e-4, 3e-5, 2e-6, 200.0), ("acc", 2e-3, 2e-4, 4e-5, 100.0))
}


# The fast tier: the outage profile on FAST_RUNS; `make test` also both profiles on MC_RUNS.
@pytest.mark.parametrize(
    ("name", "runs"),
    [
        ("land-vehicle-outage-60s", FAST_RUNS),
        pytest.param("land-vehicle-outage-60s", MC_RUNS, marks=pytest.mark.slow),
        pytest.param("static-alignment", MC_RUNS, marks=pytest.mark.slow),
    ],
)
def test_covariance_matches_monte_carlo(name, runs):
    profile = load_profile(name)
    model = error_model(
        UNIT, NOISE, covariance={("gyr.bias.x", "gyr.bias.y"): 0.5 * 2e-4**2,
                                 ("gyr.bias.y", "gyr.bias.x"): 0.5 * 2e-4**2}
    )  # fmt: skip
    prop = propagate(profile, model)
    y = monte_carlo(profile, model, prop, runs, np.random.default_rng(50), substeps=2)
    ratio = y.std(axis=0, ddof=1) / prop.sigma()[-1]
    assert np.all(abs(ratio - 1) < mc_tol(runs)), ratio
    # the budget's shares add up to the total (the sources' covariances sum to it)
    perf = performance(prop, profile.position_limit)
    for group in perf["shares"].values():
        assert sum(group.values()) == pytest.approx(1.0, abs=1e-6 * len(group))


def test_fixes_bound_the_errors_and_the_outage_lets_them_grow():
    prof = load_profile("land-vehicle-outage-60s")
    prop = propagate(prof, error_model(UNIT, NOISE))
    perf = performance(prop, 10.0, free_from=300.0)
    hp = perf["horizontal_position_95"]
    aided = (prop.t > 60) & (prop.t <= 300)
    # while fixed, the 95 % radius stays within a few fix sigmas (2 m); free, it grows
    assert hp[aided].max() < 3 * 2.448 * 2.0
    assert hp[-1] > 3 * hp[at(prop, 300.0)]
    t = perf["time_to_limit"]
    assert t is not None and 0 < t < 60
    assert np.interp(300.0 + t, prop.t, hp) == pytest.approx(10.0, rel=0.05)


def test_profile_values_are_checked():
    traj = Trajectory(np.array([0.0, 10.0]), np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="duration"):
        MissionProfile("x", 20.0, traj)
    with pytest.raises(ValueError, match="aiding kind"):
        Aiding("gnss")
    with pytest.raises(ValueError, match="increasing"):
        Trajectory(np.array([0.0, 0.0]), np.zeros((2, 3)), np.zeros((2, 3)))


def test_motion_terms_against_their_closed_forms():
    """The terms only motion excites: a heading error under along-track acceleration gives
    a cross-track velocity error a psi t (the f^n x psi term), and a z-gyro scale error over
    a turn a heading error k x the angle turned (T&W sec. 12.5). Over 20 s the Schuler and
    Earth-rate couplings change them by (omega_s t)^2 / 6 = 0.1 % and less."""
    from calib_core.mission import Segment, trajectory_from_segments

    a, t = 2.0, 20.0
    traj = trajectory_from_segments([Segment(t, forward_accel=a)], step=0.05)
    init = np.zeros(9)
    init[2] = math.radians(1.0)  # heading, rad
    prof = MissionProfile("accelerate", t, traj, initial_std=init, step=0.1)
    sig = propagate(prof, error_model({})).sigma()[-1]
    assert sig[4] == pytest.approx(a * init[2] * t, rel=CLOSED_TOL)  # East velocity
    assert sig[3] < 1e-2 * sig[4]  # along track only through Coriolis: 2 Omega sin(L) t = 0.2 %
    k = 1.0e-3
    turn = trajectory_from_segments(
        [Segment(5.0, forward_accel=2.0), Segment(10.0, yaw_rate=math.radians(9.0))], step=0.05
    )
    prof = MissionProfile("turn", 15.0, turn, step=0.1)
    sig = propagate(prof, error_model({"gyr.scale.z": k})).sigma()[-1]
    assert sig[2] == pytest.approx(k * math.radians(90.0), rel=CLOSED_TOL)


# A tactical-grade unit: errors small enough for first-order theory (tilt well under 1 deg).
TACTICAL = {
    "gyr.bias.x": 2e-5, "gyr.bias.y": 2e-5, "gyr.bias.z": 3e-5,
    "acc.bias.x": 5e-4, "acc.bias.y": 5e-4, "acc.bias.z": 8e-4,
    "gyr.scale.z": 3e-4, "acc.scale.x": 2e-4, "gyr.misalign.xy": 1e-4, "gyr.gsens.xz": 1e-5,
}  # fmt: skip
STRAPDOWN_RUNS = 800  # sample std known to 2.5 %: 10 % is 4 of those


@pytest.mark.parametrize("runs", [FAST_RUNS, pytest.param(STRAPDOWN_RUNS, marks=pytest.mark.slow)])
def test_covariance_matches_a_full_strapdown_mechanisation(runs):
    """The psi-angle model against a nonlinear mechanisation (calib_core.simulate.strapdown)
    on 120 s of the outage profile's drive (turns, speed changes), unaided: the independent
    check of the error equations' signs and couplings under motion."""
    import dataclasses

    from calib_core.simulate.strapdown import strapdown_errors

    base = load_profile("land-vehicle-outage-60s")
    prof = dataclasses.replace(
        base, duration=120.0, aiding=Aiding(), initial_std=0.1 * base.initial_std
    )
    white = {"gyr": 3e-5, "acc": 2e-4}
    model = error_model(TACTICAL, {s: [{"arw": n}] * 3 for s, n in white.items()})
    sigma = propagate(prof, model).sigma()[-1]
    y = strapdown_errors(prof, TACTICAL, white, runs, np.random.default_rng(4))
    ratio = y.std(axis=0, ddof=1) / sigma
    assert np.all(abs(ratio - 1) < mc_tol(runs)), ratio
