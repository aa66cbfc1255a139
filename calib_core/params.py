"""Canonical parameter names, used by results, archive, exports and reports.

Matrix convention (the archive's): f_meas = (I + M) f_true + b, so
``acc.misalign.xy`` is element row x, column y of M (how true y leaks into
measured x) and ``acc.scale.x`` is M[x, x] (K - 1).
Gyro: w_meas = (I + M_g) w_true + G f_true + b_g; ``gyr.gsens.xy`` is G[x, y]
in (rad/s)/(m/s^2).

High-g accelerometer terms (centrifuge): ``acc.k2.x`` / ``acc.k3.x`` multiply
f_x^2 / f_x^3 in the x output; ``acc.k2.xy`` multiplies the cross-axis square
f_y^2 in the x output; ``acc.kp.x_yz`` multiplies the product f_y f_z in the x
output (the pair in axis order: ``acc.kp.x_xy``, ``acc.kp.x_xz``, ``acc.kp.x_yz``).
"""

from __future__ import annotations

import re

AXES = ("x", "y", "z")
AXIS_INDEX = {a: i for i, a in enumerate(AXES)}

UNITS = {
    "acc.bias": "m/s^2",
    "acc.scale": "1",
    "acc.misalign": "1",
    "acc.k2": "1/(m/s^2)",
    "acc.k3": "1/(m/s^2)^2",
    "acc.kp": "1/(m/s^2)",
    "acc.noise": "m/s^2",
    "gyr.bias": "rad/s",
    "gyr.scale": "1",
    "gyr.misalign": "1",
    "gyr.gsens": "(rad/s)/(m/s^2)",
    "gyr.noise": "rad/s",
}

_NAME = re.compile(
    r"^(acc|gyr)\.(bias|scale|misalign|k2|k3|noise|gsens|kp)\.([xyz]{1,2}|[xyz]_[xyz]{2})$"
)


def unit_of(name: str) -> str:
    """SI unit string of a canonical parameter name."""
    validate(name)
    return UNITS[name.rsplit(".", 1)[0]]


def validate(name: str) -> str:
    """Return `name` if it is a canonical parameter name, else raise ValueError."""
    m = _NAME.match(name)
    if not m or f"{m[1]}.{m[2]}" not in UNITS:
        raise ValueError(f"not a canonical parameter name: {name!r}")
    kind, axes = m[2], m[3]
    if kind == "kp":
        # output axis, "_", a pair of distinct input axes in axis order
        if "_" not in axes or AXIS_INDEX[axes[2]] >= AXIS_INDEX[axes[3]]:
            raise ValueError(f"not a canonical parameter name: {name!r}")
        return name
    if "_" in axes:
        raise ValueError(f"not a canonical parameter name: {name!r}")
    two = kind in ("misalign", "gsens")
    if kind == "k2" and len(axes) == 2 and m[1] == "acc" and axes[0] != axes[1]:
        return name  # cross-axis square, e.g. acc.k2.xy (f_y^2 in the x output)
    if two != (len(axes) == 2) or (kind == "misalign" and axes[0] == axes[1]):
        raise ValueError(f"not a canonical parameter name: {name!r}")
    return name


def bias(sensor: str, axis: str) -> str:
    return f"{sensor}.bias.{axis}"


def matrix_names(sensor: str) -> list[list[str]]:
    """Names of the elements of I + M: diagonal -> scale, off-diagonal -> misalign.

    Returns a 3x3 nested list, e.g. ``[["acc.scale.x", "acc.misalign.xy", ...], ...]``.
    """
    return [
        [f"{sensor}.scale.{r}" if r == c else f"{sensor}.misalign.{r}{c}" for c in AXES]
        for r in AXES
    ]


def gsens_names() -> list[list[str]]:
    """Names of the elements of G, 3x3 nested list."""
    return [[f"gyr.gsens.{r}{c}" for c in AXES] for r in AXES]


ACC_LINEAR = [bias("acc", a) for a in AXES] + [n for row in matrix_names("acc") for n in row]
GYR_LINEAR = [bias("gyr", a) for a in AXES] + [n for row in matrix_names("gyr") for n in row]
GSENS = [n for row in gsens_names() for n in row]


# --- the MPU-6000 manual's names and signs (docs/methods.md 1 and 4.3) -------------------------
# The manual writes the misalignments as small angles with signs,
#     Ax = (1+Axx) ax + Axz ay - Axy az + a0x
#     Ay = -Ayz ax + (1+Ayy) ay + Ayx az + a0y
#     Az =  Azy ax - Azx ay + (1+Azz) az + a0z
# and the gyro the same way with G (the integral method's Gxz = M[x, y], Gxy = -M[x, z],
# ...). Its published protocol prints all 39 parameters of the program, the gyro block
# first: scales, misalignments, biases Gox..Goz, g-sensitivities Gaxx..Gazz (G[i, j] =
# (W_i(j up) - W_i(j down)) / 2g, the canonical sign), noise Gstdx..Gstdz; then the
# accelerometer's scales, misalignments, biases Aox..Aoz (a0x of the equations) and noise
# Astdx..Astdz. The order is the paper's tolerance list (docs/methods.md 4.3).
# canonical = sign * manual.

# Canonical row/column of the misalignment -> (manual suffix, sign), in the closed form's
# order Axz, Axy, Ayz, Ayx, Azy, Azx: M[x, y] = +Axz, M[x, z] = -Axy, ...
_MISALIGN = {
    "xy": ("xz", +1.0), "xz": ("xy", -1.0),
    "yx": ("yz", -1.0), "yz": ("yx", +1.0),
    "zx": ("zy", +1.0), "zy": ("zx", -1.0),
}  # fmt: skip


def _table() -> dict[str, tuple[str, float]]:
    out: dict[str, tuple[str, float]] = {}
    for sensor, letter in (("gyr", "G"), ("acc", "A")):
        for a in AXES:
            out[f"{sensor}.scale.{a}"] = (f"{letter}{a}{a}", 1.0)
        for rc, (suffix, sign) in _MISALIGN.items():
            out[f"{sensor}.misalign.{rc}"] = (f"{letter}{suffix}", sign)
        for a in AXES:
            out[f"{sensor}.bias.{a}"] = (f"{letter}o{a}", 1.0)
        if sensor == "gyr":
            for r in AXES:
                for c in AXES:
                    out[f"gyr.gsens.{r}{c}"] = (f"Ga{r}{c}", 1.0)
        for a in AXES:
            out[f"{sensor}.noise.{a}"] = (f"{letter}std{a}", 1.0)
    return out


# The 39 names in the order of the published protocol (dicts keep their order).
MANUAL_NAMES: dict[str, tuple[str, float]] = _table()


def manual_order(name: str) -> int:
    """Position of a canonical parameter in the manual's protocol (unnamed ones after)."""
    return _ORDER.get(name, len(_ORDER))


_ORDER = {name: i for i, name in enumerate(MANUAL_NAMES)}


def manual_name(name: str, value: float | None) -> tuple[str, float | None]:
    """(the manual's name, the value in the manual's sign) of a canonical parameter;
    ("", None) when the manual does not name it."""
    if name not in MANUAL_NAMES:
        return "", None
    manual, sign = MANUAL_NAMES[name]
    return manual, None if value is None else sign * value
