"""Rate-table runs with known truth: plateaus, feedback channels, two clocks, spikes.

The test oracle of the preprocessing steps. Everything here is generated from
closed forms (piecewise-linear rate, its exact integral for the angle) so a test
can compare an estimate with the truth that produced the data.

Clock convention (shared with `calib_core.preprocess.sync.ClockModel`): the IMU
clock is the time base; the table logs the same physical instant at

    t_ref = t_imu + offset_s + drift_ppm * 1e-6 * (t_imu - t0_s)

i.e. a constant offset plus a clock-rate difference.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core.preprocess.sync import ClockModel
from calib_core.recording import Recording
from calib_core.units import DEG, STANDARD_GRAVITY

AXIS_VECTORS = {
    "x": np.array([1.0, 0.0, 0.0]),
    "y": np.array([0.0, 1.0, 0.0]),
    "z": np.array([0.0, 0.0, 1.0]),
}


@dataclass(frozen=True)
class RateSchedule:
    """A piecewise-linear table rate: ramps at constant acceleration, then holds.

    Attributes
    ----------
    knot_t : (K,) s, true time of each knot (rate changes slope at knots).
    knot_rate : (K,) rad/s, rate at each knot.
    plateaus : (P, 3) rows of (hold start s, hold end s, rate rad/s), the truth
        a plateau detector is measured against.
    """

    knot_t: np.ndarray
    knot_rate: np.ndarray
    plateaus: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.knot_t[-1])

    def rate(self, t: np.ndarray) -> np.ndarray:
        """Table rate at true times `t` (N,), rad/s; 0 outside the schedule."""
        return np.interp(t, self.knot_t, self.knot_rate, left=0.0, right=0.0)

    def angle(self, t: np.ndarray) -> np.ndarray:
        """Table angle at true times `t` (N,), rad: exact integral of `rate`."""
        t = np.asarray(t, dtype=float)
        dt_knots = np.diff(self.knot_t)
        # Angle at each knot: trapezoid is exact for a piecewise-linear rate.
        angle_knots = np.concatenate(
            [[0.0], np.cumsum(0.5 * (self.knot_rate[1:] + self.knot_rate[:-1]) * dt_knots)]
        )
        tc = np.clip(t, self.knot_t[0], self.knot_t[-1])
        k = np.clip(np.searchsorted(self.knot_t, tc, side="right") - 1, 0, len(self.knot_t) - 2)
        slope = (self.knot_rate[k + 1] - self.knot_rate[k]) / dt_knots[k]
        tau = tc - self.knot_t[k]
        return angle_knots[k] + self.knot_rate[k] * tau + 0.5 * slope * tau**2


def rate_schedule(
    rates: np.ndarray | list[float],
    *,
    hold_s: float = 30.0,
    accel: float = 20.0 * DEG,
    lead_s: float = 10.0,
    tail_s: float = 10.0,
) -> RateSchedule:
    """Plateaus at the given rates, in order, joined by constant-acceleration ramps.

    Parameters
    ----------
    rates : (P,) plateau rates, rad/s (e.g. -100..100 deg/s in rad/s).
    hold_s : time held at each rate after its ramp, s.
    accel : table angular acceleration on the ramps, rad/s^2 (> 0).
    lead_s, tail_s : time at rest before the first and after the last ramp, s.
    """
    rates = np.asarray(rates, dtype=float)
    if accel <= 0 or hold_s <= 0:
        raise ValueError(f"rate_schedule: accel ({accel}) and hold_s ({hold_s}) must be > 0")
    t, r = [0.0, lead_s], [0.0, 0.0]
    plateaus = []
    for rate in np.concatenate([rates, [0.0]]):
        ramp = max(abs(rate - r[-1]) / accel, 1e-6)  # 1 us keeps knots strictly increasing
        t.append(t[-1] + ramp)
        r.append(rate)
        hold = hold_s if len(plateaus) < len(rates) else tail_s
        plateaus.append((t[-1], t[-1] + hold, rate))
        t.append(t[-1] + hold)
        r.append(rate)
    return RateSchedule(np.array(t), np.array(r), np.array(plateaus[: len(rates)]))


@dataclass(frozen=True)
class TwoClocks:
    """Sample times of an IMU log and a table log of the same run.

    Attributes
    ----------
    imu_t : (N,) IMU timestamps, s (the IMU clock is the true time base).
    ref_t : (M,) table timestamps, s, on the table clock.
    ref_true_t : (M,) true (IMU-clock) time of each table sample, s.
    clock : the true relation t_ref = clock.to_ref(t_imu).
    ref_gaps : list of (start, end) true times where the table log is missing.
    """

    imu_t: np.ndarray
    ref_t: np.ndarray
    ref_true_t: np.ndarray
    clock: ClockModel
    ref_gaps: list[tuple[float, float]] = field(default_factory=list)


def two_clocks(
    duration_s: float,
    imu_hz: float,
    ref_hz: float,
    clock: ClockModel,
    *,
    drop_fraction: float = 0.0,
    ref_gaps: list[tuple[float, float]] | None = None,
    jitter_s: float = 0.0,
    rng: np.random.Generator | None = None,
) -> TwoClocks:
    """Timestamps of two logs of one run whose clocks relate as `clock` says.

    Parameters
    ----------
    duration_s : run length, s.
    imu_hz, ref_hz : nominal sample rates of the IMU and of the table feedback, Hz.
    clock : the true relation t_ref = clock.to_ref(t_imu) (offset_s: table clock minus
        IMU clock at t_imu = t0_s, s; drift_ppm: table runs fast if > 0).
    drop_fraction : fraction of samples dropped at random from each log.
    ref_gaps : (start, end) true-time windows where the table log is missing, s.
    jitter_s : std of white timestamp jitter added to both logs, s.
    """
    rng = np.random.default_rng() if rng is None else rng
    ref_gaps = list(ref_gaps or [])

    def stamps(hz: float) -> np.ndarray:
        t = np.arange(int(round(duration_s * hz))) / hz
        keep = rng.random(t.size) >= drop_fraction
        keep[[0, -1]] = True
        return t[keep]

    imu_t = stamps(imu_hz)
    ref_true = stamps(ref_hz)
    for start, end in ref_gaps:
        ref_true = ref_true[(ref_true < start) | (ref_true >= end)]
    ref_t = clock.to_ref(ref_true)
    if jitter_s > 0:
        imu_t = imu_t + rng.normal(0.0, jitter_s, imu_t.size)
        ref_t = ref_t + rng.normal(0.0, jitter_s, ref_t.size)
    return TwoClocks(imu_t, ref_t, ref_true, clock, ref_gaps)


@dataclass(frozen=True)
class TableRun:
    """One simulated rate-table run with its truth.

    recording : IMU samples (gyro = table rate along `axis` + bias + noise).
    ref_t : (M,) table timestamps (table clock), s.
    ref_channels : {"table_angle": (M,) rad, "table_rate": (M,) rad/s}.
    clocks : timestamps and the true clock relation.
    schedule : the true rate profile (on the IMU clock).
    """

    recording: Recording
    ref_t: np.ndarray
    ref_channels: dict[str, np.ndarray]
    clocks: TwoClocks
    schedule: RateSchedule


def rate_table_run(
    rates: np.ndarray | list[float],
    *,
    imu_hz: float = 100.0,
    ref_hz: float = 100.0,
    axis: str = "z",
    hold_s: float = 30.0,
    accel: float = 20.0 * DEG,
    offset_s: float = 0.0,
    drift_ppm: float = 0.0,
    drop_fraction: float = 0.0,
    ref_gaps: list[tuple[float, float]] | None = None,
    gyr_noise: float = 0.05 * DEG,
    acc_noise: float = 0.02,
    gyr_bias: float = 0.2 * DEG,
    gyr_scale: float = 0.0,
    gravity: float = STANDARD_GRAVITY,
    seed: int = 0,
) -> TableRun:
    """An IMU on a single-axis rate table (table axis vertical, IMU `axis` along it).

    Parameters
    ----------
    rates : (P,) plateau rates, rad/s.
    imu_hz, ref_hz : sample rates of IMU and table feedback, Hz.
    axis : IMU axis along the (upward) table axis: "x", "y" or "z".
    gyr_noise, acc_noise : white-noise std per sample, rad/s and m/s^2.
    gyr_bias : gyro bias on every axis, rad/s; gyr_scale : scale error on `axis`.
    offset_s : table clock minus IMU clock at t_imu = 0, s.
    drift_ppm : clock-rate difference, parts per million (table runs fast if > 0).
    Other parameters as in `rate_schedule` and `two_clocks`.
    """
    rng = np.random.default_rng(seed)
    schedule = rate_schedule(rates, hold_s=hold_s, accel=accel)
    clocks = two_clocks(
        schedule.duration,
        imu_hz,
        ref_hz,
        ClockModel(offset_s=offset_s, drift_ppm=drift_ppm, t0_s=0.0),
        drop_fraction=drop_fraction,
        ref_gaps=ref_gaps,
        rng=rng,
    )
    u = AXIS_VECTORS[axis]
    n = clocks.imu_t.size
    rate = schedule.rate(clocks.imu_t)
    gyr = np.outer((1.0 + gyr_scale) * rate, u) + gyr_bias + rng.normal(0.0, gyr_noise, (n, 3))
    acc = np.outer(np.full(n, gravity), u) + rng.normal(0.0, acc_noise, (n, 3))
    rec = Recording(t=clocks.imu_t, acc=acc, gyr=gyr, source=f"rate_table_run(seed={seed})")
    ref_channels = {
        "table_angle": schedule.angle(clocks.ref_true_t),
        "table_rate": schedule.rate(clocks.ref_true_t),
    }
    return TableRun(rec, clocks.ref_t, ref_channels, clocks, schedule)


def inject_spikes(
    x: np.ndarray,
    fraction: float,
    sigma: float | np.ndarray,
    amplitude_sigma: tuple[float, float] = (6.0, 12.0),
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Add isolated spikes to a signal, independently per column.

    Parameters
    ----------
    x : (N,) or (N, C) signal.
    fraction : fraction of samples per column that get a spike (0..1).
    sigma : noise std of the signal, scalar or (C,), same unit as x.
    amplitude_sigma : spike size range in units of sigma; sizes are uniform in
        it and the sign is random.

    Returns
    -------
    (x_spiked, mask) : the spiked copy and a boolean mask (same shape) of the
        samples that got a spike.
    """
    rng = np.random.default_rng() if rng is None else rng
    y = np.array(x, dtype=float, copy=True)
    y2 = y.reshape(y.shape[0], -1)
    mask = np.zeros(y2.shape, dtype=bool)
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), (y2.shape[1],))
    n_spikes = int(round(fraction * y2.shape[0]))
    lo, hi = amplitude_sigma
    for c in range(y2.shape[1]):
        idx = rng.choice(y2.shape[0], size=n_spikes, replace=False)
        size = rng.uniform(lo, hi, n_spikes) * rng.choice([-1.0, 1.0], n_spikes)
        y2[idx, c] += size * sig[c]
        mask[idx, c] = True
    return y2.reshape(y.shape), mask.reshape(y.shape)
