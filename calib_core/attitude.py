"""Attitude: rotation matrices from table angles, quaternions, gyro integration.

Frames. The level frame n has z up; a sensor at rest with its z axis up reads
the specific force f_n = (0, 0, g). The attitude C (3, 3) maps body vectors
into the level frame, v_n = C v_b, so the body reads f_b = C^T f_n.

Two-axis tables (angles in rad):

- pitch/roll table: outer axis pitch about level y, inner axis roll about the
  carried x axis, C = R_y(pitch) R_x(roll). Then
  f_b / g = (-sin p, cos p sin r, cos p cos r), so every direction is reachable.
- azimuth/pitch table: outer axis azimuth about level z, inner axis pitch about
  the carried y axis, C = R_z(azimuth) R_y(pitch). Azimuth does not change f_b;
  labs reach the other faces by remounting (`mount`).

Attitude conventions (the sign of the table's pitch), ``convention``:

- ``"project"`` (default): pitch is a right-handed rotation about y, so a
  positive pitch lowers +x: a_x = -g sin(pitch) (the formulas above).
- ``"rate_table_procedure"``: the two-axis rate-table procedure (docs/methods.md
  [RT]) counts pitch the other way, a_x = +g sin(pitch): the same table
  with the pitch angle negated. Roll keeps the project's sense (the procedure
  states the x component only).

A table read with the wrong convention puts the sensor's +x where the model
expects -x: the fitted scale factor comes out near -2, which the solvers refuse
(calib_core.checks.PHYSICAL_BOUNDS).

Quaternions are (w, x, y, z), Hamilton product, q ⊗ v ⊗ q* maps body to level.
"""

from __future__ import annotations

import numpy as np

TABLE_AXES = ("pitch_roll", "azimuth_pitch")
ATTITUDE_CONVENTIONS = ("project", "rate_table_procedure")


def rot_x(a: float | np.ndarray) -> np.ndarray:
    """Rotation matrix about x by angle a (rad); (3, 3) or (N, 3, 3) for an array."""
    return _rot(a, 0)


def rot_y(a: float | np.ndarray) -> np.ndarray:
    """Rotation matrix about y by angle a (rad)."""
    return _rot(a, 1)


def rot_z(a: float | np.ndarray) -> np.ndarray:
    """Rotation matrix about z by angle a (rad)."""
    return _rot(a, 2)


def _rot(a: float | np.ndarray, axis: int) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    r = np.zeros(a.shape + (3, 3))
    i, j = [k for k in range(3) if k != axis]
    r[..., axis, axis] = 1.0
    r[..., i, i] = c
    r[..., j, j] = c
    # Right-handed: about y the sign pattern is transposed relative to x and z.
    sign = -1.0 if axis == 1 else 1.0
    r[..., i, j] = -s * sign
    r[..., j, i] = s * sign
    return r


def table_attitude(
    outer: float | np.ndarray,
    inner: float | np.ndarray,
    axes: str = "pitch_roll",
    mount: np.ndarray | None = None,
    convention: str = "project",
) -> np.ndarray:
    """Body-to-level rotation C of an IMU on a two-axis table.

    Parameters
    ----------
    outer, inner : table angles, rad, scalars or (N,): (pitch, roll) for a
        "pitch_roll" table, (azimuth, pitch) for an "azimuth_pitch" table.
    axes : "pitch_roll" or "azimuth_pitch".
    mount : (3, 3) rotation from the IMU body to the table's inner frame
        (identity if None).
    convention : "project" or "rate_table_procedure" (pitch counted the other
        way: a_x = +g sin(pitch)); see the module docstring.

    Returns
    -------
    (3, 3) or (N, 3, 3) rotation matrices.
    """
    if convention not in ATTITUDE_CONVENTIONS:
        raise ValueError(
            f"unknown attitude convention {convention!r}; expected one of "
            f"{list(ATTITUDE_CONVENTIONS)}"
        )
    if convention == "rate_table_procedure":  # pitch counted the other way
        if axes == "pitch_roll":
            outer = -np.asarray(outer, dtype=float)
        else:
            inner = -np.asarray(inner, dtype=float)
    if axes == "pitch_roll":
        c = rot_y(outer) @ rot_x(inner)
    elif axes == "azimuth_pitch":
        c = rot_z(outer) @ rot_y(inner)
    else:
        raise ValueError(f"unknown table axes {axes!r}; expected one of {list(TABLE_AXES)}")
    return c if mount is None else c @ np.asarray(mount, dtype=float)


def specific_force(attitude: np.ndarray, gravity: float) -> np.ndarray:
    """Specific force f_b = C^T (0, 0, g) read by a sensor at rest, m/s^2.

    Parameters
    ----------
    attitude : (3, 3) or (N, 3, 3) body-to-level rotations.
    gravity : m/s^2.

    Returns
    -------
    (3,) or (N, 3).
    """
    return gravity * np.asarray(attitude)[..., 2, :]  # last row of C = C^T e_z


def pitch_roll_from_direction(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pitch and roll (rad) of a pitch/roll table putting the unit up-vector `u` (N, 3) in body.

    Inverse of `specific_force` for the pitch/roll table: u = (-sin p, cos p sin r, cos p cos r).
    """
    u = np.atleast_2d(np.asarray(u, dtype=float))
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    pitch = np.arcsin(np.clip(-u[:, 0], -1.0, 1.0))
    # At pitch +-90 deg roll is free; atan2(0, 0) = 0 picks roll 0.
    roll = np.arctan2(np.round(u[:, 1], 12), np.round(u[:, 2], 12))
    return pitch, roll


def attitude_problems(
    labels: list[str], forces: np.ndarray, gravity: float, same_deg: float = 1.0
) -> tuple[list[str], list[str]]:
    """Duplicate attitudes and axes not seen in both senses, before a static solve.

    Parameters
    ----------
    labels : (K,) segment labels.
    forces : (K, 3) reference specific force of each, m/s^2.
    gravity : m/s^2.
    same_deg : two attitudes whose gravity directions are closer than this
        (degrees) are the same attitude.

    Returns
    -------
    (duplicates, uncovered): messages naming the labels of each group of
    duplicate attitudes, and naming each axis that never reads more than
    +g/2 or never less than -g/2 (one sense missing: a scale factor then rests
    on one sense only and a sign error of the attitudes cannot show).
    """
    f = np.asarray(forces, dtype=float)
    u = f / np.linalg.norm(f, axis=1, keepdims=True)
    cos_same = np.cos(np.radians(same_deg))
    duplicates, seen = [], set()
    for i in range(len(labels)):
        if i in seen:
            continue
        group = [j for j in range(i, len(labels)) if u[i] @ u[j] >= cos_same]
        seen.update(group)
        if len(group) > 1:
            names = ", ".join(labels[j] for j in group)
            duplicates.append(
                f"attitudes {names} are the same (gravity direction within {same_deg:g} deg): "
                "the repeat adds no direction"
            )
    uncovered = []
    for j, axis in enumerate("xyz"):
        for sense, reached in (
            ("+", (f[:, j] > 0.5 * gravity).any()),
            ("-", (f[:, j] < -0.5 * gravity).any()),
        ):
            if not reached:
                uncovered.append(
                    f"no attitude has {sense}{axis} up (reading {sense}g); the {axis} axis is seen "
                    "in one sense only: check the attitude list and its convention"
                )
    return duplicates, uncovered


# --- quaternions ---------------------------------------------------------------


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p ⊗ q of (..., 4) quaternions (w, x, y, z)."""
    pw, px, py, pz = np.moveaxis(np.asarray(p, dtype=float), -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_from_rotvec(phi: np.ndarray) -> np.ndarray:
    """Quaternion (..., 4) of rotation vectors phi (..., 3), rad (exact exponential map)."""
    phi = np.asarray(phi, dtype=float)
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(x/2)/x by its series below 1e-4 rad, where the division loses digits.
    k = np.where(angle < 1e-4, 0.5 - angle**2 / 48.0, np.sin(half) / np.where(angle, angle, 1.0))
    return np.concatenate([np.cos(half), k * phi], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) of unit quaternions (..., 4)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def quat_product_chain(q: np.ndarray) -> np.ndarray:
    """Ordered product q[..., 0, :] ⊗ q[..., 1, :] ⊗ ... of (..., N, 4) quaternions.

    Pairwise reduction: log2(N) vectorised steps instead of N Python steps;
    the order of the factors is kept, so it is exact for non-commuting rotations.
    Leading dimensions are independent chains.

    Returns
    -------
    (..., 4)
    """
    q = np.asarray(q, dtype=float)
    identity = np.array([1.0, 0.0, 0.0, 0.0])
    if q.shape[-2] == 0:
        return np.broadcast_to(identity, q.shape[:-2] + (4,)).copy()
    while q.shape[-2] > 1:
        if q.shape[-2] % 2:
            pad = np.broadcast_to(identity, q.shape[:-2] + (1, 4))
            q = np.concatenate([q, pad], axis=-2)
        q = quat_multiply(q[..., 0::2, :], q[..., 1::2, :])
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return q[..., 0, :]


def integrate_rotation(t: np.ndarray, gyr: np.ndarray) -> np.ndarray:
    """Rotation of the body between the first and the last sample, from its angular rate.

    Each step turns by the rotation vector 0.5 (w_k + w_k+1) (t_k+1 - t_k) (the
    mid-point rate, second order), composed as quaternions in time order, so
    large and non-commuting rotations are integrated exactly up to the sampling,
    unlike a small-angle sum of the rates.

    Parameters
    ----------
    t : (N,) s.
    gyr : (N, 3) body angular rate, rad/s.

    Returns
    -------
    (3, 3) rotation R = C(t_0)^T C(t_N-1): body vectors at the end expressed in
    the body frame at the start; a fixed level-frame vector seen in the body
    goes from v_0 to R^T v_0.
    """
    t = np.asarray(t, dtype=float)
    gyr = np.asarray(gyr, dtype=float)
    if t.ndim != 1 or gyr.shape != (t.shape[0], 3):
        raise ValueError(
            f"integrate_rotation: t (N,) and gyr (N, 3) expected, got {t.shape}, {gyr.shape}"
        )
    if t.shape[0] < 2:
        return np.eye(3)
    phi = 0.5 * (gyr[1:] + gyr[:-1]) * np.diff(t)[:, None]
    return quat_to_matrix(quat_product_chain(quat_from_rotvec(phi)))


def integrate_rotations(
    pieces: list[tuple[np.ndarray, np.ndarray]], transform: np.ndarray | None = None
) -> np.ndarray:
    """`integrate_rotation` of many (t, gyr) pieces at once, (K, 3, 3).

    The pieces are padded with zero rotation steps (identity quaternions, which
    leave a product unchanged) to one length and reduced together.

    Parameters
    ----------
    pieces : K pairs of t (N_k,) s and gyr (N_k, 3) rad/s.
    transform : (3, 3) applied to every rate first, w -> transform @ w (e.g. a
        calibration matrix), or None.
    """
    steps = [0.5 * (w[1:] + w[:-1]) * np.diff(t)[:, None] for t, w in pieces]
    length = max((s.shape[0] for s in steps), default=0)
    phi = np.zeros((len(steps), max(length, 1), 3))
    for k, s in enumerate(steps):
        phi[k, : s.shape[0]] = s
    if transform is not None:
        # Linear in the rate, so the mid-point step transforms the same way.
        phi = phi @ np.asarray(transform, dtype=float).T
    return quat_to_matrix(quat_product_chain(quat_from_rotvec(phi)))
