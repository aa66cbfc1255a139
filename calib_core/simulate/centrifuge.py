"""Centrifuge procedure, the simulator: runs with a known high-g model (the test oracle).

The physics (frames and sign conventions as in `calib_core.solvers.centrifuge`):

- specific force towards the table axis R w (w + 2 Omega_V), w the signed
  table rate about up, Omega_V Earth rate's up component (Coriolis);
- the sensor sees it at the horizontal misalignment phi_h of its position;
- gravity's reaction g along up; a table-axis tilt tau puts g tau on the
  horizontal axes with the phase of the table angle, and Earth rate's
  horizontal component adds a Coriolis term 2 Omega_H w R on up with that
  phase too: both vanish over whole revolutions;
- outputs E_i = f_i + sum_term c_term * term(f) + per-run bias offset + noise.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from calib_core.earth import EARTH_RATE
from calib_core.params import AXES
from calib_core.recording import Recording
from calib_core.solvers.centrifuge_model import (
    MOUNTS,
    ZERO_POSITIONS_DEG,
    CentrifugeStep,
    term_values,
)
from calib_core.units import STANDARD_GRAVITY


@dataclass(frozen=True)
class CentrifugeTruth:
    """What the simulator used.

    model : per axis {term: coefficient}, error = output - input (``"const"`` = bias).
    radius, phi_h : per mounting position, m and rad.
    run_offset : (3,) bias offset of this run on top of ``const``, m/s^2.
    """

    model: dict[str, dict[str, float]]
    radius: dict[str, float]
    phi_h: dict[str, float]
    tilt: float
    tilt_azimuth: float
    omega_v: float
    omega_h: float
    gravity: float
    direction: int
    run_offset: np.ndarray

    def error(self, f: np.ndarray) -> np.ndarray:
        """(N, 3) inputs -> (N, 3) true model errors (without the run offset), m/s^2."""
        out = np.zeros(np.shape(np.atleast_2d(f)))
        for i, axis in enumerate(AXES):
            terms = self.model.get(axis, {})
            if terms:
                out[:, i] = term_values(f, list(terms)) @ np.array(list(terms.values()))
        return out


@dataclass(frozen=True)
class CentrifugeRun:
    steps: list[CentrifugeStep]
    truth: CentrifugeTruth


def _per_mount(value: float | Mapping[str, float], mounts: Sequence[str]) -> dict[str, float]:
    if isinstance(value, Mapping):
        missing = set(mounts) - set(value)
        if missing:
            raise ValueError(f"per-position value missing for {sorted(missing)}")
        return {m: float(value[m]) for m in mounts}
    return {m: float(value) for m in mounts}


@dataclass(frozen=True)
class CentrifugeNoise:
    """The random parts of the accelerometer's output, SI.

    noise : white noise per sample, m/s^2.
    run_offset_std : std of a bias offset drawn once per run and axis (turn-on
        repeatability), m/s^2.
    scale_instability : std of a relative gain error drawn per record and axis
        (in-run scale-factor instability, e.g. temperature); it grows with the
        input, so it dominates the high-g steps as in the paper's residuals.
    bias_instability : std of an offset drawn per record and axis, m/s^2.
    """

    noise: float = 0.05
    run_offset_std: float = 0.0
    scale_instability: float = 0.0
    bias_instability: float = 0.0


@dataclass(frozen=True)
class CentrifugeSchedule:
    """What the lab records at each mounting position, in this order.

    Zero output at table positions 0/90/180/270 deg (`zero_duration` s each), a
    near-1 g run (`one_g_duration` s), one record per high-g step in `g_steps`
    (g, `step_duration` s each) and, with `zero_after`, the zero output again at
    the same four positions; every record sampled at `sample_rate` Hz.
    """

    g_steps: tuple[float, ...] = tuple(range(2, 21, 2))
    sample_rate: float = 200.0
    zero_duration: float = 10.0
    one_g_duration: float = 60.0
    step_duration: float = 10.0
    zero_after: bool = False


DEFAULT_NOISE = CentrifugeNoise()
DEFAULT_SCHEDULE = CentrifugeSchedule()


def _record(
    truth: CentrifugeTruth,
    noise: CentrifugeNoise,
    sample_rate: float,
    rng: np.random.Generator,
    mount: str,
    rate: float,
    duration: float,
    angle0: float,
    drift: Sequence[float] = (0.0, 0.0, 0.0),
) -> Recording:
    """One record of `duration` s at table rate `rate` (rad/s) from table angle `angle0` (rad).

    Specific force at the mount: centripetal (with the Earth's vertical rate),
    the tilted table's gravity turning with the arm, and the Coriolis term of
    the horizontal Earth rate; then the error model, the run offset, a zero
    drift (m/s^2, for the records after a run) and noise.
    """
    n = int(round(duration * sample_rate))
    t = np.arange(n) / sample_rate
    angle = angle0 + rate * t
    radius, phi, g, tilt = truth.radius[mount], truth.phi_h[mount], truth.gravity, truth.tilt
    a = radius * rate * (rate + 2.0 * truth.omega_v)
    phase = angle - truth.tilt_azimuth  # tilt direction as seen from the rotating arm
    f_mount = np.column_stack(
        [
            a * math.cos(phi) + g * tilt * np.cos(phase),
            a * math.sin(phi) - g * tilt * np.sin(phase),
            np.full(n, g * math.cos(tilt)) + 2.0 * truth.omega_h * rate * radius * np.cos(angle),
        ]
    )
    f = f_mount @ MOUNTS[mount].T
    gain = rng.normal(0.0, noise.scale_instability, 3) if noise.scale_instability > 0 else 0.0
    offset = rng.normal(0.0, noise.bias_instability, 3) if noise.bias_instability > 0 else 0.0
    acc = (
        f * (1.0 + gain)
        + truth.error(f)
        + truth.run_offset
        + offset
        + np.asarray(drift, dtype=float)
        + rng.normal(0.0, noise.noise, f.shape)
    )
    return Recording(
        t=t,
        acc=acc,
        gyr=np.zeros_like(acc),
        reference={"table_angle": angle, "table_rate": np.full(n, rate)},
        source=f"simulated centrifuge {mount}",
    )


def simulate_centrifuge(
    model: Mapping[str, Mapping[str, float]],
    *,
    rng: np.random.Generator,
    mounts: Sequence[str] = tuple(MOUNTS),
    radius: float | Mapping[str, float] = 1.0,
    phi_h: float | Mapping[str, float] = 0.0,
    tilt: float = 1e-3,
    tilt_azimuth: float = 0.7,
    latitude_deg: float = 50.0,
    direction: int = 1,
    gravity: float = STANDARD_GRAVITY,
    noise: CentrifugeNoise = DEFAULT_NOISE,
    schedule: CentrifugeSchedule = DEFAULT_SCHEDULE,
    nominal_radius: float | None = None,
    zero_drift: Mapping[str, Sequence[float]] | None = None,
) -> CentrifugeRun:
    """Simulate one centrifuge run.

    Parameters
    ----------
    model : per axis {term: coefficient} of the true error model (terms as in
        `calib_core.solvers.centrifuge.term_values`), m/s^2 per input unit.
    rng : random generator (noise, table start angles, run offset).
    mounts : mounting positions to run.
    radius, phi_h : effective radius (m) and horizontal misalignment (rad),
        one value or one per position.
    tilt, tilt_azimuth : table-axis tilt from vertical and its direction, rad.
    latitude_deg : site latitude (Earth rate).
    direction : +1 anticlockwise seen from above, -1 clockwise.
    gravity : m/s^2.
    noise : the sensor's white noise, run offset and per-record instabilities.
    schedule : the records per position (g steps, durations, sample rate, zero after).
    nominal_radius : radius the operator sets the rates from (default the mean radius).
    zero_drift : per position the (3,) change of the zero output between before and
        after, m/s^2 (default none).

    Returns
    -------
    CentrifugeRun with per-position zero records at 0/90/180/270 deg, a near-1 g
    run and the high-g steps, plus the truth.

    The steps are simulated in lab order (`_record` one at a time), so a seed
    gives the same run whatever is asked of it afterwards.
    """
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 or -1, got {direction}")
    radii = _per_mount(radius, mounts)
    phis = _per_mount(phi_h, mounts)
    r_nom = nominal_radius or float(np.mean(list(radii.values())))
    lat = math.radians(latitude_deg)
    truth = CentrifugeTruth(
        model={a: dict(t) for a, t in model.items()},
        radius=radii,
        phi_h=phis,
        tilt=tilt,
        tilt_azimuth=tilt_azimuth,
        omega_v=EARTH_RATE * math.sin(lat),
        omega_h=EARTH_RATE * math.cos(lat),
        gravity=gravity,
        direction=direction,
        run_offset=(
            rng.normal(0.0, noise.run_offset_std, 3) if noise.run_offset_std > 0 else np.zeros(3)
        ),
    )

    def rate_for(n_g: float) -> float:
        return direction * math.sqrt(n_g * gravity / r_nom)

    def record(mount: str, rate: float, duration: float, angle0: float, drift=(0, 0, 0)):
        fs = schedule.sample_rate
        return _record(truth, noise, fs, rng, mount, rate, duration, angle0, drift)

    steps: list[CentrifugeStep] = []
    for mount in mounts:
        for pos in ZERO_POSITIONS_DEG:
            rec = record(mount, 0.0, schedule.zero_duration, math.radians(pos))
            steps.append(CentrifugeStep(mount, "zero", rec, 0.0, pos))
        start = rng.uniform(0, 2 * math.pi)
        rec = record(mount, rate_for(1.0), schedule.one_g_duration, start)
        steps.append(CentrifugeStep(mount, "1g", rec, 1.0))
        for n_g in schedule.g_steps:
            start = rng.uniform(0, 2 * math.pi)
            rec = record(mount, rate_for(n_g), schedule.step_duration, start)
            steps.append(CentrifugeStep(mount, "step", rec, float(n_g)))
        drift = (zero_drift or {}).get(mount, (0.0, 0.0, 0.0))
        for pos in ZERO_POSITIONS_DEG if schedule.zero_after else ():
            rec = record(mount, 0.0, schedule.zero_duration, math.radians(pos), drift)
            steps.append(CentrifugeStep(mount, "zero_after", rec, 0.0, pos))
    return CentrifugeRun(steps=steps, truth=truth)
