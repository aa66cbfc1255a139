"""Strapdown navigation, the simulator: a full local-navigation-frame mechanisation (Groves
2013, sec. 5.4: attitude, velocity, curvilinear position; Earth rate, transport rate, WGS84
gravity with height) run on the true IMU signals of a mission profile and on the same
signals corrupted by sampled sensor errors; the difference of the two solutions is the
navigation error the covariance of `calib_core.navigation` predicts to first order.

Both solutions use one integrator, so its own error cancels; what remains is the error the
sensor errors make, with every nonlinearity of the mechanisation (the check of the psi-angle
model's linearisation and signs). Unaided only: the fixes' update is the same linear
algebra in the covariance and in `calib_core.simulate.nav_errors`.
"""

from __future__ import annotations

import math

import numpy as np

from calib_core.earth import EARTH_RATE, gravity_wgs84, radii_of_curvature
from calib_core.mission import MissionProfile
from calib_core.navigation import parameter_input, skew


def _rotation(phi: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of (..., 3) rotation vectors (Rodrigues)."""
    angle = np.linalg.norm(phi, axis=-1)[..., None, None]
    k = skew(phi)
    small = angle < 1e-12
    a = np.where(small, 1.0, np.sin(angle) / np.where(small, 1.0, angle))
    b = np.where(small, 0.5, (1 - np.cos(angle)) / np.where(small, 1.0, angle) ** 2)
    return np.eye(3) + a * k + b * (k @ k)


def _step(state: dict, w_ib: np.ndarray, f_b: np.ndarray, dt: float) -> dict:
    """One mechanisation step with the interval's mean rate (rad/s) and specific force
    (m/s^2), (runs, 3) each."""
    C, v, lat, h = state["C"], state["v"], state["lat"], state["h"]
    rn, re = radii_of_curvature(lat)
    w_ie = EARTH_RATE * np.stack([np.cos(lat), 0 * lat, -np.sin(lat)], axis=-1)
    w_en = np.stack(
        [v[:, 1] / (re + h), -v[:, 0] / (rn + h), -v[:, 1] * np.tan(lat) / (re + h)], axis=-1
    )
    C_new = (np.eye(3) - skew(w_ie + w_en) * dt) @ C @ _rotation(w_ib * dt)
    f_n = np.einsum("rij,rj->ri", 0.5 * (C + C_new), f_b)
    g = gravity_wgs84(np.degrees(lat), h)
    a_n = f_n - np.cross(w_en + 2 * w_ie, v)
    a_n[:, 2] += g
    v_new = v + a_n * dt
    vm = 0.5 * (v + v_new)
    h_new = h - vm[:, 2] * dt
    lat_new = lat + vm[:, 0] / (rn + h) * dt
    lon_new = state["lon"] + vm[:, 1] / ((re + h) * np.cos(lat)) * dt
    return {"C": C_new, "v": v_new, "lat": lat_new, "lon": lon_new, "h": h_new}


def strapdown_errors(
    profile: MissionProfile,
    constants: dict[str, float],
    white: dict[str, float],
    runs: int,
    rng: np.random.Generator,
    *,
    rate_hz: float = 20.0,
) -> np.ndarray:
    """Navigation errors at the profile's end of `runs` missions, unaided.

    Parameters
    ----------
    profile : the mission (its aiding is not used; initial_std is).
    constants : canonical parameter name -> standard deviation of its error (SI).
    white : "gyr" / "acc" -> noise density N (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)), all axes.
    runs : missions.
    rng : the generator.
    rate_hz : the IMU rate of the mechanisation.

    Returns
    -------
    (runs, 9) roll, pitch, heading (rad), velocity N E D (m/s), position N E D (m) errors,
    as `calib_core.navigation.OUTPUTS`.
    """
    dt = 1.0 / rate_hz
    n = int(round(profile.duration / dt))
    kin = profile.trajectory.kinematics((np.arange(n) + 0.5) * dt)
    lat0, h0 = profile.latitude, profile.height
    rn, re = radii_of_curvature(lat0)
    R = math.sqrt(rn * re) + h0
    w_ie = EARTH_RATE * np.array([math.cos(lat0), 0.0, -math.sin(lat0)])
    v, C = kin["velocity"], kin["dcm"]
    w_en = np.stack([v[:, 1] / R, -v[:, 0] / R, -v[:, 1] * math.tan(lat0) / R], axis=-1)
    g_n = np.array([0.0, 0.0, gravity_wgs84(math.degrees(lat0), h0)])
    f_b = np.einsum("tji,tj->ti", C, kin["acceleration"] - g_n + np.cross(2 * w_ie + w_en, v))
    w_b = kin["omega_nb"] + np.einsum("tji,tj->ti", C, w_ie + w_en)

    names = sorted(constants)
    values = rng.standard_normal((runs, len(names))) * np.array([constants[k] for k in names])
    init = rng.standard_normal((runs, 9)) * profile.initial_std
    kin0 = profile.trajectory.kinematics(np.array([0.0]))
    C0, v0 = kin0["dcm"][0], kin0["velocity"][0]
    truth = {"C": C0[None], "v": v0[None], "lat": np.array([lat0]), "lon": np.zeros(1),
             "h": np.array([h0])}  # fmt: skip
    est = {
        "C": (np.eye(3) - skew(init[:, 0:3])) @ C0,
        "v": v0 + init[:, 3:6],
        "lat": lat0 + init[:, 6] / (rn + h0),
        "lon": init[:, 7] / ((re + h0) * math.cos(lat0)),
        "h": h0 - init[:, 8],
    }
    for k in range(n):
        inp = {"1": np.ones((1, 3)), "w": w_b[k][None], "f": f_b[k][None]}
        d = {"gyr": np.zeros((runs, 3)), "acc": np.zeros((runs, 3))}
        for j, name in enumerate(names):
            sensor, (out, kind, i) = parameter_input(name)
            d[sensor][:, out] += values[:, j] * inp[kind][0, i if kind != "1" else 0]
        for sensor, density in white.items():
            d[sensor] += rng.standard_normal((runs, 3)) * density / math.sqrt(dt)
        truth = _step(truth, w_b[k][None], f_b[k][None], dt)
        est = _step(est, w_b[k] + d["gyr"], f_b[k] + d["acc"], dt)
    # attitude error phi: C_est = (I - [phi x]) C_true
    E = np.eye(3) - est["C"] @ truth["C"][0].T
    phi = 0.5 * np.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0],
                          E[:, 1, 0] - E[:, 0, 1]], axis=-1)  # fmt: skip
    lat_t, h_t = truth["lat"][0], truth["h"][0]
    rn_t, re_t = radii_of_curvature(lat_t)
    dpos = np.stack(
        [
            (est["lat"] - lat_t) * (rn_t + h_t),
            (est["lon"] - truth["lon"][0]) * (re_t + h_t) * math.cos(lat_t),
            -(est["h"] - h_t),
        ],
        axis=-1,
    )
    return np.concatenate([phi, est["v"] - truth["v"][0], dpos], axis=1)
