"""Synthetic lab runs with known truth: the test oracle of the project.

A six-position + integral-method run (the MPU-6000 paper's procedure): six
static positions with one axis up or down, then n whole turns counter-clockwise
and clockwise about each axis with that axis pointing up. The measured data are
the archive's error model applied to the true motion,

    f_meas = (I + M_a) f_true + b_a + noise
    w_meas = (I + M_g) w_true + G f_true + b_g + noise,

with white Gaussian noise per channel, optional outlier spikes and gyro
saturation at the sensor's range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib_core import params
from calib_core.recording import Recording
from calib_core.solvers.earth_rate_faces import face_earth_rate
from calib_core.solvers.integral import ROTATION_LABELS
from calib_core.solvers.six_position import STATIC_LABELS, axis_vector
from calib_core.units import DEG, STANDARD_GRAVITY

# Error magnitudes per sensor grade: (low, high) of |value|, SI.
_GRADES: dict[str, dict[str, tuple[float, float]]] = {
    "mems": {
        "acc_bias": (0.05, 0.3),  # m/s^2
        "acc_scale": (0.005, 0.03),
        "acc_misalign": (0.001, 0.01),
        "gyr_bias": (0.5 * DEG, 3.0 * DEG),  # rad/s
        "gyr_scale": (0.005, 0.03),
        "gyr_misalign": (0.001, 0.01),
        "gsens": (0.01 * DEG / STANDARD_GRAVITY, 0.1 * DEG / STANDARD_GRAVITY),
        "acc_noise": (0.008, 0.012),  # m/s^2 per sample
        "gyr_noise": (0.04 * DEG, 0.06 * DEG),  # rad/s per sample
    },
    # A navigation-grade FOG with a MEMS-class accelerometer: angle random walk
    # 0.001..0.002 deg/sqrt(h), per-sample std at 100 Hz = ARW * sqrt(100 Hz).
    "fog": {
        "acc_bias": (0.005, 0.03),
        "acc_scale": (1e-4, 1e-3),
        "acc_misalign": (1e-4, 1e-3),
        "gyr_bias": (0.01 * DEG / 3600.0, 1.0 * DEG / 3600.0),
        "gyr_scale": (1e-4, 1e-3),
        "gyr_misalign": (1e-4, 1e-3),
        "gsens": (0.0, 0.0),
        "acc_noise": (0.001, 0.002),
        "gyr_noise": (0.001 * DEG / 60.0 * 10.0, 0.002 * DEG / 60.0 * 10.0),
    },
}


@dataclass
class TrueErrors:
    """The true error model of a simulated IMU, SI units.

    Attributes
    ----------
    acc_bias : (3,) m/s^2.
    acc_M : (3, 3) accelerometer scale (diagonal) and misalignment, dimensionless.
    gyr_bias : (3,) rad/s.
    gyr_M : (3, 3) gyro scale and misalignment, dimensionless.
    gsens : (3, 3) g-sensitivity G, (rad/s)/(m/s^2).
    acc_noise : (3,) per-sample white-noise std, m/s^2.
    gyr_noise : (3,) per-sample white-noise std, rad/s.
    """

    acc_bias: np.ndarray
    acc_M: np.ndarray  # noqa: N815 (M is the error matrix of the model)
    gyr_bias: np.ndarray
    gyr_M: np.ndarray  # noqa: N815
    gsens: np.ndarray
    acc_noise: np.ndarray
    gyr_noise: np.ndarray

    def parameters(self) -> dict[str, float]:
        """All true values by canonical parameter name."""
        out: dict[str, float] = {}
        for sensor, b, M, noise in (
            ("acc", self.acc_bias, self.acc_M, self.acc_noise),
            ("gyr", self.gyr_bias, self.gyr_M, self.gyr_noise),
        ):
            for i, a in enumerate(params.AXES):
                out[params.bias(sensor, a)] = float(b[i])
                out[f"{sensor}.noise.{a}"] = float(noise[i])
            for i, row in enumerate(params.matrix_names(sensor)):
                for j, name in enumerate(row):
                    out[name] = float(M[i, j])
        for i, row in enumerate(params.gsens_names()):
            for j, name in enumerate(row):
                out[name] = float(self.gsens[i, j])
        return out

    def acc_measured(self, f_true: np.ndarray) -> np.ndarray:
        """Noise-free accelerometer output for true specific force (N, 3), m/s^2."""
        return f_true @ (np.eye(3) + self.acc_M).T + self.acc_bias

    def gyr_measured(self, w_true: np.ndarray, f_true: np.ndarray) -> np.ndarray:
        """Noise-free gyro output for true rate (N, 3) rad/s and specific force (N, 3)."""
        return w_true @ (np.eye(3) + self.gyr_M).T + f_true @ self.gsens.T + self.gyr_bias


def random_errors(rng: np.random.Generator, grade: str = "mems") -> TrueErrors:
    """Draw a realistic error model: magnitudes uniform in the grade's range, random signs.

    Parameters
    ----------
    rng : random generator.
    grade : sensor grade; "mems" (consumer MEMS like the MPU-6000) or "fog" (a
        navigation-grade fibre-optic gyro that sees the Earth rate; no g-sensitivity).
    """
    try:
        ranges = _GRADES[grade]
    except KeyError:
        raise ValueError(
            f"unknown sensor grade {grade!r}; expected one of {sorted(_GRADES)}"
        ) from None

    def signed(key: str, shape: tuple[int, ...]) -> np.ndarray:
        low, high = ranges[key]
        return rng.uniform(low, high, shape) * rng.choice([-1.0, 1.0], shape)

    def matrix(scale_key: str, misalign_key: str) -> np.ndarray:
        m = signed(misalign_key, (3, 3))
        np.fill_diagonal(m, signed(scale_key, (3,)))
        return m

    return TrueErrors(
        acc_bias=signed("acc_bias", (3,)),
        acc_M=matrix("acc_scale", "acc_misalign"),
        gyr_bias=signed("gyr_bias", (3,)),
        gyr_M=matrix("gyr_scale", "gyr_misalign"),
        gsens=signed("gsens", (3, 3)),
        acc_noise=rng.uniform(*ranges["acc_noise"], 3),
        gyr_noise=rng.uniform(*ranges["gyr_noise"], 3),
    )


@dataclass
class SimulatedRun:
    """A simulated lab run: segments by label, the truth that made them, the settings."""

    segments: dict[str, Recording]
    truth: TrueErrors
    gravity: float
    settings: dict[str, Any] = field(default_factory=dict)

    def truth_dict(self) -> dict[str, Any]:
        """JSON-able truth: {"parameters": {name: value}, "gravity": g, "settings": {...}}."""
        return {
            "parameters": self.truth.parameters(),
            "gravity": float(self.gravity),
            "settings": dict(self.settings),
        }


def rotation_profile(
    rate_hz: float, turns: int, peak_rate: float, pause_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Sample times and rate of one rotation: pause, n turns, pause.

    The rate is w(t) = w_peak sin^2(pi t / T) during the motion, smooth at both
    ends (zero rate and zero acceleration), with T = 4 pi n / w_peak so that the
    angle turned is exactly 2 pi n.

    Returns
    -------
    t : (N,) s, starting at 0.
    rate : (N,) rad/s, >= 0.
    """
    motion_s = 4.0 * math.pi * turns / peak_rate
    n = int(math.floor((2.0 * pause_s + motion_s) * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    tau = t - pause_s
    moving = (tau > 0.0) & (tau < motion_s)
    rate = np.where(moving, peak_rate * np.sin(math.pi * tau / motion_s) ** 2, 0.0)
    return t, rate


@dataclass(frozen=True)
class Turns:
    """The rotations of a simulated session: whole turns between pauses (`rotation_profile`).

    turns : whole turns per rotation. rotation_rate_dps : peak rate, deg/s.
    pause_s : static time before and after each rotation, s.
    """

    turns: int = 1
    rotation_rate_dps: float = 90.0
    pause_s: float = 2.0

    def profile(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """Sample times (s) and rate (rad/s, >= 0) of one rotation at `rate_hz` Hz."""
        return rotation_profile(rate_hz, self.turns, self.rotation_rate_dps * DEG, self.pause_s)


ONE_TURN = Turns()  # the default: one turn at 90 deg/s peak, 2 s pauses


def six_position_integral_run(
    truth: TrueErrors,
    rng: np.random.Generator,
    *,
    gravity: float = STANDARD_GRAVITY,
    rate_hz: float = 50.0,
    static_s: float = 20.0,
    turns: int = 1,
    rotation_rate_dps: float = 90.0,
    pause_s: float = 2.0,
    spike_fraction: float = 0.0,
    spike_sigma: float = 8.0,
    temp_c: float = 20.0,
    gyro_range_dps: float = 2000.0,
    cw_pause_s: float | None = None,
    true_up: dict[str, np.ndarray] | None = None,
    earth_rate_at: tuple[float, float] | None = None,
) -> SimulatedRun:
    """Simulate a six-position + integral-method lab run.

    Parameters
    ----------
    truth : the error model applied to the true motion.
    rng : random generator for noise and spikes.
    gravity : local gravity, m/s^2.
    rate_hz : sample rate, Hz.
    static_s : length of each static position, s.
    turns : whole turns per rotation.
    rotation_rate_dps : peak rotation rate, deg/s.
    pause_s : static time before and after each rotation, s.
    spike_fraction : fraction of samples that get an outlier spike of
        +-spike_sigma times the channel's noise std on one random channel.
    temp_c : temperature channel level, deg C (plus 0.01 deg C noise).
    gyro_range_dps : gyro full scale, deg/s; the output saturates there.
    cw_pause_s : pause of the clockwise rotations if different from pause_s, s
        (unequal cw / ccw record durations, as happen in a lab).
    true_up : label -> true up direction (3,) unit vector in the unit's frame, for the
        positions on a cube face that is not square (the rotations turn about it too);
        absent labels are square (the label's axis).
    earth_rate_at : (latitude_deg, heading_deg) of a level fixture: the statics then see
        the Earth rate in each position's frame (calib_core.solvers.earth_rate_faces);
        absent, they see none. The rotations never include it.

    Returns
    -------
    SimulatedRun with segments x_up, x_dn, y_up, y_dn, z_up, z_dn (static) and
    x_ccw, x_cw, y_ccw, y_cw, z_ccw, z_cw (rotations, ccw = positive rate about
    the upward axis); each segment's t starts at 0.
    """
    if turns < 1:
        raise ValueError(f"turns must be a positive whole number, got {turns}")
    if rate_hz <= 0 or static_s <= 0 or rotation_rate_dps <= 0 or pause_s < 0:
        raise ValueError("rate_hz, static_s and rotation_rate_dps must be > 0, pause_s >= 0")
    if not 0.0 <= spike_fraction < 1.0:
        raise ValueError(f"spike_fraction must be in [0, 1), got {spike_fraction}")
    gyro_range = gyro_range_dps * DEG
    noise = np.concatenate([truth.acc_noise, truth.gyr_noise])  # (6,) acc then gyr
    spikes: dict[str, int] = {}

    def record(label: str, t: np.ndarray, w_true: np.ndarray) -> Recording:
        n = t.shape[0]
        f_true = np.broadcast_to(up_of(label) * gravity, (n, 3))
        clean = np.hstack([truth.acc_measured(f_true), truth.gyr_measured(w_true, f_true)])
        data = clean + rng.standard_normal((n, 6)) * noise
        n_spikes = int(round(spike_fraction * n))
        if n_spikes:
            rows = rng.choice(n, n_spikes, replace=False)
            cols = rng.integers(0, 6, n_spikes)
            data[rows, cols] += rng.choice([-1.0, 1.0], n_spikes) * spike_sigma * noise[cols]
        spikes[label] = n_spikes
        gyr = np.clip(data[:, 3:], -gyro_range, gyro_range)  # saturation at full scale
        temp = temp_c + 0.01 * rng.standard_normal(n)
        return Recording(t, data[:, :3], gyr, temp, label=label, source=f"simulated {label}")

    def up_of(label: str) -> np.ndarray:
        return np.asarray((true_up or {}).get(label, axis_vector(label, 1.0)), dtype=float)

    segments: dict[str, Recording] = {}
    t_static = np.arange(int(round(static_s * rate_hz))) / rate_hz
    for label in STATIC_LABELS:
        w = np.zeros(3) if earth_rate_at is None else face_earth_rate(label, *earth_rate_at)
        segments[label] = record(label, t_static, np.broadcast_to(w, (t_static.shape[0], 3)))
    peak = rotation_rate_dps * DEG
    for label in ROTATION_LABELS:
        axis, sense = label.split("_")
        pause = pause_s if sense == "ccw" or cw_pause_s is None else cw_pause_s
        t, rate = rotation_profile(rate_hz, turns, peak, pause)
        # ccw: positive rate about the upward axis, the face's true normal
        w_true = np.outer(rate if sense == "ccw" else -rate, up_of(label))
        segments[label] = record(label, t, w_true)

    settings = {
        "procedure": "six_position_integral",
        "rate_hz": rate_hz,
        "static_s": static_s,
        "turns": turns,
        "rotation_rate_dps": rotation_rate_dps,
        "pause_s": pause_s,
        "cw_pause_s": cw_pause_s,
        "spike_fraction": spike_fraction,
        "spike_sigma": spike_sigma,
        "spikes": spikes,
        "temp_c": temp_c,
        "gyro_range_dps": gyro_range_dps,
        "earth_rate_at": earth_rate_at,
    }
    return SimulatedRun(segments, truth, gravity, settings)
