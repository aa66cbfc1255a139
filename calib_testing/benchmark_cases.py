"""Ground-truth benchmark, the simulated cases: a case of the set (benchmark_set.json) as a
design with known truth, its noisy replicates and its noise-free model.

Support code, never installed: the simulator (`calib_core.simulate`) is test and benchmark
equipment, not part of the product. The product's scoring (`pipelines.validation.benchmark`)
takes `design` as an argument, found at run time by `calib validate --benchmark` through the
entry point group imu_calib.benchmark_cases (pyproject.toml) or `--cases`.

A `Design` holds the truth (theta: every parameter the data depend on, canonical names,
SI), how to draw one replicate (segments as the procedure takes them, noisy, with spikes
when the case asks) and the noise-free model of the same design with each channel's noise
std (`calib_core.crlb.Model`). The data a procedure discards by its own settings (a rate
table's settle time) are left out of the model: the bound is for what the procedure
measures.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from calib_core import params
from calib_core.crlb import Segment
from calib_core.recording import Recording
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.simulate.attitudes import multi_position_run, scheme_angles
from calib_core.simulate.lab_run import TrueErrors, rotation_profile
from calib_core.simulate.noise import NoiseSpec, simulate_static
from calib_core.simulate.rate_table import GyroTruth, simulate_rate_table
from calib_core.simulate.thermal import set_parameters
from calib_core.solvers.six_position import axis_vector
from calib_core.units import DEG, STANDARD_GRAVITY

Segments = dict[str, Recording]


@dataclass(frozen=True)
class Design:
    """One case: truth, replicate draw, noise-free model.

    theta : name -> true value (SI), every parameter the data depend on.
    draw : (theta, rng) -> the noisy segments of one replicate.
    model : theta -> [(clean (N, C), noise std (C,)), ...] (`calib_core.crlb.Model`).
    settings : the run's settings the procedure is solved with.
    gravity : local gravity of the simulation, m/s^2.
    steps : name -> finite-difference step of the Jacobian (SI).
    noise : name -> true noise std per sample (SI): scored against the truth, not the
        bound (a variance parameter, outside the model's mean).
    """

    theta: dict[str, float]
    draw: Callable[[Mapping[str, float], np.random.Generator], Segments]
    model: Callable[[Mapping[str, float]], list[Segment]]
    settings: dict[str, Any]
    gravity: float
    steps: dict[str, float]
    noise: dict[str, float] = field(default_factory=dict)


def _noise(truth: TrueErrors) -> dict[str, float]:
    return {n: v for n, v in truth.parameters().items() if ".noise." in n}


def _location(truth: TrueErrors) -> dict[str, float]:
    """The error model's parameters (noise stds excluded: they are not in the mean)."""
    return {n: v for n, v in truth.parameters().items() if ".noise." not in n}


def _clean(segments: Segments, sigma: np.ndarray) -> list[Segment]:
    return [(np.hstack([r.acc, r.gyr]), sigma, None) for r in segments.values()]


def _turn_profiles(segments: Segments, truth: TrueErrors, opts: Mapping[str, Any]) -> list[Segment]:
    """The clean segments, each turn with its rate profile as nuisance: the gyro's response
    (I + M_g) up to a rate about the turning axis at each moving sample, the profile
    unknown to the procedure but for its total angle (whole turns). A turn's accelerometer
    channels carry no information in the procedures' model (the specific force of a turning
    unit off the axis is unknown: lever arm), so they are left out of the bound."""
    rate_hz = float(opts.get("rate_hz", 50.0))
    _, rate = rotation_profile(
        rate_hz,
        int(opts.get("turns", 1)),
        float(opts.get("rotation_rate_dps", 90.0)) * DEG,
        float(opts.get("pause_s", 2.0)),
    )
    sigma = np.concatenate([truth.acc_noise, truth.gyr_noise])
    turning = np.concatenate([np.full(3, np.inf), truth.gyr_noise])
    out: list[Segment] = []
    for label, rec in segments.items():
        nuisance, noise = None, sigma
        if not label.endswith(("_up", "_dn")):
            noise = turning
            response = (np.eye(3) + truth.gyr_M) @ axis_vector(label, 1.0)
            nuisance = np.zeros((rec.t.size, 6))
            nuisance[rate[: rec.t.size] > 0, 3:] = response
        out.append((np.hstack([rec.acc, rec.gyr]), noise, nuisance))
    return out


def _pick(segments: Segments, which: str) -> Segments:
    statics = {k: v for k, v in segments.items() if k.endswith(("_up", "_dn"))}
    if which == "static":
        return statics
    if which == "rotation":
        return {k: v for k, v in segments.items() if k not in statics}
    return segments


def _truth(spec: Mapping[str, Any]) -> TrueErrors:
    """A unit's true errors: drawn from its grade by its own seed, noise set if given."""
    truth = random_errors(np.random.default_rng(int(spec["seed"])), spec.get("grade", "mems"))
    if "acc_noise" in spec:
        truth = replace(truth, acc_noise=np.full(3, float(spec["acc_noise"])))
    if "gyr_noise_dps" in spec:
        truth = replace(truth, gyr_noise=np.full(3, float(spec["gyr_noise_dps"]) * DEG))
    return truth


def lab_run_design(case: Mapping[str, Any]) -> Design:
    """Six positions and turns (`six_position_integral_run`); `segments` picks the statics,
    the rotations or all of them."""
    truth = _truth(case["truth"])
    opts = dict(case.get("simulation", {}))
    which = case.get("segments", "all")
    quiet = replace(truth, acc_noise=np.zeros(3), gyr_noise=np.zeros(3))
    clean_opts = {**opts, "spike_fraction": 0.0}

    def draw(theta: Mapping[str, float], rng: np.random.Generator) -> Segments:
        sim = six_position_integral_run(set_parameters(truth, theta), rng, **opts)
        return _pick(sim.segments, which)

    def model(theta: Mapping[str, float]) -> list[Segment]:
        rng = np.random.default_rng(0)
        sim = six_position_integral_run(set_parameters(quiet, theta), rng, **clean_opts)
        return _turn_profiles(_pick(sim.segments, which), truth, opts)

    settings = dict(case.get("settings", {}))
    return Design(_location(truth), draw, model, settings, STANDARD_GRAVITY, {}, _noise(truth))


def multi_position_design(case: Mapping[str, Any]) -> Design:
    """Static records at the table attitudes of an n-position scheme (`scheme_angles`)."""
    truth = _truth(case["truth"])
    opts = dict(case.get("simulation", {}))
    angles = scheme_angles(int(opts.pop("positions")))
    sigma = np.concatenate([truth.acc_noise, truth.gyr_noise])
    quiet = replace(truth, acc_noise=np.zeros(3), gyr_noise=np.zeros(3))
    run = multi_position_run(truth, angles, np.random.default_rng(0), **opts)
    settings = {**case.get("settings", {}), "attitudes": run.attitudes_setting()}

    def draw(theta: Mapping[str, float], rng: np.random.Generator) -> Segments:
        return multi_position_run(set_parameters(truth, theta), angles, rng, **opts).segments

    def model(theta: Mapping[str, float]) -> list[Segment]:
        rng = np.random.default_rng(0)
        sim = multi_position_run(set_parameters(quiet, theta), angles, rng, **opts)
        return _clean(sim.segments, sigma)

    return Design(_location(truth), draw, model, settings, STANDARD_GRAVITY, {}, _noise(truth))


def _gyro_truth(theta: Mapping[str, float]) -> GyroTruth:
    bias = np.array([theta[params.bias("gyr", a)] for a in params.AXES])
    names = params.matrix_names("gyr")
    M = np.array([[theta[n] for n in row] for row in names])  # noqa: N806
    return GyroTruth(bias=bias, M=M)


def rate_table_design(case: Mapping[str, Any]) -> Design:
    """Rate plateaus about each axis (`simulate_rate_table`), the gyro's bias, scale and
    misalignment as truth; the model keeps each plateau after its settle time."""
    spec = case["truth"]
    rng = np.random.default_rng(int(spec["seed"]))
    theta = {params.bias("gyr", a): float(rng.uniform(-2e-3, 2e-3)) for a in params.AXES}
    for row in params.matrix_names("gyr"):
        for n in row:
            theta[n] = float(rng.uniform(-3e-3, 3e-3))
    opts = dict(case.get("simulation", {}))
    density = float(opts.pop("gyro_noise_density"))
    rates = tuple(r * DEG for r in opts.pop("rates_dps", (-100.0, -50.0, 0.0, 50.0, 100.0)))
    settle = float(opts.get("settle_s", 20.0))
    sigma = np.full(3, density * math.sqrt(float(opts["rate_hz"])))

    def draw(th: Mapping[str, float], rng: np.random.Generator) -> Segments:
        run = simulate_rate_table(
            _gyro_truth(th), rates=rates, gyro_noise_density=density, rng=rng, **opts
        )
        return {r.label: r for r in run.recordings}

    def model(th: Mapping[str, float]) -> list[Segment]:
        run = simulate_rate_table(
            _gyro_truth(th), rates=rates, rng=np.random.default_rng(0), **opts
        )
        return [(r.gyr[r.t - r.t[0] >= settle], sigma, None) for r in run.recordings]

    settings = {"settle_s": settle, **case.get("settings", {})}
    return Design(theta, draw, model, settings, STANDARD_GRAVITY, {})


def static_bias_design(case: Mapping[str, Any]) -> Design:
    """One long static record with white gyro noise (`simulate_static`): the gyro biases."""
    spec = case["truth"]
    rng = np.random.default_rng(int(spec["seed"]))
    theta = {params.bias("gyr", a): float(rng.uniform(-1e-2, 1e-2)) for a in params.AXES}
    opts = dict(case.get("simulation", {}))
    arw = float(opts.pop("gyro_arw"))
    acc_arw = float(opts.pop("acc_arw"))
    sigma = np.full(3, arw * math.sqrt(float(opts["rate_hz"])))

    def bias(th: Mapping[str, float]) -> np.ndarray:
        return np.array([th[params.bias("gyr", a)] for a in params.AXES])

    def draw(th: Mapping[str, float], rng: np.random.Generator) -> Segments:
        rec = simulate_static(
            gyro_bias=bias(th),
            gyro_noise=NoiseSpec(arw=arw),
            acc_noise=NoiseSpec(arw=acc_arw),
            rng=rng,
            **opts,
        )
        return {"static": rec}

    def model(th: Mapping[str, float]) -> list[Segment]:
        rec = simulate_static(
            gyro_bias=bias(th), gyro_noise=NoiseSpec(), rng=np.random.default_rng(0), **opts
        )
        return [(rec.gyr, sigma, None)]

    noise = {f"gyr.noise.{a}": float(sigma[0]) for a in params.AXES}
    noise |= {f"acc.noise.{a}": acc_arw * math.sqrt(float(opts["rate_hz"])) for a in params.AXES}
    settings = dict(case.get("settings", {}))
    return Design(theta, draw, model, settings, STANDARD_GRAVITY, {}, noise)


SIMULATORS: dict[str, Callable[[Mapping[str, Any]], Design]] = {
    "lab_run": lab_run_design,
    "multi_position": multi_position_design,
    "rate_table": rate_table_design,
    "static": static_bias_design,
}


def design(case: Mapping[str, Any]) -> Design:
    """The design of one case of the set; ValueError naming an unknown simulator."""
    try:
        build = SIMULATORS[case["simulator"]]
    except KeyError:
        raise ValueError(
            f"benchmark case {case.get('id')!r}: unknown simulator {case.get('simulator')!r};"
            f" expected one of {sorted(SIMULATORS)}"
        ) from None
    d = build(case)
    steps = {n: 1e-6 for n in d.theta}  # linear models: any step; 1e-6 of the SI unit
    return replace(d, steps=steps)
