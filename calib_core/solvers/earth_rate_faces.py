"""Gyro bias, scale and misalignment from the six statics with Earth rate as the input.

The north-seeker note's FOG case (docs/methods.md, "Gyro from Earth rate"): a gyro quiet
enough to see Earth's rotation (15.04 deg/h) has, in each of the six static positions of
a level fixture of known heading at a known latitude, a known input rate w_b, and

    w_meas_mean(position) = (I + M_g) w_b(position) + b_g

gives b_g (3) and M_g (9) from the 18 equations by weighted least squares (one 4-unknown
fit per gyro channel, `calib_core.solvers.multi_position.fit_affine`).

Convention of the positions (the note gives none). The level frame is the static-bias
procedure's (`earth_rate_level_frame`): e1 horizontal at `heading_deg` clockwise from true
North, e2 at heading - 90 deg, e3 up. In a position the named axis points along +e3 (up)
or -e3 (dn), and the next axis in the cycle x -> y -> z -> x points along e1, the fixture
heading: the z faces have x at the heading (the static-bias fixture is the z_up
position), the x faces y, the y faces z. A dn position is its up position turned half a
turn about that heading axis. So, with the named axis i, heading axis h = i + 1 and the
third t = i + 2 (mod 3), and s = +1 up, -1 dn:

    w_b[i] = s w_L[2],   w_b[h] = w_L[0],   w_b[t] = s w_L[1].
"""

from __future__ import annotations

import numpy as np

from calib_core import params
from calib_core.earth import EARTH_RATE
from calib_core.solvers.multi_position import LinearFit, fit_affine, named_fit
from calib_core.solvers.six_position import STATIC_LABELS
from calib_core.solvers.static_bias import earth_rate_level_frame
from calib_core.units import DEG

# The scale-free design [1, w_b / Omega] of a well-posed set is conditioned near 1..3;
# beyond this the latitude and heading leave a combination of the 12 unknowns unseen.
EARTH_RATE_CONDITION_LIMIT = 1e3
# The Earth rate is the only input, so u(M_ij) ~ u(mean) / Omega: it is taken as observed
# when the noisiest gyro mean's standard uncertainty is at most 1 % of Omega (scale and
# misalignment resolved to about 1 %, finer than a MEMS gyro's own 0.5..3 % errors).
OBSERVABLE_LIMIT = 0.01
DEG_PER_H = DEG / 3600.0


def face_earth_rate(label: str, latitude_deg: float, heading_deg: float) -> np.ndarray:
    """Earth rate in the body frame of one static position (module docstring), rad/s, (3,).

    label : x_up, x_dn, y_up, y_dn, z_up or z_dn.
    latitude_deg, heading_deg : site latitude and fixture heading, degrees.
    """
    axis, _, sense = label.partition("_")
    if axis not in params.AXIS_INDEX or sense not in ("up", "dn"):
        raise ValueError(f"Earth-rate input: {label!r} is not a static position {STATIC_LABELS}")
    w_level = earth_rate_level_frame(latitude_deg, heading_deg)
    i = params.AXIS_INDEX[axis]
    s = 1.0 if sense == "up" else -1.0
    w = np.empty(3)
    w[i], w[(i + 1) % 3], w[(i + 2) % 3] = s * w_level[2], w_level[0], s * w_level[1]
    return w


def faces_earth_rate(latitude_deg: float | None, heading_deg: float | None) -> np.ndarray:
    """(6, 3) body-frame Earth rate of the six positions in STATIC_LABELS order, rad/s.

    ValueError naming why when latitude or heading is not known, or when they leave the
    12-parameter model undetermined (e.g. on the equator with the fixture facing north,
    where each channel's bias and its scale see the same input in every position).
    """
    if latitude_deg is None or heading_deg is None:
        raise ValueError(
            "gyro_from_earth_rate needs the site latitude_deg and the fixture heading_deg "
            f"(the Earth rate's direction in each position), got latitude_deg={latitude_deg!r}, "
            f"heading_deg={heading_deg!r}"
        )
    w = np.array([face_earth_rate(label, latitude_deg, heading_deg) for label in STATIC_LABELS])
    design = np.hstack([np.ones((len(w), 1)), w / EARTH_RATE])
    condition = float(np.linalg.cond(design))
    if not np.isfinite(condition) or condition > EARTH_RATE_CONDITION_LIMIT:
        raise ValueError(
            f"gyro_from_earth_rate: at latitude {latitude_deg} deg and heading {heading_deg} deg "
            f"the six positions' Earth-rate inputs do not determine gyro bias, scale and "
            f"misalignment (condition number {condition:.3g} > {EARTH_RATE_CONDITION_LIMIT:g}); "
            "turn the fixture's heading away from north/south (e.g. 45 deg)"
        )
    return w


def solve_gyro_earth_rate(
    w_body: np.ndarray, means: np.ndarray, sem: np.ndarray
) -> tuple[LinearFit, dict]:
    """gyr.bias.*, gyr.scale.*, gyr.misalign.* from the six statics' means.

    Parameters
    ----------
    w_body : (6, 3) Earth rate in each position's body frame (`faces_earth_rate`), rad/s.
    means, sem : (6, 3) gyro means and their standard uncertainties, rad/s.

    Returns
    -------
    The fit (12 parameters, their covariance from the sems, chi2 per channel with 2
    degrees of freedom) and the check ``model:earth_rate_observable`` (the evidence that
    the largest standard uncertainty of the six means is at most OBSERVABLE_LIMIT times
    the Earth rate). ValueError with the same figures for a gyro (a MEMS one) whose noise
    hides the Earth rate.
    """
    b, A, cov, condition, residual, chi2 = fit_affine(w_body, means, sem)
    fit = named_fit("gyr", b, A, cov, condition, residual, chi2, identity=True, misfit_scaled=True)
    u_matrix = max(u for name, u in fit.std.items() if ".bias." not in name)
    ratio = float(np.max(sem)) / EARTH_RATE
    observed = ratio <= OBSERVABLE_LIMIT
    check = {
        "name": "model:earth_rate_observable",
        "value": ratio,
        "limit": OBSERVABLE_LIMIT,
        "passed": bool(observed),
        "detail": (
            f"noisiest gyro mean's standard uncertainty {float(np.max(sem)) / DEG_PER_H:.3g} "
            f"deg/h against the Earth rate {EARTH_RATE / DEG_PER_H:.2f} deg/h (ratio {ratio:.3g}, "
            f"limit {OBSERVABLE_LIMIT:g}); largest u of a gyro scale/misalignment "
            f"{u_matrix:.3g}: "
            + ("the Earth rate is observed" if observed else "the noise hides the Earth rate")
        ),
    }
    if not observed:
        # Refused, not archived with a failed check: the estimates would then carry whatever
        # the noise and the unmodelled g-sensitivity put there (a MEMS gyro's M_ij come out
        # at 10 and beyond, which the physical-bounds guard would blame on the labels).
        raise ValueError(
            f"gyro_from_earth_rate: {check['detail']}; gyro scale and misalignment are not "
            "identifiable from this run: a FOG/RLG-grade gyro or longer statics are needed, "
            "else solve with gyro_from_earth_rate = false (gyro bias and g-sensitivity)"
        )
    return fit, check
