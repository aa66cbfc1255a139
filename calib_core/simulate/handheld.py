"""Hand-held multi-pose sessions (equipment-free calibration input) with known truth.

One continuous recording: a long first rest, then `poses` still poses, each
reached by turning the IMU about a random body axis by a random angle with a
smooth rate profile w(t) = w_peak sin^2(pi t / T). About a fixed body axis the
attitude is exactly C(t) = C_0 exp(theta(t) [a]x) (Rodrigues), so the true
specific force f_b = C^T (0, 0, g) is known in closed form at every sample.
The motion is a pure rotation about the sensor (no linear acceleration).

The accelerometer truth is put in the frame the equipment-free solver uses
(I + M_a lower triangular, see calib_core.solvers.equipment_free), so the
recovered parameters are comparable with it one to one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib_core.attitude import quat_from_rotvec, quat_to_matrix
from calib_core.recording import Recording
from calib_core.simulate.lab_run import TrueErrors
from calib_core.units import DEG, STANDARD_GRAVITY


@dataclass
class HandheldRun:
    """A simulated hand-held session: the recording, the truth, the true rest attitudes."""

    recording: Recording
    truth: TrueErrors
    gravity: float
    attitudes: np.ndarray  # (poses + 1, 3, 3) body-to-level at each rest


def accelerometer_frame(truth: TrueErrors) -> TrueErrors:
    """The same sensor with I + M_a lower triangular (upper misalignments zeroed).

    Zeroing them is a choice of the true frame (any error model is one rotation
    away from a lower-triangular one), so the simulated sensor stays realistic.
    """
    acc_m = np.tril(truth.acc_M)
    return TrueErrors(
        truth.acc_bias,
        acc_m,
        truth.gyr_bias,
        truth.gyr_M,
        truth.gsens,
        truth.acc_noise,
        truth.gyr_noise,
    )


def handheld_run(
    truth: TrueErrors,
    rng: np.random.Generator,
    *,
    poses: int = 30,
    gravity: float = STANDARD_GRAVITY,
    rate_hz: float = 100.0,
    init_s: float = 20.0,
    hold_s: float = 4.0,
    move_s: float = 1.5,
    angle_deg: tuple[float, float] = (60.0, 150.0),
    gsens: bool = False,
) -> HandheldRun:
    """Simulate a hand-held session.

    Parameters
    ----------
    truth : error model; its accelerometer part should be lower triangular
        (`accelerometer_frame`) for a one-to-one comparison.
    rng : random generator (poses and noise).
    poses : number of still poses after the first rest.
    gravity : m/s^2; rate_hz : Hz.
    init_s : first rest, s; hold_s : each later rest, s; move_s : each motion, s.
    angle_deg : range of the turn angle of each motion, deg.
    gsens : include the gyro g-sensitivity (the equipment-free model has none).
    """
    dt = 1.0 / rate_hz
    n_init, n_hold, n_move = (int(round(x * rate_hz)) for x in (init_s, hold_s, move_s))
    c = quat_to_matrix(quat_from_rotvec(rng.normal(0.0, 1.0, 3)))  # random start attitude
    attitudes = [c]
    w_parts = [np.zeros((n_init, 3))]
    c_parts = [np.broadcast_to(c, (n_init, 3, 3))]
    tau = (np.arange(n_move) + 0.5) * dt  # motion samples strictly inside the move
    for _ in range(poses):
        axis = rng.normal(0.0, 1.0, 3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(*angle_deg) * DEG * rng.choice([-1.0, 1.0])
        # sin^2 profile: rate w_peak sin^2(pi tau/T) integrates to angle with w_peak = 2 angle / T.
        rate = 2.0 * angle / move_s * np.sin(math.pi * tau / move_s) ** 2
        theta = angle * (tau / move_s - np.sin(2 * math.pi * tau / move_s) / (2 * math.pi))
        rot = quat_to_matrix(quat_from_rotvec(theta[:, None] * axis))
        w_parts += [rate[:, None] * axis, np.zeros((n_hold, 3))]
        c_parts.append(c @ rot)
        c = c @ quat_to_matrix(quat_from_rotvec(angle * axis))
        attitudes.append(c)
        c_parts.append(np.broadcast_to(c, (n_hold, 3, 3)))
    w_true = np.vstack(w_parts)
    c_all = np.concatenate(c_parts)
    n = w_true.shape[0]
    f_true = gravity * c_all[:, 2, :]  # C^T e_z g
    acc = truth.acc_measured(f_true) + rng.standard_normal((n, 3)) * truth.acc_noise
    g_matrix = truth.gsens if gsens else np.zeros((3, 3))
    gyr = (
        w_true @ (np.eye(3) + truth.gyr_M).T
        + f_true @ g_matrix.T
        + truth.gyr_bias
        + rng.standard_normal((n, 3)) * truth.gyr_noise
    )
    t = np.arange(n) * dt
    rec = Recording(
        t, acc, gyr, label="handheld", source=f"simulated hand-held session ({poses} poses)"
    )
    return HandheldRun(rec, truth, gravity, np.array(attitudes))
