"""Mission profiles for navigation performance, the science: the trajectory, temperatures and
aiding a unit's calibrated errors are propagated over (`calib_core.navigation`).

Frames and conventions (Groves 2013, ch. 2): navigation frame n = local North-East-Down at
the start point; body frame b = forward-right-down; attitude = roll, pitch, yaw (ZYX Euler
angles, rad), C_b^n = R_z(yaw) R_y(pitch) R_x(roll). Positions are metres North, East,
Down from the start point (a trajectory of tens of kilometres; the latitude used for the
Earth rate and the transport rate is the start's).

A profile is a typed object; its TOML form (pipelines/navprofiles/*.toml) is parsed by
`pipelines.navigation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def euler_to_dcm(euler: np.ndarray) -> np.ndarray:
    """C_b^n from roll, pitch, yaw (Groves eq. 2.22).

    Parameters
    ----------
    euler : (..., 3) roll, pitch, yaw, rad.

    Returns
    -------
    (..., 3, 3) C_b^n.
    """
    r, p, y = np.moveaxis(np.asarray(euler, dtype=float), -1, 0)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rows = [
        [cp * cy, -cr * sy + sr * sp * cy, sr * sy + cr * sp * cy],
        [cp * sy, cr * cy + sr * sp * sy, -sr * cy + cr * sp * sy],
        [-sp, sr * cp, cr * cp],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def body_rates(euler: np.ndarray, euler_rates: np.ndarray) -> np.ndarray:
    """omega_nb^b from Euler angles and their rates (Groves eq. 2.57, inverted).

    Parameters
    ----------
    euler, euler_rates : (..., 3) rad and rad/s.

    Returns
    -------
    (..., 3) rad/s.
    """
    r, p, _ = np.moveaxis(euler, -1, 0)
    dr, dp, dy = np.moveaxis(euler_rates, -1, 0)
    return np.stack(
        [
            dr - dy * np.sin(p),
            dp * np.cos(r) + dy * np.sin(r) * np.cos(p),
            -dp * np.sin(r) + dy * np.cos(r) * np.cos(p),
        ],
        axis=-1,
    )


@dataclass(frozen=True)
class Trajectory:
    """The true motion, sampled.

    Attributes
    ----------
    t : (K,) time, s, increasing, from 0.
    position : (K, 3) North, East, Down from the start, m.
    euler : (K, 3) roll, pitch, yaw, rad (yaw unwrapped).
    """

    t: np.ndarray
    position: np.ndarray
    euler: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size < 2 or not np.all(np.diff(t) > 0) or abs(t[0]) > 1e-9:
            raise ValueError("trajectory time must be 1-D, increasing and start at 0 s")
        for name in ("position", "euler"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (t.size, 3) or not np.isfinite(a).all():
                raise ValueError(f"trajectory {name} must be ({t.size}, 3) finite numbers")

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def kinematics(self, times: np.ndarray) -> dict[str, np.ndarray]:
        """Velocity, acceleration, attitude and body rates at `times` (linear interpolation of
        the sampled values and of their finite differences).

        Returns
        -------
        {"velocity": (T, 3) m/s, "acceleration": (T, 3) m/s^2 (NED), "euler": (T, 3) rad,
        "dcm": (T, 3, 3) C_b^n, "omega_nb": (T, 3) rad/s in the body frame}.
        """
        t = np.asarray(self.t, dtype=float)
        vel = np.gradient(np.asarray(self.position, dtype=float), t, axis=0)
        acc = np.gradient(vel, t, axis=0)
        rates = np.gradient(np.asarray(self.euler, dtype=float), t, axis=0)

        def at(a: np.ndarray) -> np.ndarray:
            return np.stack([np.interp(times, t, a[:, i]) for i in range(3)], axis=-1)

        euler = at(np.asarray(self.euler, dtype=float))
        return {
            "velocity": at(vel),
            "acceleration": at(acc),
            "euler": euler,
            "dcm": euler_to_dcm(euler),
            "omega_nb": body_rates(euler, at(rates)),
        }


@dataclass(frozen=True)
class Segment:
    """One piece of a built-in trajectory with constant inputs.

    Attributes
    ----------
    duration : s.
    forward_accel : along-track acceleration, m/s^2.
    yaw_rate : rad/s (positive: turning right, North to East).
    climb_accel : vertical acceleration, m/s^2, up positive.
    """

    duration: float
    forward_accel: float = 0.0
    yaw_rate: float = 0.0
    climb_accel: float = 0.0


def trajectory_from_segments(
    segments: list[Segment],
    *,
    heading: float = 0.0,
    tilt_with_acceleration: bool = False,
    step: float = 0.05,
    gravity: float = 9.80665,
) -> Trajectory:
    """A trajectory driven by piecewise-constant along-track acceleration, yaw rate and climb
    acceleration, integrated at `step` s (trapezoidal rule on the speed).

    Parameters
    ----------
    segments : the pieces, in order.
    heading : initial yaw, rad.
    tilt_with_acceleration : a multicopter: the body tilts so that its thrust (the specific
        force) stays along body -z: pitch = -atan(a_fwd / g), roll = atan(a_lat / g).
    step : sampling, s.
    gravity : m/s^2, for the tilt.
    """
    if not segments:
        raise ValueError("a trajectory needs at least one segment")
    n = [max(1, round(s.duration / step)) for s in segments]
    a_f = np.concatenate([np.full(k, s.forward_accel) for k, s in zip(n, segments, strict=True)])
    w_y = np.concatenate([np.full(k, s.yaw_rate) for k, s in zip(n, segments, strict=True)])
    a_u = np.concatenate([np.full(k, s.climb_accel) for k, s in zip(n, segments, strict=True)])
    t = np.arange(a_f.size + 1) * step
    speed = np.concatenate([[0.0], np.cumsum(a_f) * step])
    climb = np.concatenate([[0.0], np.cumsum(a_u) * step])
    yaw = heading + np.concatenate([[0.0], np.cumsum(w_y) * step])
    if speed.min() < -1e-9:
        raise ValueError("trajectory segments drive the speed below zero")
    vel = np.stack([speed * np.cos(yaw), speed * np.sin(yaw), -climb], axis=-1)
    pos = np.concatenate([[np.zeros(3)], np.cumsum(0.5 * (vel[1:] + vel[:-1]) * step, axis=0)])
    euler = np.zeros((t.size, 3))
    euler[:, 2] = yaw
    if tilt_with_acceleration:
        a_fwd = np.append(a_f, a_f[-1])
        a_lat = speed * np.append(w_y, w_y[-1])
        euler[:, 0] = np.arctan2(a_lat, gravity)
        euler[:, 1] = -np.arctan2(a_fwd, gravity)
    return Trajectory(t, pos, euler)


AIDING_KINDS = ("none", "position", "velocity", "position+velocity")


@dataclass(frozen=True)
class Aiding:
    """External fixes while the aid is available.

    Attributes
    ----------
    kind : "none", "position", "velocity" or "position+velocity".
    interval : s between fixes.
    position_std : m, 1 sigma per axis (N, E, D) of a position fix.
    velocity_std : m/s, 1 sigma per axis of a velocity fix.
    until : s, the outage start (fixes at t <= until); None: fixes to the end.
    height_std : m, 1 sigma of a height fix (barometer) at every fix time, outages
        included; None: no height aiding (the vertical channel is free and diverges).
    """

    kind: str = "none"
    interval: float = 1.0
    position_std: float = 2.0
    velocity_std: float = 0.1
    until: float | None = None
    height_std: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in AIDING_KINDS:
            raise ValueError(
                f"aiding kind must be none, position, velocity or position+velocity, "
                f"got {self.kind!r}"
            )
        if not (self.interval > 0 and self.position_std > 0 and self.velocity_std > 0):
            raise ValueError("aiding interval, position_std and velocity_std must be > 0")
        if self.height_std is not None and not self.height_std > 0:
            raise ValueError("aiding height_std must be > 0 m (or absent)")

    def observed(self, t: float) -> tuple[list[int], np.ndarray]:
        """A fix at time t (s): the navigation-error indices it observes (velocity 3:6,
        position 6:9) and their variances; ([], ...) when there is none."""
        idx: list[int] = []
        var: list[float] = []
        if self.kind != "none" and (self.until is None or t <= self.until + 1e-9):
            if "velocity" in self.kind:
                idx, var = idx + [3, 4, 5], var + [self.velocity_std**2] * 3
            if "position" in self.kind:
                idx, var = idx + [6, 7, 8], var + [self.position_std**2] * 3
        if self.height_std is not None and 8 not in idx:
            idx, var = idx + [8], var + [self.height_std**2]
        return idx, np.array(var)


@dataclass(frozen=True)
class MissionProfile:
    """Everything the propagation needs to know about a mission.

    Attributes
    ----------
    name : the profile's name.
    duration : s (<= the trajectory's).
    trajectory : the true motion.
    latitude : start latitude, rad.
    height : start height, m.
    temperature_range : (min, max) deg C the unit sees.
    aiding : the fixes.
    initial_std : (9,) 1-sigma initial errors: attitude (roll, pitch, heading; rad),
        velocity (N, E, D; m/s), position (N, E, D; m).
    step : propagation step, s.
    position_limit : m, the horizontal 95 % error whose first crossing is reported.
    description : one line.
    """

    name: str
    duration: float
    trajectory: Trajectory
    latitude: float = math.radians(45.0)
    height: float = 0.0
    temperature_range: tuple[float, float] = (20.0, 25.0)
    aiding: Aiding = field(default_factory=Aiding)
    initial_std: np.ndarray = field(default_factory=lambda: np.zeros(9))
    step: float = 0.5
    position_limit: float = 10.0
    description: str = ""

    def __post_init__(self) -> None:
        if not 0 < self.duration <= self.trajectory.duration + 1e-9:
            raise ValueError(
                f"profile {self.name!r}: duration {self.duration} s must be > 0 and within the "
                f"trajectory's {self.trajectory.duration:g} s"
            )
        if not 0 < self.step <= self.duration:
            raise ValueError(f"profile {self.name!r}: step must be in (0, duration]")
        if abs(self.latitude) >= math.radians(89.0):
            raise ValueError(f"profile {self.name!r}: latitude must be within +-89 deg")
        lo, hi = self.temperature_range
        if not lo <= hi:
            raise ValueError(f"profile {self.name!r}: temperature range min must be <= max")
        if np.shape(self.initial_std) != (9,) or np.any(np.asarray(self.initial_std) < 0):
            raise ValueError(f"profile {self.name!r}: initial_std must be 9 values >= 0")
        if self.position_limit <= 0:
            raise ValueError(f"profile {self.name!r}: position limit must be > 0 m")
