"""Local gravity and Earth rotation.

The gravity value used for a calibration is archived with every result, so the
choice of model is always visible.
"""

from __future__ import annotations

import math

import numpy as np

from calib_core.units import STANDARD_GRAVITY

EARTH_RATE = 7.2921150e-5  # rad/s, IERS
FREE_AIR_GRADIENT = 3.086e-6  # m/s^2 per metre of height

# WGS84 normal gravity (Somigliana), NIMA TR8350.2
_WGS84_GAMMA_E = 9.7803253359  # m/s^2 at the equator
_WGS84_K = 0.00193185265241
_WGS84_E2 = 0.00669437999013
_WGS84_A = 6378137.0
_WGS84_F = 1.0 / 298.257223563
_WGS84_M = 0.00344978650684


def gravity_helmert(latitude_deg: float, height_m: float = 0.0) -> float:
    """Helmert's 1901 normal gravity with the free-air height correction.

    g = 9.80616 (1 - 0.0026373 cos 2phi + 0.0000059 cos^2 2phi) - 3.086e-6 h

    Parameters
    ----------
    latitude_deg : geodetic latitude, degrees.
    height_m : height above the ellipsoid / sea level, m.

    Returns
    -------
    float, m/s^2
    """
    c2 = math.cos(2.0 * math.radians(latitude_deg))
    return 9.80616 * (1.0 - 0.0026373 * c2 + 0.0000059 * c2 * c2) - FREE_AIR_GRADIENT * height_m


def gravity_wgs84(latitude_deg: float, height_m: float = 0.0) -> float:
    """WGS84 normal gravity (Somigliana) with the second-order height correction.

    latitude_deg, height_m : floats or arrays of one shape. Returns m/s^2, of their shape.
    """
    s2 = np.sin(np.radians(latitude_deg)) ** 2
    gamma = _WGS84_GAMMA_E * (1.0 + _WGS84_K * s2) / np.sqrt(1.0 - _WGS84_E2 * s2)
    a, f, m = _WGS84_A, _WGS84_F, _WGS84_M
    g = gamma * (1.0 - 2.0 / a * (1.0 + f + m - 2.0 * f * s2) * height_m + 3.0 / a**2 * height_m**2)
    return float(g) if np.ndim(g) == 0 else g


def local_gravity(
    model: str,
    latitude_deg: float | None = None,
    height_m: float = 0.0,
    measured: float | None = None,
) -> float:
    """Gravity magnitude for a site, by the named model.

    Parameters
    ----------
    model : "standard", "helmert", "wgs84" or "measured".
    latitude_deg, height_m : site position (helmert, wgs84).
    measured : an absolute-gravimeter value in m/s^2 (measured).
    """
    if model == "standard":
        return STANDARD_GRAVITY
    if model == "measured":
        if measured is None or not (9.7 < measured < 9.9):
            raise ValueError(
                f"measured gravity must be given in m/s^2 (9.7..9.9), got {measured!r}"
            )
        return float(measured)
    if model in ("helmert", "wgs84"):
        if latitude_deg is None or not -90.0 <= latitude_deg <= 90.0:
            raise ValueError(
                f"gravity model {model!r} needs a latitude in degrees, got {latitude_deg!r}"
            )
        fn = gravity_helmert if model == "helmert" else gravity_wgs84
        return fn(latitude_deg, height_m)
    raise ValueError(
        f"unknown gravity model {model!r}; expected standard, helmert, wgs84 or measured"
    )


def earth_rate_local(latitude_deg: float) -> np.ndarray:
    """Earth rotation in the local North-East-Down frame, rad/s, shape (3,)."""
    phi = math.radians(latitude_deg)
    return np.array([EARTH_RATE * math.cos(phi), 0.0, -EARTH_RATE * math.sin(phi)])


def radii_of_curvature(latitude_rad: float) -> tuple[float, float]:
    """WGS84 meridian and transverse radii of curvature R_N, R_E, m (Groves eqs. 2.105-2.106).

    Parameters
    ----------
    latitude_rad : geodetic latitude, rad (a float or an array).
    """
    s2 = np.sin(latitude_rad) ** 2
    den = 1.0 - _WGS84_E2 * s2
    rn, re = _WGS84_A * (1.0 - _WGS84_E2) / den**1.5, _WGS84_A / np.sqrt(den)
    return (float(rn), float(re)) if np.ndim(rn) == 0 else (rn, re)
