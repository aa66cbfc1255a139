"""Synthetic lab runs with known truth (the test oracle)."""

from calib_core.simulate.lab_run import (
    ROTATION_LABELS,
    STATIC_LABELS,
    SimulatedRun,
    TrueErrors,
    Turns,
    axis_vector,
    random_errors,
    rotation_profile,
    six_position_integral_run,
)

__all__ = [
    "ROTATION_LABELS",
    "STATIC_LABELS",
    "SimulatedRun",
    "TrueErrors",
    "Turns",
    "axis_vector",
    "random_errors",
    "rotation_profile",
    "six_position_integral_run",
]
