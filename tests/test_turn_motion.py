"""The integral method's efficient estimator (calib_core.solvers.turn_motion): the turn's
window, the regression of the cross-axis rates, the rests as static data, and its
fallbacks where a hand turn breaks its model."""

from __future__ import annotations

import math

import numpy as np

from calib_core.procedures import solve
from calib_core.recording import Recording
from calib_core.simulate import ROTATION_LABELS, STATIC_LABELS, random_errors
from calib_core.simulate import six_position_integral_run as simulate
from calib_core.solvers.integral import clean_turn, solve_integral
from calib_core.solvers.turn_motion import motion_window
from calib_core.stats import channel_stats
from calib_core.units import DEG, STANDARD_GRAVITY

RANGE = 2000 * DEG
PAUSE_S = 2.0  # the simulator's default pause before and after a turn
RATE_HZ = 50.0  # the simulator's default sample rate
MOTION_S = 4.0 * math.pi / (90 * DEG)  # one turn at 90 deg/s peak (rotation_profile)


def _run(seed: int):
    rng = np.random.default_rng(seed)
    truth = random_errors(rng)
    return truth, simulate(truth, rng)


def _statics(run):
    stats = {k: channel_stats(run.segments[k].gyr) for k in STATIC_LABELS}
    return ({k: s.mean for k, s in stats.items()}, {k: s.sem for k, s in stats.items()}), {
        k: s.std for k, s in stats.items()
    }


def _solve(run, estimator: str):
    (means, sems), stds = _statics(run)
    rotations = {k: run.segments[k] for k in ROTATION_LABELS}
    return solve_integral(rotations, means, sems, RANGE, 1, noise_std=stds, estimator=estimator)


def test_window_holds_the_whole_turn_and_leaves_the_rests_out():
    """The window starts before the motion and ends after it (the sin^2 profile's slow
    ends inside), within the margins: less than 0.5 s of rest each side."""
    _, run = _run(1)
    (means, _), stds = _statics(run)
    for label in ROTATION_LABELS:
        rec = run.segments[label]
        j = "xyz".index(label[0])
        _, _, span, _ = clean_turn(rec, means[f"{label[0]}_up"], j, stds[f"{label[0]}_up"])
        assert PAUSE_S - 0.5 < rec.t[span.start] <= PAUSE_S, label
        assert PAUSE_S + MOTION_S <= rec.t[span.stop - 1] < PAUSE_S + MOTION_S + 0.5, label


def test_an_end_still_creeping_stays_in_the_window():
    """A fixture settling back at 0.05 deg/s over the last 1.5 s (below the motion
    threshold, 0.18 deg/s here) is still turning: the window keeps the record's end."""
    _, run = _run(2)
    (means, _), stds = _statics(run)
    rec = run.segments["z_ccw"]
    gyr = rec.gyr.copy()
    gyr[rec.t > rec.t[-1] - 1.5, 2] += 0.05 * DEG
    rest, sigma = means["z_up"], float(stds["z_up"][2])
    assert motion_window(rec.gyr, rec.t, 2, rest, sigma, sigma).stop < len(rec)
    assert motion_window(gyr, rec.t, 2, rest, sigma, sigma).stop == len(rec)


def test_regression_is_more_precise_and_within_its_uncertainty():
    """On a rigid turn the default estimator's stated uncertainties are smaller than the
    literal reading's (scale: the rests' 4 s of 12 s leave the integral; misalignment:
    the regression, about 2.3 times less variance), and both are within 4 of their
    standard uncertainties of the truth."""
    truth, run = _run(3)
    fast, literal = _solve(run, "regression"), _solve(run, "whole_record")
    err_f = fast.matrix("gyr") - truth.gyr_M
    err_l = literal.matrix("gyr") - truth.gyr_M
    std_f = np.array([[fast.parameters[n].std for n in row] for row in _names()])
    std_l = np.array([[literal.parameters[n].std for n in row] for row in _names()])
    assert np.all(np.abs(err_f) < 4 * std_f) and np.all(np.abs(err_l) < 4 * std_l)
    assert np.all(np.diag(std_f) < np.diag(std_l) * math.sqrt(0.8))
    off = ~np.eye(3, dtype=bool)
    assert np.all(std_f[off] < std_l[off] / math.sqrt(1.8))
    assert set(fast.info["misalignment_by"].values()) == {"regression"}


def test_a_wobbling_turn_keeps_the_integral():
    """A turn whose axis wobbles (a cross-axis rate that follows the on-axis rate's
    change, closing over the turn, 20 times the noise) breaks the regression's model:
    that entry is read from the integral over the turn, the others by regression."""
    truth, run = _run(4)
    rec = run.segments["x_ccw"]
    gyr = rec.gyr.copy()
    accel = np.gradient(rec.gyr[:, 0] - rec.gyr[:5, 0].mean(), rec.t)
    gyr[:, 1] += 20 * float(truth.gyr_noise[1]) * accel / np.abs(accel).max()
    run.segments["x_ccw"] = Recording(rec.t, rec.acc, gyr, rec.temp, label="x_ccw")
    cal = _solve(run, "regression")
    by = cal.info["misalignment_by"]
    assert by["gyr.misalign.yx"] == "integral" and by["gyr.misalign.zx"] == "regression"
    err = cal.value("gyr.misalign.yx") - truth.gyr_M[1, 0]
    assert abs(err) < 4 * cal.parameters["gyr.misalign.yx"].std


def test_the_rests_join_their_faces_statics():
    """six_position_integral: each "A up" face's gyro statistics take the rests of the
    turns about A (2 s before and after each of two turns, less the margins); the down
    faces keep their own; the literal reading uses the faces alone."""
    _, run = _run(5)
    cal = solve("six_position_integral", run.segments, STANDARD_GRAVITY, {})
    counts = cal.info["gyro_static_samples"]
    for a in "xyz":
        rests = counts[f"{a}_up"] - len(run.segments[f"{a}_up"])
        assert 4 * (PAUSE_S - 0.5) * RATE_HZ < rests <= 4 * PAUSE_S * RATE_HZ
        assert counts[f"{a}_dn"] == len(run.segments[f"{a}_dn"])
    literal = solve(
        "six_position_integral", run.segments, STANDARD_GRAVITY, {"turn_estimator": "whole_record"}
    )
    assert "gyro_static_samples" not in literal.info
    assert literal.info["turn_estimator"] == "whole_record"


def _names():
    from calib_core import params

    return params.matrix_names("gyr")
