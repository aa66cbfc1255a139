"""Noise models for navigation filters, the export files: Kalibr's imu.yaml and OpenVINS's
kalibr_imu_chain.yaml from a static-bias (Allan) run (docs/exports.md, section "Noise
models for Kalibr and OpenVINS"). The numbers come from `calib_core.nav_noise`; this
module writes them with the conversion and their uncertainty as comments.
"""

from __future__ import annotations

import math

import numpy as np

from calib_core.nav_noise import BOOTSTRAP_RECORDS, NavNoise, NavTerm

DEFAULT_ROSTOPIC = "/imu0"

_KEYS = (
    ("accelerometer_noise_density", "acc_noise_density"),
    ("accelerometer_random_walk", "acc_random_walk"),
    ("gyroscope_noise_density", "gyr_noise_density"),
    ("gyroscope_random_walk", "gyr_random_walk"),
)
_IDENTITY = ("    - [1.0, 0.0, 0.0]", "    - [0.0, 1.0, 0.0]", "    - [0.0, 0.0, 1.0]")
_ZERO = ("    - [0.0, 0.0, 0.0]",) * 3


def _num(x: float) -> str:
    """A float YAML 1.1 and OpenCV both read as a float (a dot in the mantissa)."""
    return f"{x:.6e}"


def _rate(hz: float) -> str:
    """An update rate to 6 digits, always with a dot (a rate measured from time stamps
    carries float noise: 50.000000000045)."""
    return repr(float(f"{hz:.6g}"))


def _term_lines(key: str, term: NavTerm) -> list[str]:
    axes = ", ".join(
        f"{a} {_num(v)} +- {u:.2g}" for a, v, u in zip("xyz", term.values, term.stds, strict=True)
    )
    if term.value > 0:
        first = (
            f"  {key} [{term.unit}] = {_num(term.value)} (axis {'xyz'[term.axis]}), "
            f"u = {term.std:.2g} ({100 * term.std / term.value:.2g} %), "
            f"estimator bias {term.biases[term.axis]:+.2g}"
        )
    else:
        first = f"  {key} [{term.unit}] = 0: no such term in the Allan deviation"
    return [first, f"    per axis: {axes}"]


def comment_lines(nav: NavNoise, update_rate_hz: float, header: str) -> list[str]:
    """The explanatory comment block (without '# '): source, conversion, uncertainty, advice."""
    dt = 1.0 / update_rate_hz
    disc = nav.discrete(update_rate_hz)
    lines = header.splitlines() + [
        f"Static-bias (Allan) record: {nav.duration_s:g} s at {nav.sample_rate_hz:g} Hz.",
        "Noise fits: " + (", ".join(f"{k} {v}" for k, v in nav.methods.items()) or "-") + ".",
        "Continuous time, Kalibr's units: noise density = the Allan white-noise term N",
        "(avar = N^2/tau), random walk = the Allan rate random walk K (avar = K^2 tau/3):",
        "the same quantities, no factor.",
        "Kalibr models every axis alike: each value is the largest of the three axes.",
        f"Discrete time at update_rate {update_rate_hz:g} Hz (dt = {dt:g} s; Kalibr and",
        "OpenVINS convert themselves):",
        f"  noise sigma/sqrt(dt): acc {_num(disc['accelerometer_noise'])} m/s^2, gyro "
        f"{_num(disc['gyroscope_noise'])} rad/s;",
        f"  bias step sigma_b*sqrt(dt): acc {_num(disc['accelerometer_bias_step'])} m/s^2, "
        f"gyro {_num(disc['gyroscope_bias_step'])} rad/s.",
        "  (sigma/sqrt(dt) assumes the sensor's filter cut the noise above f/2; a topic",
        "  that only subsamples the sensor keeps the sensor's density.)",
        f"Standard uncertainties (k = 1): parametric bootstrap of the Allan fit "
        f"({BOOTSTRAP_RECORDS} records per axis),",
        "the estimator's bias (fitted minus generating) added in quadrature, not subtracted:",
    ]
    lines += [ln for key, attr in _KEYS for ln in _term_lines(key, getattr(nav, attr))]
    lines += [
        "Bias instability (flicker) has no term in this model and is not exported.",
        "Not inflated: values from a static bench record are a lower bound for a moving",
        "platform (vibration, temperature, unmodelled scale and misalignment). Kalibr's IMU",
        "noise model page and the Kalibr / OpenVINS / allan_variance_ros discussions advise",
        "inflating them for real data; choose the factor yourself and record it.",
    ]
    return lines


def _values(nav: NavNoise, indent: str) -> list[str]:
    return [f"{indent}{key}: {_num(getattr(nav, attr).value)}" for key, attr in _KEYS]


def _check(nav: NavNoise, update_rate_hz: float, rostopic: str) -> None:
    if not (math.isfinite(update_rate_hz) and update_rate_hz > 0):
        raise ValueError(f"update rate must be a positive number of Hz, got {update_rate_hz!r}")
    if not rostopic.startswith("/") or any(c.isspace() or c in "#:'\"" for c in rostopic):
        raise ValueError(
            f"rostopic must be a ROS topic name starting with '/' (no spaces, '#', ':' or "
            f"quotes), got {rostopic!r}"
        )
    terms = [getattr(nav, attr) for _, attr in _KEYS]
    if not all(np.isfinite(t.values).all() for t in terms):
        raise ValueError("the run's noise parameters are not finite numbers")


def kalibr_yaml(
    nav: NavNoise, *, update_rate_hz: float, rostopic: str = DEFAULT_ROSTOPIC, header: str = ""
) -> str:
    """Kalibr's imu.yaml: the four noise values, rostopic and update_rate, with comments."""
    _check(nav, update_rate_hz, rostopic)
    body = [f"# {ln}".rstrip() for ln in comment_lines(nav, update_rate_hz, header)]
    body += ["", *_values(nav, ""), f"rostopic: {rostopic}"]
    body.append(f"update_rate: {_rate(update_rate_hz)}")
    return "\n".join(body) + "\n"


def openvins_yaml(
    nav: NavNoise, *, update_rate_hz: float, rostopic: str = DEFAULT_ROSTOPIC, header: str = ""
) -> str:
    """OpenVINS's kalibr_imu_chain.yaml (imu0): the noise values, identity intrinsics.

    OpenVINS reads it with OpenCV's FileStorage: the first line is ``%YAML:1.0`` and
    comments stand on their own lines (an inline comment after a value can break it).
    """
    _check(nav, update_rate_hz, rostopic)
    lines = [
        "%YAML:1.0",
        *[f"# {ln}".rstrip() for ln in comment_lines(nav, update_rate_hz, header)],
    ]
    lines += [
        "# IMU intrinsics: identity / zero. A static record does not measure scale,",
        "# misalignment or g-sensitivity; OpenVINS requires the five matrices: keep",
        "# calib_imu_intrinsics and calib_imu_g_sensitivity off, or fill them in.",
        "",
        "imu0:",
        "  T_i_b:",
        "    - [1.0, 0.0, 0.0, 0.0]",
        "    - [0.0, 1.0, 0.0, 0.0]",
        "    - [0.0, 0.0, 1.0, 0.0]",
        "    - [0.0, 0.0, 0.0, 1.0]",
        *_values(nav, "  "),
        f"  rostopic: {rostopic}",
        "  time_offset: 0.0",
        f"  update_rate: {_rate(update_rate_hz)}",
        '  model: "kalibr"',
        "  Tw:",
        *_IDENTITY,
        "  R_IMUtoGYRO:",
        *_IDENTITY,
        "  Ta:",
        *_IDENTITY,
        "  R_IMUtoACC:",
        *_IDENTITY,
        "  Tg:",
        *_ZERO,
    ]
    return "\n".join(lines) + "\n"
