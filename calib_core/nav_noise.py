"""Noise models for navigation filters (Kalibr, OpenVINS), the science: Allan results ->
continuous-time noise densities with their own uncertainty.

Kalibr's IMU model (its wiki, "IMU Noise Model"), one axis:

    w_meas(t) = w(t) + b(t) + n(t),   E[n(t) n(t')] = sigma^2 delta(t - t'),   b' = sigma_b w_b(t)

`sigma` (noise density, rad/s/sqrt(Hz), m/s^2/sqrt(Hz)) is the Allan white-noise term N
(avar = N^2 / tau), and `sigma_b` (random walk, rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz)) is the
rate random walk K (avar = K^2 tau / 3): the same continuous-time quantities, no factor.
Discrete time at the update rate f (period dt = 1 / f): sigma_d = sigma / sqrt(dt),
sigma_bd = sigma_b sqrt(dt). Bias instability (flicker) has no term in this model.

Uncertainty of a term: a parametric bootstrap of the whole estimator (GUM Supplement 1
practice). Records of the same length and rate are generated from the fitted noise (white N,
flicker B, random walk K), passed through the static-bias solver's own chain (n-sigma
clipping and fill, overlapping Allan deviation, noise fit), and the spread of the fitted
values about the generating ones is the standard uncertainty; their mean offset is the
estimator's bias (e.g. clipping a Gaussian's tails at 3 sigma lowers N by about 1.5 %),
reported and added in quadrature, never subtracted. An analytic single-tau reading
(chi-squared on the equivalent degrees of freedom) under-covers the random walk: the
fit combines correlated taus. The bootstrap is seeded, so an export is reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from calib_core.noise import NoiseParameters

AXES = ("x", "y", "z")


BOOTSTRAP_RECORDS = 20  # replicates per axis: the std itself known to ~16 %
BOOTSTRAP_SEED = 20260


@lru_cache(maxsize=2)
def _flicker_kernel(n: int) -> tuple[int, np.ndarray]:
    """(FFT length, rfft of Kasdin's (1 - z^-1)^(-1/2) impulse response of length n): the
    same for every channel and replicate of a bootstrap, so it is transformed once."""
    from scipy import fft

    k = np.arange(1, n)
    h = np.concatenate([[1.0], np.cumprod((k - 0.5) / k)])
    size = fft.next_fast_len(2 * n - 1, real=True)
    return size, fft.rfft(h, size)


def noise_records(
    terms: list[NoiseParameters], n: int, rate_hz: float, rng: np.random.Generator
) -> np.ndarray:
    """(n, len(terms)) rate noise, channel c with the white, flicker and random-walk terms of
    terms[c] (the conventions of `calib_core.noise`: sample std N sqrt(f_s); flicker by
    Kasdin's (1 - z^-1)^(-1/2) filter of white noise of variance B^2; random-walk increments
    of std K / sqrt(f_s))."""
    from scipy import fft

    out = np.empty((n, len(terms)))
    for c, p in enumerate(terms):
        x = p.arw * math.sqrt(rate_hz) * rng.standard_normal(n)
        if p.bias_instability > 0:
            size, kernel = _flicker_kernel(n)
            w = fft.rfft(rng.standard_normal(n) * p.bias_instability, size)
            x += fft.irfft(w * kernel, size)[:n]
        if p.rrw > 0:
            x += np.cumsum(rng.standard_normal(n)) * (p.rrw / math.sqrt(rate_hz))
        out[:, c] = x
    return out


def bootstrap_terms(
    terms: list[NoiseParameters],
    n: int,
    rate_hz: float,
    n_sigma: float,
    taus: np.ndarray,
    records: int = BOOTSTRAP_RECORDS,
    seed: int = BOOTSTRAP_SEED,
) -> dict[str, np.ndarray]:
    """Bias and spread of the fitted N and K of each channel (module docstring).

    Parameters
    ----------
    terms : the fitted noise parameters of each channel (the generating values).
    n, rate_hz : record length (samples) and sample rate (Hz) of the run.
    n_sigma : the run's clipping rule.
    taus : the run's cluster times, s.
    records, seed : replicates per channel, the generator's seed.

    Returns
    -------
    {"n_bias", "n_sd", "k_bias", "k_sd"}: (channels,) arrays in the terms' units.
    """
    from calib_core.solvers.static_bias import sensor_statistics

    rng = np.random.default_rng(seed)
    fitted = np.empty((records, len(terms), 2))
    for r in range(records):
        x = noise_records(terms, n, rate_hz, rng)
        got = sensor_statistics(x, rate_hz, n_sigma, np.asarray(taus, dtype=float))[4]
        fitted[r] = [(q.arw, q.rrw) for q in got]
    truth = np.array([(p.arw, p.rrw) for p in terms])
    bias = fitted.mean(axis=0) - truth
    sd = fitted.std(axis=0, ddof=1)
    return {"n_bias": bias[:, 0], "n_sd": sd[:, 0], "k_bias": bias[:, 1], "k_sd": sd[:, 1]}


@dataclass(frozen=True)
class NavTerm:
    """One continuous-time noise term of one sensor, all axes.

    Attributes
    ----------
    values : (3,) per axis, SI continuous-time unit (`unit`), as fitted.
    stds : (3,) their standard uncertainties: the bootstrap spread and bias in quadrature.
    biases : (3,) the estimator's bias found by the bootstrap (fitted minus generating).
    unit : "rad/s/sqrt(Hz)", "m/s^2/sqrt(Hz)", "rad/s^2/sqrt(Hz)" or "m/s^3/sqrt(Hz)".
    """

    values: np.ndarray
    stds: np.ndarray
    biases: np.ndarray
    unit: str

    @property
    def axis(self) -> int:
        """The axis exported: the largest value (a scalar model must not under-state any axis)."""
        return int(np.argmax(self.values))

    @property
    def value(self) -> float:
        return float(self.values[self.axis])

    @property
    def std(self) -> float:
        return float(self.stds[self.axis])


@dataclass(frozen=True)
class NavNoise:
    """Kalibr / OpenVINS noise model of an IMU from one static (Allan) record.

    Attributes
    ----------
    acc_noise_density, acc_random_walk, gyr_noise_density, gyr_random_walk : NavTerm.
    sample_rate_hz : the record's sample rate, Hz.
    duration_s : the record's length, s.
    methods : "sensor.axis" -> the noise-fit method used ("model" / "lines").
    """

    acc_noise_density: NavTerm
    acc_random_walk: NavTerm
    gyr_noise_density: NavTerm
    gyr_random_walk: NavTerm
    sample_rate_hz: float
    duration_s: float
    methods: dict[str, str]

    def discrete(self, update_rate_hz: float) -> dict[str, float]:
        """Kalibr's discrete-time values at `update_rate_hz`: sigma / sqrt(dt), sigma_b sqrt(dt)."""
        dt = 1.0 / update_rate_hz
        return {
            "accelerometer_noise": self.acc_noise_density.value / math.sqrt(dt),
            "accelerometer_bias_step": self.acc_random_walk.value * math.sqrt(dt),
            "gyroscope_noise": self.gyr_noise_density.value / math.sqrt(dt),
            "gyroscope_bias_step": self.gyr_random_walk.value * math.sqrt(dt),
        }


_UNITS = {
    ("acc", "n"): "m/s^2/sqrt(Hz)",
    ("acc", "k"): "m/s^3/sqrt(Hz)",
    ("gyr", "n"): "rad/s/sqrt(Hz)",
    ("gyr", "k"): "rad/s^2/sqrt(Hz)",
}


def nav_noise(info: dict) -> NavNoise:
    """The navigation noise model from a static-bias calibration's `info`.

    Parameters
    ----------
    info : `Calibration.info` of procedure static_bias (calib_core.solvers.static_bias):
        ``allan`` (taus per sensor), ``noise_parameters`` (per sensor, per axis),
        ``n_samples``, ``sample_rate_hz``, ``duration_s``.

    Returns
    -------
    NavNoise. Raises ValueError naming what is missing when `info` is not a static-bias
    run's (no Allan deviation, no noise parameters).
    """
    missing = [
        k for k in ("allan", "noise_parameters", "n_samples", "sample_rate_hz") if k not in info
    ]
    for sensor in ("acc", "gyr"):
        if sensor not in info.get("noise_parameters", {}) or sensor not in info.get("allan", {}):
            missing.append(f"noise_parameters.{sensor} / allan.{sensor}")
    if missing:
        raise ValueError(
            "a Kalibr / OpenVINS noise model needs a static-bias (Allan) run; the calibration's "
            f"info lacks {', '.join(dict.fromkeys(missing))}"
        )
    n, rate = int(info["n_samples"]), float(info["sample_rate_hz"])
    terms: dict[tuple[str, str], NavTerm] = {}
    methods: dict[str, str] = {}
    for sensor in ("acc", "gyr"):
        docs = info["noise_parameters"][sensor]
        fitted = [
            NoiseParameters(
                float(d["arw"]), float(d["bias_instability"]), float(d["rrw"]), str(d["method"])
            )
            for d in docs
        ]
        methods |= {f"{sensor}.{a}": p.method for a, p in zip(AXES, fitted, strict=True)}
        boot = bootstrap_terms(
            fitted,
            n,
            rate,
            float(info.get("n_sigma", 3.0)),
            np.asarray(info["allan"][sensor]["taus"], dtype=float),
        )
        for term, attr in (("n", "arw"), ("k", "rrw")):
            bias, sd = boot[f"{term}_bias"], boot[f"{term}_sd"]
            terms[sensor, term] = NavTerm(
                values=np.array([getattr(p, attr) for p in fitted]),
                stds=np.hypot(sd, bias),
                biases=bias,
                unit=_UNITS[sensor, term],
            )
    return NavNoise(
        acc_noise_density=terms["acc", "n"],
        acc_random_walk=terms["acc", "k"],
        gyr_noise_density=terms["gyr", "n"],
        gyr_random_walk=terms["gyr", "k"],
        sample_rate_hz=rate,
        duration_s=float(info.get("duration_s", n / rate)),
        methods=methods,
    )
