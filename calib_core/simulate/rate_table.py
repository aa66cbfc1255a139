"""Single-axis rate-table runs: rate plateaus about each body axis, with known gyro truth.

For each axis in turn the IMU is mounted with that axis on the (vertical) table
axis; the table steps through the rate points, each plateau being `settle_s`
(the table ramps to the new rate at the start) followed by `record_s` of
steady rate. One Recording per plateau, labelled "<axis>_<rate in deg/s>"
(e.g. "x_+100", "z_-50", "y_+0"), with the table's rate feedback in
``reference["table_rate"]`` (rad/s).

Gyro truth (channel i, on-axis input w_i):

    w_meas_i = b_i + (1 + M_ii)(1 + a_i/2 sign(w_i)) w_i + sum_{j != i} M_ij w_j + k3_i w_i^3

so the positive-rate scale is (1 + M_ii)(1 + a_i/2), the negative one
(1 + M_ii)(1 - a_i/2): asymmetry a_i exactly. Earth rate and g-sensitivity are
left out (constant over a run, they only add to the bias).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib_core.params import AXES
from calib_core.recording import Recording
from calib_core.units import DEG, STANDARD_GRAVITY

DEFAULT_RATES = tuple(r * DEG for r in (-100.0, -50.0, 0.0, 50.0, 100.0))  # rad/s


@dataclass(frozen=True)
class GyroTruth:
    """True gyro errors. bias (3,) rad/s; M (3, 3); k3 (3,) (rad/s)^-2; asymmetry (3,) 1."""

    bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    M: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    k3: np.ndarray = field(default_factory=lambda: np.zeros(3))
    asymmetry: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def output(self, w: np.ndarray) -> np.ndarray:
        """Noise-free gyro output for true rates `w` (N, 3) rad/s -> (N, 3) rad/s."""
        w = np.atleast_2d(w)
        diag = np.diag(self.M)
        off = self.M - np.diag(diag)
        on_axis = (1.0 + diag) * (1.0 + 0.5 * self.asymmetry * np.sign(w)) * w
        return self.bias + on_axis + w @ off.T + self.k3 * w**3


@dataclass(frozen=True)
class RateTableRun:
    recordings: list[Recording]
    truth: GyroTruth
    rates: tuple[float, ...]  # rad/s
    axes: tuple[str, ...]


def simulate_rate_table(
    truth: GyroTruth,
    *,
    rates: tuple[float, ...] = DEFAULT_RATES,
    axes: tuple[str, ...] = AXES,
    rate_hz: float = 1000.0,
    settle_s: float = 20.0,
    record_s: float = 10.0,
    gyro_noise_density: float = 0.0,
    acc_noise_std: float = 0.0,
    table_accel: float = 100.0 * DEG,
    table_stability: float = 0.0,
    feedback_noise: float = 0.0,
    gravity: float = STANDARD_GRAVITY,
    rng: np.random.Generator,
) -> RateTableRun:
    """A rate-table run with known truth.

    Parameters
    ----------
    truth : gyro errors.
    rates : table rates of the plateaus, rad/s (same list for every axis).
    axes : body axes put on the table axis, in order.
    rate_hz : IMU sample rate, Hz.
    settle_s, record_s : settle and record time of each plateau, s.
    gyro_noise_density : white gyro noise, rad/s/sqrt(Hz).
    acc_noise_std : white accelerometer noise per sample, m/s^2.
    table_accel : table angular acceleration while changing rate, rad/s^2.
    table_stability : relative rate wobble of the table (sinusoid at 1.3 Hz with
        random phase, amplitude table_stability * |rate|), which the feedback sees.
    feedback_noise : white noise of the rate feedback per sample, rad/s.
    gravity : m/s^2 (the table axis is vertical; the mounted axis reads +g).
    rng : numpy Generator.
    """
    if settle_s < 0 or record_s <= 0:
        raise ValueError(f"settle_s must be >= 0 and record_s > 0, got {settle_s}, {record_s}")
    n = int(round((settle_s + record_s) * rate_hz))
    tt = np.arange(n) / rate_hz
    recordings = []
    t0 = 0.0
    for axis in axes:
        if axis not in AXES:
            raise ValueError(f"axis must be one of {AXES}, got {axis!r}")
        j = AXES.index(axis)
        previous = 0.0
        for target in rates:
            # ramp from the previous plateau at constant acceleration, then hold
            ramp = previous + np.sign(target - previous) * table_accel * tt
            true_rate = np.where(np.abs(ramp - previous) < abs(target - previous), ramp, target)
            phase = rng.uniform(0.0, 2.0 * math.pi)
            true_rate = true_rate * (1.0 + table_stability * np.sin(2 * math.pi * 1.3 * tt + phase))
            w = np.zeros((n, 3))
            w[:, j] = true_rate
            gyr = truth.output(w) + gyro_noise_density * math.sqrt(rate_hz) * rng.standard_normal(
                (n, 3)
            )
            acc = np.zeros((n, 3))
            acc[:, j] = gravity
            acc += acc_noise_std * rng.standard_normal((n, 3))
            feedback = true_rate + feedback_noise * rng.standard_normal(n)
            recordings.append(
                Recording(
                    t=t0 + tt,
                    acc=acc,
                    gyr=gyr,
                    reference={"table_rate": feedback},
                    label=f"{axis}_{target / DEG:+g}",
                    source="simulate_rate_table",
                )
            )
            t0 += n / rate_hz
            previous = target
    return RateTableRun(recordings=recordings, truth=truth, rates=tuple(rates), axes=tuple(axes))
