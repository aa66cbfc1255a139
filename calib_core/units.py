"""Unit conversion at the edges: everything inside the pipeline is SI.

Accelerations in m/s^2, angular rates in rad/s, time in s, temperature in deg C.
"""

from __future__ import annotations

import math

STANDARD_GRAVITY = 9.80665  # m/s^2, CGPM 1901
DEG = math.pi / 180.0  # rad per degree
ARCSEC = DEG / 3600.0  # rad per second of arc

# Factor that turns a value in the named unit into SI.
ACCELERATION_UNITS: dict[str, float] = {
    "m/s^2": 1.0,
    "m/s2": 1.0,
    "g": STANDARD_GRAVITY,
    "mg": STANDARD_GRAVITY * 1e-3,
    "ug": STANDARD_GRAVITY * 1e-6,
}
ANGULAR_RATE_UNITS: dict[str, float] = {
    "rad/s": 1.0,
    "deg/s": DEG,
    "deg/h": DEG / 3600.0,
    "rpm": 2.0 * math.pi / 60.0,
}
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
ANGLE_UNITS: dict[str, float] = {
    "deg": DEG,
    "°": DEG,
    "arcmin": DEG / 60.0,
    "arcsec": ARCSEC,
    "rad": 1.0,
    "mrad": 1e-3,
    "urad": 1e-6,
}


def _factor(table: dict[str, float], unit: str, quantity: str) -> float:
    try:
        return table[unit]
    except KeyError:
        known = ", ".join(sorted(table))
        raise ValueError(f"unknown {quantity} unit {unit!r}; expected one of: {known}") from None


def acceleration_factor(unit: str) -> float:
    """Factor converting an acceleration in `unit` to m/s^2."""
    return _factor(ACCELERATION_UNITS, unit, "acceleration")


def angular_rate_factor(unit: str) -> float:
    """Factor converting an angular rate in `unit` to rad/s."""
    return _factor(ANGULAR_RATE_UNITS, unit, "angular rate")


def time_factor(unit: str) -> float:
    """Factor converting a time in `unit` to s."""
    return _factor(TIME_UNITS, unit, "time")
