"""Multi-position runs on a two-axis table: position schemes and static segments with truth.

Schemes are sets of "up" directions in the body frame (the unit vector the
sensor reads as +g), turned into pitch/roll table angles by
`calib_core.attitude.pitch_roll_from_direction`:

- 6: the faces (+-x, +-y, +-z up);
- 12: the cube's edges, gravity at 45 deg between two axes ((+-1, +-1, 0)/sqrt 2, ...);
- 18: faces and edges; every axis sees -g, -g/sqrt 2, 0, g/sqrt 2 and g, so
  quadratic and cubic terms separate from bias and scale;
- 24: the 18 plus each face again through the table's other angle solution
  (pitch 180 - p, roll r + 180): same gravity direction, table axis errors average.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core import params
from calib_core.attitude import pitch_roll_from_direction, specific_force, table_attitude
from calib_core.recording import Recording
from calib_core.simulate.lab_run import TrueErrors
from calib_core.units import DEG, STANDARD_GRAVITY

SCHEMES = (6, 12, 18, 24)


def _faces() -> np.ndarray:
    return np.vstack([np.eye(3), -np.eye(3)])[[0, 3, 1, 4, 2, 5]]


def _edges() -> np.ndarray:
    out = []
    for i, j in ((0, 1), (1, 2), (0, 2)):
        for si in (1.0, -1.0):
            for sj in (1.0, -1.0):
                u = np.zeros(3)
                u[i], u[j] = si, sj
                out.append(u / np.sqrt(2.0))
    return np.array(out)


def scheme_angles(n_positions: int) -> np.ndarray:
    """Table angles (K, 2) = (pitch, roll), rad, of a standard K-position scheme (6, 12, 18, 24)."""
    if n_positions not in SCHEMES:
        raise ValueError(f"unknown position scheme {n_positions}; expected one of {SCHEMES}")
    dirs = {6: _faces(), 12: _edges(), 18: np.vstack([_faces(), _edges()])}.get(n_positions)
    if dirs is None:
        dirs = np.vstack([_faces(), _edges()])
    pitch, roll = pitch_roll_from_direction(dirs)
    angles = np.column_stack([pitch, roll])
    if n_positions == 24:
        face = angles[:6]
        # The other solution of the same gravity direction.
        other = np.column_stack([np.pi - face[:, 0], face[:, 1] + np.pi])
        angles = np.vstack([angles, (other + np.pi) % (2 * np.pi) - np.pi])
    return angles


@dataclass
class NonlinearTruth:
    """Truth of a multi-position run: linear errors plus k2 (3,) 1/(m/s^2), k3 (3,) 1/(m/s^2)^2."""

    errors: TrueErrors
    k2: np.ndarray
    k3: np.ndarray

    def parameters(self) -> dict[str, float]:
        out = self.errors.parameters()
        for i, a in enumerate(params.AXES):
            out[f"acc.k2.{a}"] = float(self.k2[i])
            out[f"acc.k3.{a}"] = float(self.k3[i])
        return out

    def acc_measured(self, f_true: np.ndarray) -> np.ndarray:
        return self.errors.acc_measured(f_true) + self.k2 * f_true**2 + self.k3 * f_true**3


@dataclass
class MultiPositionRun:
    """Static segments "p00", "p01", ... with their table angles and the truth."""

    segments: dict[str, Recording]
    angles: np.ndarray  # (K, 2) rad, (pitch, roll) or (azimuth, pitch)
    f_true: np.ndarray  # (K, 3) m/s^2
    truth: NonlinearTruth
    gravity: float

    def attitudes_setting(self, axes: str = "pitch_roll") -> dict[str, dict[str, float]]:
        """The manifest's ``attitudes`` table for these segments, degrees."""
        keys = ("pitch", "roll") if axes == "pitch_roll" else ("azimuth", "pitch")
        return {
            lab: {f"{keys[0]}_deg": float(a[0] / DEG), f"{keys[1]}_deg": float(a[1] / DEG)}
            for lab, a in zip(self.segments, self.angles, strict=True)
        }


def multi_position_run(
    truth: TrueErrors,
    angles: np.ndarray,
    rng: np.random.Generator,
    *,
    k2: np.ndarray | None = None,
    k3: np.ndarray | None = None,
    gravity: float = STANDARD_GRAVITY,
    rate_hz: float = 100.0,
    static_s: float = 10.0,
    table_axes: str = "pitch_roll",
    reference_channels: bool = False,
) -> MultiPositionRun:
    """Static records at the given table angles, with white noise.

    Parameters
    ----------
    truth : linear error model (acc, gyro bias, g-sensitivity, noise).
    angles : (K, 2) table angles, rad (pitch, roll) or (azimuth, pitch).
    rng : random generator.
    k2, k3 : (3,) accelerometer quadratic / cubic terms (zero if None).
    gravity : m/s^2; rate_hz : Hz; static_s : length of each record, s.
    table_axes : "pitch_roll" or "azimuth_pitch".
    reference_channels : also write the angles as reference channels
        ``table_pitch``/``table_roll`` (or ``table_azimuth``/``table_pitch``), rad.
    """
    angles = np.atleast_2d(np.asarray(angles, dtype=float))
    nl = NonlinearTruth(
        truth,
        np.zeros(3) if k2 is None else np.asarray(k2, float),
        np.zeros(3) if k3 is None else np.asarray(k3, float),
    )
    keys = ("pitch", "roll") if table_axes == "pitch_roll" else ("azimuth", "pitch")
    n = int(round(static_s * rate_hz))
    t = np.arange(n) / rate_hz
    f_all = specific_force(table_attitude(angles[:, 0], angles[:, 1], table_axes), gravity)
    segments: dict[str, Recording] = {}
    for k, (f, ang) in enumerate(zip(f_all, angles, strict=True)):
        label = f"p{k:02d}"
        fb = np.broadcast_to(f, (n, 3))
        acc = nl.acc_measured(fb) + rng.standard_normal((n, 3)) * truth.acc_noise
        gyr = (
            truth.gyr_measured(np.zeros((n, 3)), fb) + rng.standard_normal((n, 3)) * truth.gyr_noise
        )
        ref = (
            {f"table_{keys[0]}": np.full(n, ang[0]), f"table_{keys[1]}": np.full(n, ang[1])}
            if reference_channels
            else {}
        )
        segments[label] = Recording(
            t, acc, gyr, reference=ref, label=label, source=f"simulated {label}"
        )
    return MultiPositionRun(segments, angles, f_all, nl, gravity)
