"""Is a static record still? Absolute criteria from physics and the unit's stated limits.

`calib_core.preprocess.motion` compares a record's windows with its own quietest ones,
which says nothing when the whole record moves (a vehicle's log given as a static-bias
run: its quietest quarter moves too) or is too short for windows. Here a static record is
judged against what a still unit can read at all:

- gyro: the magnitude of its median rate at most Earth's rate plus OUT_OF_TOLERANCE times
  the stated bias range (the profile's ``gyr.bias.*`` bound on each axis);
- accelerometer: the magnitude of its median specific force within OUT_OF_TOLERANCE times
  the stated bias and scale ranges (``acc.bias.*``, ``acc.scale.*``) of local gravity;
- scatter: each channel's robust standard deviation (median absolute deviation, so an
  isolated spike is none) at most STILL_SCATTER times its stated noise (``*.noise.*``
  high limit); where the profile states none, at most STILL_SCATTER times the noise
  measured on the run's quietest static segment (`measured_noise`: the same unit, filter
  and rate in every position, so one moving segment stands out).

A criterion whose limit the profile does not state, and a scatter that nothing measured
bounds (a run of one static segment), is not judged: a record's own successive
differences do not bound it, a still unit read through a low-pass filter scatters 2-6
times its sample-to-sample noise, as much as a moving vehicle does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib_core.earth import EARTH_RATE
from calib_core.params import AXES
from calib_core.preprocess.motion import MOTION_MIN_RATIO
from calib_core.recording import Recording
from calib_core.tolerances import ToleranceProfile
from calib_core.units import DEG

# A still unit's scatter within its stated noise; "far above" as the motion check's ratio
# of variances (MOTION_MIN_RATIO, 3.2 x the std): a unit out of its noise tolerance by less
# still reads as still (its noise parameter judges it), a moving one scatters 10-100x more.
STILL_SCATTER = math.sqrt(MOTION_MIN_RATIO)
MAD_TO_STD = 1.4826  # std of normal noise over its median absolute deviation
# The stated ranges are the tolerance's: a still unit that is out of its tolerance reads
# beyond them, and must fail that tolerance (the unit's verdict), not be refused as moving
# (a finding about the record). Only a reading this many times beyond the tolerance is
# taken for motion (or a unit far beyond any use: refused either way, with the figures).
OUT_OF_TOLERANCE = 10.0


@dataclass(frozen=True)
class StatedLimits:
    """Per-axis (3,) limits a profile states, SI; None where it states none."""

    gyr_bias: np.ndarray | None
    acc_bias: np.ndarray | None
    acc_scale: np.ndarray | None
    gyr_noise: np.ndarray | None
    acc_noise: np.ndarray | None

    @classmethod
    def of(cls, profile: ToleranceProfile) -> StatedLimits:
        def bound(family: str, upper_only: bool = False) -> np.ndarray | None:
            out = []
            for a in AXES:
                lim = profile.limit_for(f"{family}.{a}")
                if lim is None:
                    return None
                b = lim.high if upper_only else max(abs(lim.low), abs(lim.high))
                if not math.isfinite(b):
                    return None
                out.append(b)
            return np.array(out)

        return cls(
            bound("gyr.bias"),
            bound("acc.bias"),
            bound("acc.scale"),
            bound("gyr.noise", upper_only=True),
            bound("acc.noise", upper_only=True),
        )


def robust_scatter(data: np.ndarray) -> np.ndarray:
    """(3,) robust standard deviation of each column of `data` (N, 3): 1.4826 x the median
    absolute deviation, so an isolated spike is none."""
    return MAD_TO_STD * np.median(np.abs(data - np.median(data, axis=0)), axis=0)


def measured_noise(records: list[Recording]) -> dict[str, np.ndarray | None]:
    """{"gyr", "acc"}: (3,) the run's quietest static segment's robust scatter per axis, SI,
    from `records` (a run's static segments); None with fewer than two segments (a
    segment is no reference for itself) or where the quietest one reads no scatter (a
    quantised still channel: nothing to scale)."""
    usable = [r for r in records if len(r) >= 2]
    out: dict[str, np.ndarray | None] = {"gyr": None, "acc": None}
    if len(usable) < 2:
        return out
    for sensor in out:
        quietest = np.min([robust_scatter(getattr(r, sensor)) for r in usable], axis=0)
        out[sensor] = quietest if np.all(quietest > 0) else None
    return out


def stillness_problems(
    rec: Recording,
    gravity: float,
    stated: StatedLimits,
    measured: dict[str, np.ndarray | None] | None = None,
) -> list[str]:
    """What in static record `rec` no still unit within its stated limits reads (empty:
    still). `gravity` : local gravity, m/s^2. `measured` : `measured_noise` of the run's
    static segments, the scatter's bound where `stated` gives no noise."""
    problems = []
    measured = measured or {}
    if len(rec) < 2:
        return problems
    median = {"gyr": np.median(rec.gyr, axis=0), "acc": np.median(rec.acc, axis=0)}
    if stated.gyr_bias is not None:
        rate = float(np.linalg.norm(median["gyr"]))
        limit = EARTH_RATE + OUT_OF_TOLERANCE * float(np.linalg.norm(stated.gyr_bias))
        if rate > limit:
            problems.append(
                f"gyro reads {rate / DEG:.4g} deg/s (median magnitude); a still unit at most "
                f"{limit / DEG:.4g} deg/s (Earth's rate plus {OUT_OF_TOLERANCE:g} times the "
                "stated bias range)"
            )
    if stated.acc_bias is not None and stated.acc_scale is not None:
        force = float(np.linalg.norm(median["acc"]))
        bias = float(np.linalg.norm(stated.acc_bias))
        allowed = OUT_OF_TOLERANCE * (bias + float(stated.acc_scale.max()) * gravity)
        if abs(force - gravity) > allowed:
            problems.append(
                f"accelerometer reads {force:.5g} m/s^2 (median magnitude); a still unit "
                f"{gravity:.5g} +- {allowed:.3g} m/s^2 (local gravity, {OUT_OF_TOLERANCE:g} "
                "times the stated bias and scale ranges)"
            )
    for sensor, noise, unit, scale in (
        ("gyr", stated.gyr_noise, "deg/s", DEG),
        ("acc", stated.acc_noise, "m/s^2", 1.0),
    ):
        whose = "its stated noise"
        if noise is None:
            noise, whose = measured.get(sensor), "the noise of the run's quietest static segment"
        if noise is None:
            continue
        scatter = robust_scatter(getattr(rec, sensor))
        worst = int(np.argmax(scatter / noise))
        if scatter[worst] > STILL_SCATTER * noise[worst]:
            problems.append(
                f"{sensor} {AXES[worst]} scatters {scatter[worst] / scale:.3g} {unit} (robust "
                f"std), {scatter[worst] / noise[worst]:.3g} x {whose} "
                f"{noise[worst] / scale:.3g} {unit} (still: at most {STILL_SCATTER:.3g} x)"
            )
    return problems
