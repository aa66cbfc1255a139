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
from calib_core.simulate.array import array_run
from calib_core.simulate.attitudes import multi_position_run, scheme_angles
from calib_core.simulate.handheld import accelerometer_frame, handheld_run
from calib_core.simulate.lab_run import TrueErrors, Turns, rotation_profile
from calib_core.simulate.noise import NoiseSpec, simulate_static
from calib_core.simulate.rate_table import GyroTruth, simulate_rate_table
from calib_core.simulate.thermal import set_parameters
from calib_core.solvers.equipment_free import ACC_MISALIGN
from calib_core.solvers.equipment_free import SETTINGS as EQUIPMENT_FREE
from calib_core.solvers.sensor_array import cube_mounts
from calib_core.solvers.six_position import axis_vector
from calib_core.units import DEG, STANDARD_GRAVITY

Segments = dict[str, Recording]


@dataclass(frozen=True)
class Design:
    """One case: truth, replicate draw, noise-free model.

    theta : name -> true value (SI), every parameter the data depend on.
    draw : (theta, rng) -> the noisy segments of one replicate.
    model : theta -> [(clean (N, C), noise std (C,)), ...] (`calib_core.crlb.Model`); None
        where the bound is not derived (the case's docstring says why).
    settings : the run's settings the procedure is solved with.
    gravity : local gravity of the simulation, m/s^2.
    steps : name -> finite-difference step of the Jacobian (SI).
    noise : name -> true noise std per sample (SI): scored against the truth, not the
        bound (a variance parameter, outside the model's mean).
    bounded : the model's parameters and their true values where they are not theta: the
        design's nuisances added (a pose's unknown attitude), or the parameters the bound
        is derived for alone; None: theta.
    linear : the model is linear in `bounded` (one-sided differences suffice).
    condition : what the case stresses beyond the procedure's model (a drift of the truth
        within the run), or None; such a case is judged by its coverage, not its efficiency.
    """

    theta: dict[str, float]
    draw: Callable[[Mapping[str, float], np.random.Generator], Segments]
    model: Callable[[Mapping[str, float]], list[Segment]] | None
    settings: dict[str, Any]
    gravity: float
    steps: dict[str, float]
    noise: dict[str, float] = field(default_factory=dict)
    bounded: dict[str, float] | None = None
    linear: bool = True
    condition: str | None = None


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
    # the continuous-time terms the peers' rows name: white noise only, no random walk
    for sensor, density in (("gyr", arw), ("acc", acc_arw)):
        noise |= {f"{sensor}.noise_density.{a}": density for a in params.AXES}
        noise |= {f"{sensor}.random_walk.{a}": 0.0 for a in params.AXES}
    settings = dict(case.get("settings", {}))
    return Design(theta, draw, model, settings, STANDARD_GRAVITY, {}, noise)


def _quiet(truth: TrueErrors) -> TrueErrors:
    return replace(truth, acc_noise=np.zeros(3), gyr_noise=np.zeros(3))


def _tangent(u: np.ndarray) -> np.ndarray:
    """(2, 3) an orthonormal basis of the plane normal to the unit vector u."""
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return np.array([e1, np.cross(u, e1)])


def handheld_design(case: Mapping[str, Any]) -> Design:
    """A hand-held session (`handheld_run`): its poses drawn once from the case's seed, the
    noise per replicate. The truth in the solver's frame (`accelerometer_frame`).

    The bound is derived for the accelerometer's nine terms, from the rests (less the
    settle time the procedure drops at each end, as a rate table's settle), each rest's
    gravity direction a free nuisance (two angles): the attitudes of a hand are unknown. The
    gyro's terms have none here: their information lies in the rotations between rests
    through a rate profile the hand leaves unknown in three axes (the nuisance of
    `calib_core.crlb` is one known direction per sample), so they are scored by their
    error and coverage only.
    """
    truth = accelerometer_frame(_truth(case["truth"]))
    opts = dict(case.get("simulation", {}))
    layout = int(case["truth"]["seed"])
    quiet = _quiet(truth)
    run = handheld_run(quiet, np.random.default_rng(layout), **opts)
    rate_hz = float(opts.get("rate_hz", 100.0))
    settings = dict(case.get("settings", {}))
    dropped = 2.0 * EQUIPMENT_FREE.parse(settings).settle_s
    held = [float(opts.get("init_s", 20.0)) - dropped]
    held += [float(opts.get("hold_s", 4.0)) - dropped] * (len(run.attitudes) - 1)
    ups = run.attitudes[:, 2, :]  # each rest's gravity direction in the body frame

    def draw(theta: Mapping[str, float], rng: np.random.Generator) -> Segments:
        sim = handheld_run(set_parameters(quiet, theta), np.random.default_rng(layout), **opts)
        rec = sim.recording
        acc = rec.acc + rng.standard_normal(rec.acc.shape) * truth.acc_noise
        gyr = rec.gyr + rng.standard_normal(rec.gyr.shape) * truth.gyr_noise
        return {"session": Recording(rec.t, acc, gyr, label="session", source=rec.source)}

    acc_names = [params.bias("acc", a) for a in params.AXES]
    acc_names += [params.matrix_names("acc")[i][i] for i in range(3)]
    acc_names += [params.matrix_names("acc")[i][j] for i, j in ACC_MISALIGN]
    location = _location(truth)
    bounded = {n: location[n] for n in acc_names}
    bounded |= {f"rest{k}.{e}": 0.0 for k in range(len(ups)) for e in "ab"}

    def model(theta: Mapping[str, float]) -> list[Segment]:
        errors = set_parameters(quiet, {n: theta[n] for n in acc_names})
        out: list[Segment] = []
        for k, (u, seconds) in enumerate(zip(ups, held, strict=True)):
            turned = u + np.array([theta[f"rest{k}.a"], theta[f"rest{k}.b"]]) @ _tangent(u)
            mean = errors.acc_measured(run.gravity * turned[None, :] / np.linalg.norm(turned))
            out.append((mean, truth.acc_noise / math.sqrt(seconds * rate_hz), None))
        return out

    noise = _noise(truth)
    return Design(location, draw, model, settings, run.gravity, {}, noise, bounded, linear=False)


def sensor_array_design(case: Mapping[str, Any]) -> Design:
    """The six-IMU cube (`array_run`, `cube_mounts`): the static record and a turn each way
    about the vertical. The bound as for the turns of `lab_run_design`: each turn's rate
    profile a nuisance along (I + M_g) C_s e_z, its accelerometer channels left out."""
    truth = _truth(case["truth"])
    opts = dict(case.get("simulation", {}))
    turns = Turns(**opts.pop("turns", {}))
    mounts = cube_mounts()
    quiet = _quiet(truth)
    _, rate = turns.profile(float(opts.get("rate_hz", 100.0)))
    sigma = np.concatenate([truth.acc_noise, truth.gyr_noise])
    turning = np.concatenate([np.full(3, np.inf), truth.gyr_noise])

    def draw(theta: Mapping[str, float], rng: np.random.Generator) -> Segments:
        return array_run(set_parameters(truth, theta), mounts, rng, turns=turns, **opts).segments

    def model(theta: Mapping[str, float]) -> list[Segment]:
        errors = set_parameters(quiet, theta)
        sim = array_run(errors, mounts, np.random.default_rng(0), turns=turns, **opts)
        out: list[Segment] = []
        for label, rec in sim.segments.items():
            clean = np.hstack([rec.acc, rec.gyr])
            if label.endswith("_static"):
                out.append((clean, sigma, None))
                continue
            up = mounts[label.rsplit("_", 1)[0]] @ np.array([0.0, 0.0, 1.0])
            nuisance = np.zeros((rec.t.size, 6))
            nuisance[rate > 0, 3:] = (np.eye(3) + errors.gyr_M) @ up
            out.append((clean, turning, nuisance))
        return out

    settings = dict(case.get("settings", {}))
    return Design(_location(truth), draw, model, settings, STANDARD_GRAVITY, {}, _noise(truth))


def centrifuge_design(case: Mapping[str, Any]) -> Design:
    """A centrifuge run (`simulate_centrifuge`): zero records, the near-1 g run and the
    high-g steps at every mounting position; the truth is the case's error model (per axis
    {term: coefficient}, by canonical name), white noise only.

    The bound is an oracle bound: that of the true model's terms, though the procedure
    chooses each axis's terms per run by t tests. The model is every record as simulated
    (the table's start angles from one fixed draw), noise-free, white noise per sample;
    the geometry the procedure estimates from the same data is a free nuisance: the
    effective radius (one, as simulated), the horizontal misalignment of each position,
    the table's tilt and its azimuth. Each axis's 1 g scale (`acc.scale.i`) is given to the
    procedure (settings `scale_1g`: a centrifuge cannot separate it from the radius), so
    it is a known prior here, held at its truth, and not scored against the bound.
    """
    from calib_core.simulate.centrifuge import (
        CentrifugeNoise,
        CentrifugeSchedule,
        simulate_centrifuge,
    )
    from calib_core.solvers.centrifuge_model import canonical_name
    from calib_core.solvers.centrifuge_segments import step_label

    model = {a: dict(terms) for a, terms in case["truth"]["model"].items()}
    names = {canonical_name(a, t): (a, t) for a, terms in model.items() for t in terms}
    opts = dict(case.get("simulation", {}))
    schedule = CentrifugeSchedule(**opts.pop("schedule", {}))
    noise = CentrifugeNoise(**opts.pop("noise", {}))

    def draw(theta: Mapping[str, float], rng: np.random.Generator) -> Segments:
        true = {a: dict(terms) for a, terms in model.items()}
        for name, (a, t) in names.items():
            true[a][t] = theta[name]
        run = simulate_centrifuge(true, rng=rng, schedule=schedule, noise=noise, **opts)
        return {step_label(s): s.recording for s in run.steps}

    theta = {name: float(model[a][t]) for name, (a, t) in names.items()}
    settings = dict(case.get("settings", {}))
    geometry = simulate_centrifuge(
        model, rng=np.random.default_rng(0), schedule=schedule, noise=noise, **opts
    ).truth
    # the model below: white noise only, one radius
    if noise != CentrifugeNoise(noise=noise.noise) or len(set(geometry.radius.values())) > 1:
        return Design(theta, draw, None, settings, STANDARD_GRAVITY, {})
    given = {canonical_name(a, f"a_{a}") for a in settings.get("scale_1g", {})}
    bounded = {n: v for n, v in theta.items() if n not in given}
    bounded["radius"] = float(np.mean(list(geometry.radius.values())))
    bounded |= {f"phi_h.{m}": v for m, v in geometry.phi_h.items()}
    bounded |= {"tilt": geometry.tilt, "tilt_azimuth": geometry.tilt_azimuth}
    quiet = CentrifugeNoise(noise=0.0)
    sigma = np.full(3, noise.noise)
    fixed = {k: v for k, v in opts.items() if k not in ("radius", "phi_h", "tilt", "tilt_azimuth")}
    # the operator's rates stay those of the true radius when the model's radius moves
    fixed.setdefault("nominal_radius", bounded["radius"])

    def clean(th: Mapping[str, float]) -> list[Segment]:
        true = {a: dict(terms) for a, terms in model.items()}
        for name, (a, t) in names.items():
            true[a][t] = th.get(name, theta[name])
        run = simulate_centrifuge(
            true,
            rng=np.random.default_rng(0),
            schedule=schedule,
            noise=quiet,
            radius=th["radius"],
            phi_h={m: th[f"phi_h.{m}"] for m in geometry.phi_h},
            tilt=th["tilt"],
            tilt_azimuth=th["tilt_azimuth"],
            **fixed,
        )
        return [(s.recording.acc, sigma, None) for s in run.steps]

    return Design(theta, draw, clean, settings, STANDARD_GRAVITY, {}, {}, bounded, linear=False)


def drifting(design: Design, drift: Mapping[str, float]) -> Design:
    """The design with biases that drift linearly through the run (a warm-up): each named
    parameter (canonical name, SI) changes by the given amount from the first sample of
    the run to the last, the segments taken in their order, and the truth is its value at
    mid-run (the run's mean). The model, and so the bound, stays the design's: a drifting
    truth is judged by the coverage of the stated U."""
    for name in drift:
        sensor, kind, _ = params.validate(name).split(".")
        if kind != "bias":
            raise ValueError(f"drift: {name}: only biases drift in the simulated cases")

    def draw(theta: Mapping[str, float], rng: np.random.Generator) -> Segments:
        segments = design.draw(theta, rng)
        total = sum(r.t[-1] - r.t[0] for r in segments.values())
        out, start = {}, 0.0
        for label, rec in segments.items():
            frac = (start + rec.t - rec.t[0]) / total - 0.5
            acc, gyr = rec.acc.copy(), rec.gyr.copy()
            for name, amount in drift.items():
                sensor, _, axis = name.split(".")
                (acc if sensor == "acc" else gyr)[:, params.AXIS_INDEX[axis]] += amount * frac
            out[label] = replace(rec, acc=acc, gyr=gyr)
            start += rec.t[-1] - rec.t[0]
        return out

    what = ", ".join(f"{n} by {v:g}" for n, v in drift.items())
    return replace(design, draw=draw, condition=f"linear drift through the run: {what}")


SIMULATORS: dict[str, Callable[[Mapping[str, Any]], Design]] = {
    "lab_run": lab_run_design,
    "multi_position": multi_position_design,
    "rate_table": rate_table_design,
    "static": static_bias_design,
    "handheld": handheld_design,
    "array": sensor_array_design,
    "centrifuge": centrifuge_design,
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
    if "drift" in case:
        d = drifting(d, case["drift"])
    # linear models: any step; the attitudes' nuisance angles: second order, 1e-6 rad
    steps = {n: 1e-6 for n in (d.bounded if d.bounded is not None else d.theta)}
    return replace(d, steps=steps)
