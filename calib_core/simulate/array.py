"""Sensor-array runs: IMUs on a cube with known mountings, one static record and two turns.

Every sensor s has the mounting C_s (cube to sensor) and the same error model
(`TrueErrors`). The cube stands z up; the static record reads f_s = C_s (0, 0, g);
the turns are n whole turns about the vertical, ccw (+) then cw (-), with the
smooth rate profile of `calib_core.simulate.lab_run.Turns`, so the
sensor rate is w_s(t) = +-rate(t) C_s e_z and f_s stays constant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.recording import Recording
from calib_core.simulate.lab_run import ONE_TURN, TrueErrors, Turns
from calib_core.units import STANDARD_GRAVITY


@dataclass
class ArrayRun:
    """Segments "<sensor>_static|_ccw|_cw", the mountings, and the shared truth."""

    segments: dict[str, Recording]
    mounts: dict[str, np.ndarray]
    truth: TrueErrors
    gravity: float


def array_run(
    truth: TrueErrors,
    mounts: dict[str, np.ndarray],
    rng: np.random.Generator,
    *,
    gravity: float = STANDARD_GRAVITY,
    rate_hz: float = 100.0,
    static_s: float = 30.0,
    turns: Turns = ONE_TURN,
) -> ArrayRun:
    """Simulate the static record and the ccw / cw turns of every sensor of an array.

    Parameters
    ----------
    truth : the shared error model.
    mounts : sensor name -> (3, 3) cube-to-sensor rotation.
    rng : random generator (independent white noise per sensor and channel).
    gravity : m/s^2; rate_hz : Hz; static_s : static record length, s.
    turns : the ccw and cw turns (whole turns, peak rate, pauses).
    """
    t_static = np.arange(int(round(static_s * rate_hz))) / rate_hz
    t_turn, rate = turns.profile(rate_hz)
    segments: dict[str, Recording] = {}
    for name, mount in mounts.items():
        c = np.asarray(mount, dtype=float)
        for phase, t, sign in (
            ("static", t_static, 0.0),
            ("ccw", t_turn, 1.0),
            ("cw", t_turn, -1.0),
        ):
            acc, gyr = _outputs(truth, c, sign * rate if sign else np.zeros(len(t)), gravity, rng)
            label = f"{name}_{phase}"
            segments[label] = Recording(t, acc, gyr, label=label, source=f"simulated {label}")
    return ArrayRun(segments, {k: np.asarray(v, float) for k, v in mounts.items()}, truth, gravity)


def _outputs(
    truth: TrueErrors, mount: np.ndarray, rate: np.ndarray, gravity: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Accelerometer and gyro outputs (N, 3) of a sensor with mounting `mount` on the cube
    standing z up, turning at `rate` (N,) rad/s about the vertical."""
    up = mount @ np.array([0.0, 0.0, 1.0])
    n = rate.shape[0]
    w_true = np.outer(rate, up)
    f_true = np.broadcast_to(gravity * up, (n, 3))
    acc = truth.acc_measured(f_true) + rng.standard_normal((n, 3)) * truth.acc_noise
    gyr = truth.gyr_measured(w_true, f_true) + rng.standard_normal((n, 3)) * truth.gyr_noise
    return acc, gyr


def array_session(
    truth: TrueErrors,
    mounts: dict[str, np.ndarray],
    rng: np.random.Generator,
    *,
    gravity: float = STANDARD_GRAVITY,
    rate_hz: float = 100.0,
    static_s: float = 40.0,
    turns: Turns = ONE_TURN,
) -> dict[str, Recording]:
    """One continuous recording per sensor: static, cw turn, static, ccw turn, static.

    All sensors are recorded at once (same time base). The unlabelled sessions
    are what automatic segmentation (``labels = "array"``) cuts into the
    ``<sensor>_static``, ``_cw`` and ``_ccw`` segments of `array_run`.

    Parameters as `array_run`; static_s is each of the three static stretches, s.

    Returns
    -------
    sensor name -> Recording of the whole session.
    """
    rest = np.zeros(int(round(static_s * rate_hz)))
    _, turn = turns.profile(rate_hz)
    rate = np.concatenate([rest, -turn, rest, turn, rest])
    t = np.arange(rate.shape[0]) / rate_hz
    out = {}
    for name, mount in mounts.items():
        acc, gyr = _outputs(truth, np.asarray(mount, dtype=float), rate, gravity, rng)
        out[name] = Recording(t, acc, gyr, label=name, source=f"simulated array session {name}")
    return out
