"""Six-position closed form (docs/methods.md 2.1, MPU-6000 paper).

Positions, in order k = 1..6: x up, x down, y up, y down, z up, z down, where
"up" means that axis reads +g. The paper writes the model with signed small
angles,

    Ax = (1+Axx) ax + Axz ay - Axy az + a0x
    Ay = -Ayz ax + (1+Ayy) ay + Ayx az + a0y
    Az =  Azy ax - Azx ay + (1+Azz) az + a0z,

which maps onto the archive's matrix convention f_meas = (I + M) f_true + b as
M[x,y] = Axz, M[x,z] = -Axy, M[y,x] = -Ayz, M[y,z] = Ayx, M[z,x] = Azy,
M[z,y] = -Azx. The formulas below are the paper's, then converted.
"""

from __future__ import annotations

import numpy as np

from calib_core import params
from calib_core.recording import Recording

# Static positions in the paper's order k = 1..6; "x_up": the x axis reads +g.
STATIC_LABELS = ("x_up", "x_dn", "y_up", "y_dn", "z_up", "z_dn")


def axis_vector(label: str, gravity: float) -> np.ndarray:
    """True specific force (3,) of an orientation label: "y_dn" -> (0, -g, 0), m/s^2.

    Rotation labels ("x_ccw", "x_cw") have their axis up.
    """
    axis, sense = label.split("_")
    f = np.zeros(3)
    f[params.AXIS_INDEX[axis]] = -gravity if sense == "dn" else gravity
    return f


# Reference channel (N, 3): the true up direction (unit vector, unit frame) of a position
# whose face is not square, set by a reference correction (calib_core.reference_errors).
UP_CHANNEL = "reference_up"


def nominal_up(label: str) -> np.ndarray:
    """Unit up direction (3,) of a face label ("x_dn" -> (0, 0, 0) with -1 at x).

    Rotation labels ("x_ccw", "x_cw") have their axis up.
    """
    return axis_vector(label, 1.0)


def reference_up(label: str, rec: Recording | None, gravity: float) -> np.ndarray:
    """True specific force (3,) of a position, m/s^2: the segment's ``reference_up``
    channel when it has one (a face found not square), else the face label's axis."""
    if rec is None or UP_CHANNEL not in rec.reference:
        return axis_vector(label, gravity)
    up = np.mean(np.asarray(rec.reference[UP_CHANNEL], dtype=float), axis=0)
    norm = float(np.linalg.norm(up))
    if up.shape != (3,) or not norm > 0.5:
        raise ValueError(
            f"segment {label} ({rec.source or 'no source'}): reference channel {UP_CHANNEL} "
            f"must hold unit vectors (N, 3), got mean {up}"
        )
    return up / norm * gravity


def _check_means(means: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    missing = [label for label in STATIC_LABELS if label not in means]
    if missing:
        raise ValueError(f"six-position closed form: missing position means {missing}")
    out = {label: np.asarray(means[label], dtype=float) for label in STATIC_LABELS}
    for label, m in out.items():
        if m.shape != (3,):
            raise ValueError(f"six-position closed form: mean of {label} must have shape (3,)")
    return out


def accel_closed_form(means: dict[str, np.ndarray], gravity: float) -> dict[str, float]:
    """Accelerometer bias, scale and misalignment from six position means.

    Parameters
    ----------
    means : label -> (3,) mean accelerometer output, m/s^2, for the labels
        x_up, x_dn, y_up, y_dn, z_up, z_dn.
    gravity : local gravity, m/s^2.

    Returns
    -------
    dict of canonical names acc.bias.*, acc.scale.*, acc.misalign.* (matrix convention).
    """
    m = _check_means(means)
    A1, A2, A3, A4, A5, A6 = (m[label] for label in STATIC_LABELS)
    x, y, z = 0, 1, 2
    g2 = 2.0 * gravity
    # Paper convention, verbatim.
    Axx = (A1[x] - A2[x]) / g2 - 1.0
    Ayy = (A3[y] - A4[y]) / g2 - 1.0
    Azz = (A5[z] - A6[z]) / g2 - 1.0
    Axz = (A3[x] - A4[x]) / g2
    Axy = -(A5[x] - A6[x]) / g2
    Ayz = -(A1[y] - A2[y]) / g2
    Ayx = (A5[y] - A6[y]) / g2
    Azy = (A1[z] - A2[z]) / g2
    Azx = -(A3[z] - A4[z]) / g2
    # Three bias estimates per axis, one per pair of opposite positions, averaged.
    bias = ((A1 + A2) / 2.0 + (A3 + A4) / 2.0 + (A5 + A6) / 2.0) / 3.0
    manual = {
        "Axx": Axx,
        "Ayy": Ayy,
        "Azz": Azz,
        "Axz": Axz,
        "Axy": Axy,
        "Ayz": Ayz,
        "Ayx": Ayx,
        "Azy": Azy,
        "Azx": Azx,
    }
    out = {f"acc.bias.{a}": float(bias[i]) for i, a in enumerate(params.AXES)}
    for canonical, (name, sign) in params.MANUAL_NAMES.items():
        if name in manual:  # canonical = sign * manual (params.MANUAL_NAMES)
            out[canonical] = float(sign * manual[name])
    return out


# chi2 with 2 degrees of freedom exceeded with probability 0.001: -2 ln(0.001).
FACE_BIAS_CHI2_LIMIT = 13.8155


def face_bias_checks(means: dict[str, np.ndarray], sems: dict[str, np.ndarray]) -> list[dict]:
    """Model-misfit check: the accelerometer bias seen by each pair of opposite faces.

    Each channel's bias is estimated three times, as the mean of its readings
    on the x, y and z face pairs; under the linear model the three agree within
    their noise (the misalignment and scale terms cancel in each pair's mean).
    A spread beyond it (chi2 of the three about their weighted mean, 2 degrees of
    freedom, p < 0.001) means the model misses something: a non-linearity, a
    tilted face, a temperature step between faces.

    Returns one check dict (name, value = chi2, limit, passed, detail) per axis.
    """
    m, u = _check_means(means), _check_means(sems)
    checks = []
    for i, a in enumerate("xyz"):
        b = np.array([(m[f"{c}_up"][i] + m[f"{c}_dn"][i]) / 2.0 for c in "xyz"])
        ub = np.array([np.hypot(u[f"{c}_up"][i], u[f"{c}_dn"][i]) / 2.0 for c in "xyz"])
        w = 1.0 / np.maximum(ub, 1e-300) ** 2
        chi2 = float(np.sum(w * (b - np.sum(w * b) / np.sum(w)) ** 2))
        faces = ", ".join(f"{c} {v * 1e3:.3f}" for c, v in zip("xyz", b, strict=True))
        checks.append(
            {
                "name": f"model:face_bias.{a}",
                "value": chi2,
                "limit": FACE_BIAS_CHI2_LIMIT,
                "passed": chi2 <= FACE_BIAS_CHI2_LIMIT,
                "detail": f"acc.bias.{a} from the x, y, z face pairs (mm/s^2): {faces}; "
                f"spread {np.ptp(b) * 1e3:.3f} mm/s^2; chi2 of the three, 2 dof, p = 0.001",
            }
        )
    return checks


def accel_closed_form_std(sems: dict[str, np.ndarray], gravity: float) -> dict[str, float]:
    """Standard uncertainties of `accel_closed_form`, from those of the six means.

    Parameters
    ----------
    sems : label -> (3,) standard uncertainty of each mean, m/s^2.
    gravity : m/s^2.

    Returns
    -------
    dict of the same canonical names -> standard uncertainty.
    """
    s = _check_means(sems)
    out: dict[str, float] = {}
    axes = "xyz"
    for i, a in enumerate(axes):
        out[f"acc.bias.{a}"] = float(np.sqrt(sum(s[label][i] ** 2 for label in STATIC_LABELS)) / 6)
        for j, c in enumerate(axes):
            # Element (i, j) uses the difference of the j-up and j-down means of channel i.
            u = np.hypot(s[f"{c}_up"][i], s[f"{c}_dn"][i]) / (2.0 * gravity)
            out[f"acc.scale.{a}" if i == j else f"acc.misalign.{a}{c}"] = float(u)
    return out
