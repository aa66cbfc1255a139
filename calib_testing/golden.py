"""The calibration of the golden export files (tests/golden/; their comment headers say the
same): values chosen by hand so that every firmware's sign and unit convention shows."""

from __future__ import annotations

from calib_core.calibration import Calibration


def firmware_calibration() -> Calibration:
    """Biases (m/s^2, rad/s) and accelerometer scale factors (1): what PX4 and ArduPilot
    both carry, with their standard uncertainties."""
    cal = Calibration("six_position_integral", 9.80665)
    for a, b, s in zip("xyz", (0.125, -0.25, 0.5), (0.01, -0.02, 0.004), strict=True):
        cal.add(f"acc.bias.{a}", b, 1e-4)
        cal.add(f"acc.scale.{a}", s, 1e-5)
    for a, b in zip("xyz", (0.0125, -0.003, 0.02), strict=True):
        cal.add(f"gyr.bias.{a}", b, 1e-5)
    return cal


def golden_calibration() -> Calibration:
    """`firmware_calibration` and three parameters neither firmware has a place for."""
    cal = firmware_calibration()
    cal.add("acc.misalign.xy", 0.002, 1e-5)
    cal.add("gyr.scale.x", 0.005, 1e-5)
    cal.add("gyr.noise.x", 1e-4)
    return cal
