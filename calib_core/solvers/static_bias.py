"""Static bias and noise from one long static record (docs/methods.md 2.5).

Frame of the Earth-rate correction: a level fixture, body z up, body x pointing
at `heading_deg` (clockwise from true North seen from above), y completing the
right-handed frame (so y points at heading - 90 deg). In that frame the Earth
rate is

    w_ie = Omega [cos(lat) cos(hdg), cos(lat) sin(hdg), sin(lat)]

which a FOG/RLG-grade gyro sees (Omega = 15.04 deg/h) and a MEMS gyro does not.
"""

from __future__ import annotations

import math

import numpy as np

from calib_core.calibration import Calibration
from calib_core.distributions import norm_sf
from calib_core.earth import EARTH_RATE
from calib_core.noise import NOISE_TERMS, allan_deviation, archived_terms, choose_noise_fit
from calib_core.params import AXES
from calib_core.preprocess.replaced import replaced_check
from calib_core.recording import Recording
from calib_core.units import STANDARD_GRAVITY

MIN_DURATION_S = 3600.0  # docs/methods.md 2.5: >= 60 min static
BIAS_UNCERTAINTY_RULE = (
    "u(bias) = Allan deviation of the fitted noise model N^2/tau + (0.664 B)^2 + K^2 tau/3 "
    "at tau = record length: exact for white noise (= std/sqrt(n)) and for rate random "
    "walk (std of the record mean about the starting bias)"
)


def earth_rate_level_frame(latitude_deg: float, heading_deg: float) -> np.ndarray:
    """Earth rate seen by a level z-up fixture (frame in the module docstring), rad/s, (3,)."""
    lat, hdg = math.radians(latitude_deg), math.radians(heading_deg)
    return EARTH_RATE * np.array(
        [math.cos(lat) * math.cos(hdg), math.cos(lat) * math.sin(hdg), math.sin(lat)]
    )


def sigma_clip(x: np.ndarray, n_sigma: float = 3.0) -> np.ndarray:
    """Keep-mask of the n-sigma rule (one pass, per channel).

    Parameters
    ----------
    x : (N, C) samples.
    n_sigma : samples further than n_sigma * std from the channel mean are outliers.

    Returns
    -------
    (N, C) bool, True = kept. One pass because iterating the rule on Gaussian
    data keeps trimming good samples (each pass shrinks the std by ~1.3 %).
    """
    mean, std = x.mean(axis=0), x.std(axis=0)
    return np.abs(x - mean) <= n_sigma * std


def _fill(x: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Replace rejected samples by linear interpolation of their kept neighbours (per channel),
    so the Allan deviation sees a contiguous record."""
    out = x.copy()
    idx = np.arange(x.shape[0])
    for c in range(x.shape[1]):
        bad = ~keep[:, c]
        if bad.any():
            out[bad, c] = np.interp(idx[bad], idx[~bad], x[~bad, c])
    return out


def _up_vector(up_axis: str) -> np.ndarray:
    if len(up_axis) != 2 or up_axis[0] not in "+-" or up_axis[1] not in AXES:
        raise ValueError(f"up_axis must be one of +x, -x, +y, -y, +z, -z, got {up_axis!r}")
    e = np.zeros(3)
    e[AXES.index(up_axis[1])] = 1.0 if up_axis[0] == "+" else -1.0
    return e


def _kept_stats(x: np.ndarray, rate_hz: float, n_sigma: float, taus) -> tuple:
    """mean, std, outlier counts, Allan result of (N, 3) samples: the outlier rule's kept
    samples' mean and std, the Allan deviation of the record with its rejected samples
    interpolated over."""
    keep = sigma_clip(x, n_sigma)
    counts = (~keep).sum(axis=0)
    mean = np.array([x[keep[:, c], c].mean() for c in range(3)])
    std = np.array([x[keep[:, c], c].std(ddof=1) for c in range(3)])
    return mean, std, counts, allan_deviation(_fill(x, keep), rate_hz, taus)


def sensor_statistics(x: np.ndarray, rate_hz: float, n_sigma: float, taus) -> tuple:
    """mean, std, outlier counts, Allan result, noise parameters, u(mean), fit misfits and
    warnings (None or text, per channel) of (N, 3) samples (`choose_noise_fit`)."""
    mean, std, counts, allan = _kept_stats(x, rate_hz, n_sigma, taus)
    return (mean, std, counts, allan, *_noise_stats(allan, std, x.shape[0], rate_hz))


def _noise_stats(allan, std: np.ndarray, n: int, rate_hz: float) -> tuple:
    """noise parameters, u(mean), fit misfits and warnings (None or text, per channel) of
    one sensor's Allan result (`choose_noise_fit`)."""
    duration = n / rate_hz
    chosen = [choose_noise_fit(allan.column(c)) for c in range(3)]
    noise = [c[0] for c in chosen]
    misfits = [c[1] for c in chosen]
    warnings = [c[2] for c in chosen]
    sem_white = std / math.sqrt(n)
    u = np.array([float(p.adev_model(duration)) for p in noise])
    # A fit that found no noise at all (constant data) still has the white-noise floor.
    u = np.where(np.isfinite(u) & (u > 0), u, sem_white)
    return noise, u, misfits, warnings


def earth_rate_removed(
    where: str,
    n: int,
    n_sigma: float,
    remove_earth_rate: bool,
    latitude_deg: float | None,
    heading_deg: float | None,
    up_axis: str | None,
) -> np.ndarray:
    """Check the settings; the Earth rate to remove from the gyro means, rad/s (zeros if not)."""
    if n < 16:
        raise ValueError(f"static bias ({where}): need >= 16 samples, got {n}")
    if n_sigma <= 0:
        raise ValueError(f"static bias: n_sigma must be > 0, got {n_sigma}")
    earth = np.zeros(3)
    if remove_earth_rate:
        if latitude_deg is None or heading_deg is None:
            raise ValueError(
                f"static bias ({where}): remove_earth_rate needs latitude_deg and heading_deg, "
                f"got latitude_deg={latitude_deg!r}, heading_deg={heading_deg!r}"
            )
        if up_axis not in (None, "+z"):
            raise ValueError(
                f"static bias ({where}): the Earth-rate correction is defined for the level "
                f"z-up fixture, got up_axis={up_axis!r}"
            )
        earth = earth_rate_level_frame(latitude_deg, heading_deg)
    return earth


def solve_static_bias(
    rec: Recording,
    *,
    latitude_deg: float | None = None,
    heading_deg: float | None = None,
    remove_earth_rate: bool = False,
    n_sigma: float = 3.0,
    up_axis: str | None = None,
    gravity: float = STANDARD_GRAVITY,
    taus: str | np.ndarray = "octave",
) -> Calibration:
    """Gyro bias and noise (and accelerometer bias if the orientation is known).

    Parameters
    ----------
    rec : one static Recording, ideally >= 60 min (a warning is added if shorter).
    latitude_deg, heading_deg : site latitude and fixture heading (module docstring
        frame), degrees; needed when `remove_earth_rate`.
    remove_earth_rate : subtract the Earth-rate projection from the gyro means
        (FOG/RLG-grade units); only for the level z-up fixture.
    n_sigma : outlier rule; rejected samples are left out of mean and std and
        interpolated over for the Allan deviation.
    up_axis : body axis pointing up ("+z", "-x", ...); if given, acc.bias.* is the
        mean minus gravity along that axis.
    gravity : local gravity, m/s^2.
    taus : cluster times of the Allan deviation ("octave", "log" or seconds).

    Returns
    -------
    Calibration "static_bias" with gyr.bias.* and gyr.noise.* (std of one sample,
    rad/s), acc.noise.* (m/s^2), acc.bias.* when `up_axis` is given. Bias
    uncertainties follow BIAS_UNCERTAINTY_RULE (white-noise std/sqrt(n) would be
    far too small under bias instability and random walk). `info` holds the Allan
    deviations (lists), the noise parameters of every channel, outlier counts and
    the Earth rate removed.
    """
    where = rec.source or rec.label or "recording"
    earth = earth_rate_removed(
        where, len(rec), n_sigma, remove_earth_rate, latitude_deg, heading_deg, up_axis
    )
    rate_hz = rec.sample_rate
    stats = {
        sensor: _kept_stats(np.asarray(x, dtype=float), rate_hz, n_sigma, taus)
        for sensor, x in (("gyr", rec.gyr), ("acc", rec.acc))
    }
    return static_bias_calibration(
        stats,
        len(rec),
        rate_hz,
        rec.label or "record",
        earth,
        n_sigma=n_sigma,
        latitude_deg=latitude_deg,
        heading_deg=heading_deg,
        up_axis=up_axis,
        gravity=gravity,
    )


def static_bias_calibration(
    stats: dict[str, tuple],
    n: int,
    rate_hz: float,
    label: str,
    earth: np.ndarray,
    *,
    n_sigma: float,
    latitude_deg: float | None,
    heading_deg: float | None,
    up_axis: str | None,
    gravity: float,
) -> Calibration:
    """The static-bias Calibration from each sensor's statistics, however they were computed
    (one array: `solve_static_bias`; a stream: `calib_core.solvers.static_bias_stream`).

    stats : {"gyr": ..., "acc": ...}, each (mean (3,), std (3,) ddof 1, outlier counts (3,),
        AllanResult (K, 3)) of the kept samples (the n-sigma rule).
    n : samples; rate_hz : median sample rate, Hz; label : the record's label;
    earth : Earth rate removed from the gyro means, rad/s (3,).
    """
    cal = Calibration(procedure="static_bias", gravity=float(gravity))
    duration = n / rate_hz  # samples x period (t[-1] - t[0] is one period short)
    if duration < MIN_DURATION_S - 0.5 / rate_hz:  # half a sample of rounding slack
        cal.warnings.append(
            f"static record is {duration / 60:.1f} min long; the procedure asks for >= 60 min"
        )
    info: dict = {
        "n_samples": n,
        "duration_s": duration,
        "sample_rate_hz": rate_hz,
        "n_sigma": n_sigma,
        "bias_uncertainty_rule": BIAS_UNCERTAINTY_RULE,
        "earth_rate_removed": earth.tolist(),
        "latitude_deg": latitude_deg,
        "heading_deg": heading_deg,
        "allan": {},
        "noise_parameters": {},
        "outliers": {},
    }
    checks: list[dict] = []
    references = {"gyr": earth, "acc": None if up_axis is None else gravity * _up_vector(up_axis)}
    for sensor, reference in references.items():
        mean, std, counts, allan = stats[sensor]
        noise, u, misfits, warns = _noise_stats(allan, std, n, rate_hz)
        cal.warnings += [f"{sensor}.{a}: {w}" for a, w in zip(AXES, warns, strict=True) if w]
        worst = [m["misfit_max"] for m in misfits if m["misfit_max"] is not None]
        # A scalar: it goes into the solve step's record (statistics).
        info[f"{sensor}_noise_fit_misfit_max"] = max(worst) if worst else None
        for i, a in enumerate(AXES):
            cal.add(f"{sensor}.noise.{a}", std[i])
            if reference is not None:
                cal.add(f"{sensor}.bias.{a}", mean[i] - reference[i], u[i])
        info["allan"][sensor] = allan.to_dict()
        # A stuck channel's Allan deviation is the rounding of its constant value.
        varies = std > 64 * np.finfo(float).eps * np.abs(mean)
        terms = [
            archived_terms(p, allan.column(c), warns[c] is None, bool(varies[c]))
            for c, p in enumerate(noise)
        ]
        info["noise_parameters"][sensor] = [
            {**p.to_dict(), **m, **t} for p, m, t in zip(noise, misfits, terms, strict=True)
        ]
        checks += _undetermined_checks(sensor, terms)
        info["outliers"][sensor] = counts.tolist()
        if counts.max() > 0.01 * n:
            cal.warnings.append(
                f"{sensor}: {counts.max()} samples ({100 * counts.max() / n:.1f} %) outside "
                f"{n_sigma} sigma in one channel; expected ~0.3 % for Gaussian noise"
            )
    cal.info.update(info)
    clipped = {
        f"{sensor}.{a}": int(n)
        for sensor, counts in info["outliers"].items()
        for a, n in zip(AXES, counts, strict=True)
    }
    checks.append(
        replaced_check(
            "static_bias", label, clipped, 6 * n, 2.0 * float(norm_sf(n_sigma)), "left out"
        )
    )
    cal.info.setdefault("replaced_samples", {})["static_bias"] = clipped
    cal.info.setdefault("solver_checks", []).extend(checks)
    return cal


def _undetermined_checks(sensor: str, terms: list[dict]) -> list[dict]:
    """A ``model:noise:<sensor>.<axis>`` check for each channel with a noise term the
    record does not determine (archived as None, never as 0)."""
    out = []
    for a, t in zip(AXES, terms, strict=True):
        missing = [k for k in NOISE_TERMS if t[k] is None]
        if missing:
            out.append(
                {
                    "name": f"model:noise:{sensor}.{a}",
                    "value": None,
                    "limit": None,
                    "passed": False,
                    "detail": "; ".join(f"{k}: {t[f'{k}_method']}" for k in missing),
                }
            )
    return out
