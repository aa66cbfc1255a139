"""Stillness where the profile states no noise: the scatter of each static segment against
the noise measured on the run's quietest static segment (calib_core.stillness)."""

from __future__ import annotations

import numpy as np

from calib_core.recording import Recording
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.stillness import (
    STILL_SCATTER,
    StatedLimits,
    measured_noise,
    robust_scatter,
    stillness_problems,
)

G = 9.80665
NO_NOISE = StatedLimits(None, None, None, None, None)  # a profile stating no limit at all


def _statics(seed: int) -> dict[str, Recording]:
    rng = np.random.default_rng(seed)
    sim = six_position_integral_run(random_errors(rng), rng, static_s=10.0)
    return {k: r for k, r in sim.segments.items() if k.endswith(("_up", "_dn"))}


def test_a_still_run_passes_and_a_moving_segment_is_named() -> None:
    statics = _statics(46)
    assert len(statics) == 6
    measured = measured_noise(list(statics.values()))
    for label, rec in statics.items():
        assert stillness_problems(rec, G, NO_NOISE, measured) == [], label
    # the unit rocked on the table in one position: a 0.5 Hz swing of the x axis whose
    # rate amplitude is 2 x STILL_SCATTER x the gyro noise (rate std amplitude / sqrt(2))
    rec = statics["y_up"]
    noise = measured["gyr"][0]
    swing = 2 * STILL_SCATTER * noise * np.sqrt(2) * np.sin(2 * np.pi * 0.5 * rec.t)
    gyr = rec.gyr.copy()
    gyr[:, 0] += swing
    moving = Recording(t=rec.t, acc=rec.acc, gyr=gyr, temp=rec.temp)
    segments = [*(r for k, r in statics.items() if k != "y_up"), moving]
    measured = measured_noise(segments)
    (problem,) = stillness_problems(moving, G, NO_NOISE, measured)
    assert problem.startswith("gyr x scatters") and "quietest static segment" in problem
    ratio = robust_scatter(moving.gyr)[0] / measured["gyr"][0]
    assert ratio > STILL_SCATTER, ratio


def test_one_segment_is_no_reference_for_itself() -> None:
    """A run of one static segment (a static-bias run) measures no noise to judge against:
    its own successive differences would not do (a low-pass filtered still unit scatters
    several times its sample-to-sample noise)."""
    rec = next(iter(_statics(7).values()))
    assert measured_noise([rec]) == {"gyr": None, "acc": None}
    gyr = rec.gyr + 1.0  # far beyond any noise, but nothing measured bounds it
    moved = Recording(t=rec.t, acc=rec.acc, gyr=gyr)
    assert stillness_problems(moved, G, NO_NOISE, measured_noise([moved])) == []


def test_a_quantised_still_channel_bounds_nothing() -> None:
    """The quietest segment reading no scatter (a quantised channel) gives no bound: no
    scale to judge others by, rather than every other segment refused."""
    statics = list(_statics(8).values())
    flat = Recording(t=statics[0].t, acc=statics[0].acc, gyr=np.zeros_like(statics[0].gyr))
    measured = measured_noise([flat, *statics[1:]])
    assert measured["gyr"] is None and measured["acc"] is not None


def test_a_unit_out_of_its_bias_tolerance_is_not_taken_for_motion() -> None:
    """The stated ranges are the tolerance's: a still unit whose gyro bias is three times its
    tolerance must fail that tolerance, not be refused as moving; a steady turn of 20 times
    the tolerance (a unit on a rotating table) is refused."""
    from calib_core.earth import EARTH_RATE
    from calib_core.stillness import OUT_OF_TOLERANCE
    from calib_core.units import DEG

    rec = _statics(5)["z_up"]
    bias_limit = np.full(3, 0.5 * DEG)  # rad/s per axis
    stated = StatedLimits(bias_limit, None, None, None, None)
    limit = EARTH_RATE + OUT_OF_TOLERANCE * np.linalg.norm(bias_limit)
    offset = np.array([3 * 0.5 * DEG, 0.0, 0.0])  # 3 x the tolerance on x
    out = Recording(t=rec.t, acc=rec.acc, gyr=rec.gyr - np.median(rec.gyr, axis=0) + offset)
    assert np.linalg.norm(np.median(out.gyr, axis=0)) < limit
    assert stillness_problems(out, G, stated) == []
    turning = Recording(t=rec.t, acc=rec.acc, gyr=out.gyr + np.array([0.0, 0.0, 20 * 0.5 * DEG]))
    (problem,) = stillness_problems(turning, G, stated)
    assert problem.startswith("gyro reads") and "10 times the stated bias range" in problem
