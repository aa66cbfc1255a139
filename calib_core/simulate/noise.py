"""Sensor noise with a known Allan-deviation signature, and long static records.

Each generator returns samples of a rate (rad/s for a gyro, m/s^2 for an
accelerometer) whose overlapping Allan variance is, for tau well inside the record,

    white          N^2 / tau                   N: (unit)/sqrt(Hz)
    flicker        (2 ln 2 / pi) B^2           B: bias instability, (unit)
    random walk    K^2 tau / 3                 K: (unit)/sqrt(s)

(IEEE Std 952 Annex C). These are the truths the noise tests recover.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal
from scipy.spatial.transform import Rotation

from calib_core.earth import earth_rate_local
from calib_core.recording import Recording
from calib_core.units import STANDARD_GRAVITY


def white(n: int, rate_hz: float, arw: float, rng: np.random.Generator, channels: int = 1):
    """White rate noise with density `arw` ((unit)/sqrt(Hz)): sample std = arw sqrt(f_s).

    Returns (n,) if channels == 1 else (n, channels).
    """
    shape = (n,) if channels == 1 else (n, channels)
    return arw * math.sqrt(rate_hz) * rng.standard_normal(shape)


def flicker(n: int, rate_hz: float, bias_instability: float, rng: np.random.Generator):
    """1/f ("flicker", bias-instability) rate noise, shape (n,).

    Kasdin's fractional-integration filter H(z) = (1 - z^-1)^(-1/2), whose impulse
    response h_k = h_{k-1} (k - 1/2) / k is applied by FFT convolution over the whole
    record, so the 1/f law holds down to the record length. With white input of
    variance q the two-sided PSD is q / (2 pi f) for f << f_s; IEEE Std 952 writes
    its (two-sided) model as S(f) = B^2 / (2 pi f), so q = B^2. The process starts at 0.
    The sample rate does not enter: the 1/f PSD level is rate-independent.
    """
    del rate_hz  # kept in the signature for symmetry with the other generators
    k = np.arange(1, n)
    h = np.concatenate([[1.0], np.cumprod((k - 0.5) / k)])
    w = rng.standard_normal(n) * bias_instability
    return signal.fftconvolve(w, h)[:n]


def random_walk(n: int, rate_hz: float, rrw: float, rng: np.random.Generator):
    """Rate random walk with density `rrw` ((unit)/sqrt(s)), starting at 0, shape (n,).

    Increments have variance rrw^2 / f_s per sample.
    """
    return np.cumsum(rng.standard_normal(n)) * (rrw / math.sqrt(rate_hz))


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    """Round readings to multiples of `step` (an ADC LSB). Adds white noise of variance
    step^2 / 12 when the signal spans many steps."""
    return np.round(np.asarray(x) / step) * step if step > 0 else np.asarray(x)


@dataclass(frozen=True)
class NoiseSpec:
    """Noise mix of one channel (same for each channel of a triad).

    arw : white-noise density, (unit)/sqrt(Hz).
    bias_instability : flicker level B, (unit).
    rrw : random-walk density, (unit)/sqrt(s).
    quantisation : reading resolution, (unit); 0 = none.
    """

    arw: float = 0.0
    bias_instability: float = 0.0
    rrw: float = 0.0
    quantisation: float = 0.0

    def sample(self, n: int, rate_hz: float, rng: np.random.Generator, channels: int = 3):
        """(n, channels) noise samples (quantisation is applied later, to the full reading)."""
        out = np.zeros((n, channels))
        for c in range(channels):
            if self.arw:
                out[:, c] += white(n, rate_hz, self.arw, rng)
            if self.bias_instability:
                out[:, c] += flicker(n, rate_hz, self.bias_instability, rng)
            if self.rrw:
                out[:, c] += random_walk(n, rate_hz, self.rrw, rng)
        return out

    def allan_deviation(self, tau: np.ndarray) -> np.ndarray:
        """True Allan deviation of this mix at `tau` (s), quantisation excluded."""
        tau = np.asarray(tau, dtype=float)
        flat2 = 2.0 * math.log(2.0) / math.pi * self.bias_instability**2
        return np.sqrt(self.arw**2 / tau + flat2 + self.rrw**2 * tau / 3.0)


def level_frame_earth_rate(latitude_deg: float, heading_deg: float) -> np.ndarray:
    """Earth rate in the body frame of a level fixture, rad/s, (3,).

    Body frame: z up, x pointing at `heading_deg` (clockwise from North seen from
    above), y completing a right-handed frame. Body-to-NED rotation: heading about
    Down, then 180 deg about x (z up instead of down).
    """
    C_nb = Rotation.from_euler("ZX", [math.radians(heading_deg), math.pi]).as_matrix()
    return C_nb.T @ earth_rate_local(latitude_deg)


_AXIS = {"x": 0, "y": 1, "z": 2}


def up_vector(up_axis: str) -> np.ndarray:
    """Unit vector of the body axis that points up, e.g. "+z" -> (0, 0, 1), "-x" -> (-1, 0, 0)."""
    if len(up_axis) != 2 or up_axis[0] not in "+-" or up_axis[1] not in _AXIS:
        raise ValueError(f"up_axis must be one of +x, -x, +y, -y, +z, -z, got {up_axis!r}")
    e = np.zeros(3)
    e[_AXIS[up_axis[1]]] = 1.0 if up_axis[0] == "+" else -1.0
    return e


def simulate_static(
    duration_s: float,
    rate_hz: float,
    *,
    gyro_bias: np.ndarray,
    gyro_noise: NoiseSpec,
    acc_bias: np.ndarray = (0.0, 0.0, 0.0),
    acc_noise: NoiseSpec | None = None,
    gravity: float = STANDARD_GRAVITY,
    up_axis: str = "+z",
    latitude_deg: float | None = None,
    heading_deg: float = 0.0,
    outliers: int = 0,
    outlier_size: float = 0.0,
    temperature: float = 20.0,
    rng: np.random.Generator,
) -> Recording:
    """A long static record of an IMU on a level fixture.

    Parameters
    ----------
    duration_s, rate_hz : record length (s) and sample rate (Hz).
    gyro_bias : (3,) constant gyro bias, rad/s.
    gyro_noise : noise mix of each gyro channel (rad/s units).
    acc_bias : (3,) accelerometer bias, m/s^2.
    acc_noise : noise mix of each accelerometer channel (m/s^2 units); None = noiseless.
    gravity : m/s^2; the up axis reads +gravity.
    up_axis : body axis pointing up ("+z" for the level fixture).
    latitude_deg, heading_deg : if a latitude is given, the Earth rate is added to
        the gyro (only for up_axis "+z", frame of `level_frame_earth_rate`).
    outliers, outlier_size : number of single-sample spikes added to each gyro
        channel at random times, and their size (rad/s, random sign).
    temperature : constant deg C.
    rng : numpy Generator (the seed is the caller's).

    Returns
    -------
    Recording labelled "static", acc/gyr (N, 3).
    """
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    gyr = np.asarray(gyro_bias, dtype=float) + gyro_noise.sample(n, rate_hz, rng)
    if latitude_deg is not None:
        if up_axis != "+z":
            raise ValueError(
                f"Earth rate is simulated for the level z-up fixture only, got {up_axis}"
            )
        gyr += level_frame_earth_rate(latitude_deg, heading_deg)
    if outliers:
        idx = rng.choice(n, size=(outliers, 3), replace=False)
        for c in range(3):
            gyr[idx[:, c], c] += outlier_size * rng.choice([-1.0, 1.0], size=outliers)
    acc = gravity * up_vector(up_axis) + np.asarray(acc_bias, dtype=float)
    acc = np.broadcast_to(acc, (n, 3)).copy()
    if acc_noise is not None:
        acc += acc_noise.sample(n, rate_hz, rng)
        acc = quantise(acc, acc_noise.quantisation)
    gyr = quantise(gyr, gyro_noise.quantisation)
    return Recording(
        t=t,
        acc=acc,
        gyr=gyr,
        temp=np.full(n, temperature),
        label="static",
        source="simulate_static",
    )
