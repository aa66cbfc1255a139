"""The static-bias procedure: one long static record -> gyro bias and noise (Allan deviation),
accelerometer bias when the up axis is given (docs/methods.md 2.5).

Settings: `STATIC_BIAS.settings` (docs/procedures.md).
"""

from __future__ import annotations

from typing import Any

from calib_core.calibration import Calibration
from calib_core.condition_rules import ConditionUse
from calib_core.procedures.base import (
    ATTITUDES,
    ENVIRONMENT,
    EQUIPMENT_PRECHECK,
    METHODS,
    TABLE_POSITION,
    Procedure,
    Setting,
    Settings,
)
from calib_core.recording import Recording
from calib_core.settings import SettingsIn
from calib_core.solvers.static_bias import solve_static_bias, solve_static_bias_stream

MEMORY_LIMIT = "memory_limit_mb"  # MB (10^6 bytes)
UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")
# Where the Earth rate points in the fixture's frame: here and in six_position's
# gyro_from_earth_rate (calib_core.solvers.earth_rate_faces).
LATITUDE_DEG = Setting(
    "latitude_deg", "number", "deg", None, "site latitude (the Earth rate's projection)",
    low=-90.0, high=90.0)  # fmt: skip
HEADING_DEG = Setting(
    "heading_deg", "number", "deg", None,
    "fixture heading from north (the Earth rate's projection)", low=-360.0, high=360.0)  # fmt: skip
SETTINGS = Settings(
    Setting("up_axis", "text", "", None,
            "body axis pointing up; given, acc.bias.* is the mean minus gravity along it",
            choices=UP_AXES),
    LATITUDE_DEG,
    HEADING_DEG,
    Setting("remove_earth_rate", "bool", "", False,
            "subtract the Earth rate from the gyro means (FOG/RLG grade; level z-up fixture)"),
    Setting("n_sigma", "number", "1", 3.0,
            "outlier rule: samples beyond n_sigma std are left out of mean and std", low=0.0,
            low_open=True),
    Setting(MEMORY_LIMIT, "number", "MB", 1000.0,
            "memory limit: a record whose files are larger is streamed in chunks (one pass "
            "over the file, then one over its samples) instead of read into memory, unless "
            "its settings need the whole record; the results are the same either way",
            low=1.0),
    name="StaticBiasSettings",
)  # fmt: skip
# Settings that choose how the record is read, not what is solved.
READING = (MEMORY_LIMIT,)


def solver_settings(settings: SettingsIn) -> dict[str, Any]:
    """The solver's keyword arguments: the typed settings given, without READING."""
    s = SETTINGS.parse(settings).as_dict()
    return {k: v for k, v in s.items() if v is not None and k not in READING}


def solve_static_bias_procedure(
    segments: dict[str, Recording], gravity: float, settings: SettingsIn = None
) -> Calibration:
    """Static bias and noise of one long static segment (any label).

    settings : typed `SETTINGS` (see calib_core.solvers.static_bias.solve_static_bias); a
        mapping is parsed.
    """
    kwargs = solver_settings(settings)
    if len(segments) != 1:
        raise ValueError(
            f"static_bias: expected one static segment, got {len(segments)} ({', '.join(segments)})"
        )
    return solve_static_bias(next(iter(segments.values())), gravity=gravity, **kwargs)


def solve_static_bias_streamed(chunks, settings: SettingsIn, **streaming) -> Calibration:
    """The solve of one static record streamed in chunks (longer than memory).

    chunks : called once per pass, a fresh iterator of (t, gyr, acc) chunks.
    settings : `STATIC_BIAS.settings` (the reading ones, such as memory_limit_mb, left out).
    streaming : label, first, gravity and how the pass runs (history, threads, motion),
        as `calib_core.solvers.static_bias.solve_static_bias_stream` takes them.
    """
    return solve_static_bias_stream(chunks, **streaming, **solver_settings(settings))


STATIC_BIAS = Procedure(
    name="static_bias",
    summary="one long static record: gyro bias and noise (Allan deviation), accelerometer "
    "bias when the up axis is known",
    segments="one static segment (any label), >= 60 min at >= 100 Hz",
    solver=solve_static_bias_procedure,
    settings=SETTINGS,
    conditions=ENVIRONMENT
    + ATTITUDES
    + (
        TABLE_POSITION,
        *EQUIPMENT_PRECHECK,
        ConditionUse("static_record_min", "length of the static record", f"{METHODS} 2.5"),
        ConditionUse(
            "static_temperature_spread_c",
            "chamber (ambient) temperature over the record: reference channel "
            "chamber_temperature or ambient_temperature; without one, the sensor's "
            "own temperature",
            "rate-table procedure, 60-min static bias run",
        ),
    ),
    reference="docs/methods.md 2.5; IEEE Std 952 (Allan variance)",
    model_checks="record length (a warning under 60 min); outliers beyond n_sigma; Allan "
    "deviation fits (angle random walk, bias instability, rate random walk)",
    static_segments="all",
    stream_solver=solve_static_bias_streamed,
)
