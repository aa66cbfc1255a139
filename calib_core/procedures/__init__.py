"""Calibration procedures: from labelled segments to a Calibration (docs/procedures.md).

A procedure is one `Procedure` object in one module of this package (`base`: what it
declares): its segments and labels, typed settings, the lab conditions that apply to it, its
solver, its uncertainty model, its physical-bounds hint and model checks. `ALL` is the one
list of them; `PROCEDURES` maps each name to its solver.

A procedure takes the segments of one lab run (Recordings keyed by label), the local gravity
and its settings, and returns a Calibration with every parameter's standard uncertainty,
residuals per segment and solver facts in `info`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

from calib_core.calibration import Calibration, StepRecord
from calib_core.checks import check_physical_bounds
from calib_core.preprocess.motion import static_motion_checks
from calib_core.procedures.base import COMMON_SETTINGS, Procedure, Solver
from calib_core.procedures.centrifuge import CENTRIFUGE
from calib_core.procedures.equipment_free import EQUIPMENT_FREE
from calib_core.procedures.integral import INTEGRAL, solve_integral_procedure
from calib_core.procedures.multi_position import MULTI_POSITION
from calib_core.procedures.rate_table import RATE_TABLE, solve_rate_table_procedure
from calib_core.procedures.sensor_array import SENSOR_ARRAY
from calib_core.procedures.six_position import SIX_POSITION, solve_six_position
from calib_core.procedures.six_position_integral import (
    SIX_POSITION_INTEGRAL,
    solve_six_position_integral,
)
from calib_core.procedures.static_bias import STATIC_BIAS, solve_static_bias_procedure
from calib_core.procedures.tables import TABLES
from calib_core.recording import Recording
from calib_core.settings import Setting, SettingError, Settings

__all__ = [
    "ALL",
    "BY_NAME",
    "COMMON_SETTINGS",
    "PROCEDURES",
    "TABLES",
    "Procedure",
    "Setting",
    "SettingError",
    "Settings",
    "get",
    "solve",
    "solve_integral_procedure",
    "solve_rate_table_procedure",
    "solve_six_position",
    "solve_six_position_integral",
    "solve_static_bias_procedure",
    "solve_step",
    "validate_settings",
]

# The one list of procedures, in the order the documentation gives them.
ALL: tuple[Procedure, ...] = (
    SIX_POSITION,
    SIX_POSITION_INTEGRAL,
    INTEGRAL,
    MULTI_POSITION,
    EQUIPMENT_FREE,
    SENSOR_ARRAY,
    RATE_TABLE,
    STATIC_BIAS,
    CENTRIFUGE,
)
BY_NAME: dict[str, Procedure] = {p.name: p for p in ALL}
PROCEDURES: dict[str, Callable[[dict[str, Recording], float, Any], Calibration]] = {
    p.name: p.solver for p in ALL
}


def get(name: str) -> Procedure:
    """The procedure of that name; ValueError naming the known ones."""
    try:
        return BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown procedure {name!r}; expected one of {sorted(BY_NAME)}") from None


def validate_settings(procedure: str, settings: Mapping[str, Any]) -> Any:
    """The whole ``[run.settings]`` of a run of `procedure`, checked (`Procedure.validate`).

    Returns the procedure's own settings typed, defaults filled in (`Settings.parse`).
    Raises SettingError (a ValueError) naming the key: unknown (with the closest valid
    one), wrong type or out of bounds (with the value and the allowed range). An unknown
    key with no valid one close to it that another procedure declares says whose it is (a
    run written for another procedure, or the wrong procedure).
    """
    proc = get(procedure)
    try:
        return proc.validate(settings)
    except SettingError as exc:
        owners = [p.name for p in ALL if p is not proc and exc.key in p.settings]
        # Only where no valid key is close: a near one is the likelier meaning.
        if "; expected one of " not in exc.problem or not owners:
            raise
        whose = ", ".join(owners[:-1]) + " and " * (len(owners) > 1) + owners[-1]
        raise SettingError(exc.key, f"{exc.problem}; {exc.key} is a setting of {whose}") from None


def solve(
    procedure: str,
    segments: dict[str, Recording],
    gravity: float,
    settings: dict[str, Any],
    solver: Solver | None = None,
) -> Calibration:
    """Run the named procedure on labelled segments.

    Parameters
    ----------
    procedure : a key of PROCEDURES.
    segments : label -> Recording (SI units).
    gravity : local gravity, m/s^2.
    settings : the run's settings (``[run.settings]``), checked whole against the
        procedure's (docs/procedures.md).
    solver : in place of the procedure's own, one that finds the same numbers from
        elsewhere (a record streamed in chunks; `segments` then empty). Either takes the
        procedure's typed settings (`Procedure.settings.parse`).

    Returns
    -------
    Calibration with every parameter's standard uncertainty, residuals per
    segment and solver facts (`info`).

    Raises
    ------
    ValueError for an unknown procedure, a refused setting, a gravity outside 9.7..9.9
    m/s^2, missing segments, or a parameter beyond physical bounds (with what to check).
    """
    proc = get(procedure)
    typed = validate_settings(procedure, settings or {})
    if not (9.7 < gravity < 9.9):
        raise ValueError(f"gravity must be the local value in m/s^2 (9.7..9.9), got {gravity!r}")
    cal = (solver or proc.solver)(segments, gravity, typed)
    cal.info.setdefault("solver_checks", []).extend(
        static_motion_checks(proc.static_segments, segments)
    )
    check_physical_bounds(cal, proc.bounds_hint)
    return cal


def solve_step(
    segments: dict[str, Recording],
    settings: dict[str, Any],
    held_out: frozenset[str] | set[str] = frozenset(),
    solver: Solver | None = None,
) -> tuple[Calibration, StepRecord]:
    """The solve step of a run: the one StepRecord a solve leaves in the archive.

    Parameters
    ----------
    segments : label -> Recording, after preprocessing.
    settings : {"procedure", "gravity" (m/s^2), ...} plus the run's settings (checked whole
        against the procedure's; its own keys are the solver's).
    held_out : labels of verification segments: kept out of the fit, checked after.
    solver : as `solve`'s.

    Returns the Calibration and the StepRecord "solve" (settings used, wall time,
    sample counts, condition number, warnings, held-out labels).
    """
    procedure = settings.get("procedure")
    if procedure is None or "gravity" not in settings:
        raise ValueError("solve step: settings need 'procedure' and 'gravity'")
    gravity = float(settings["gravity"])
    proc_settings = {k: v for k, v in settings.items() if k not in ("procedure", "gravity")}
    fit = {k: v for k, v in segments.items() if k not in held_out}
    started = time.perf_counter()
    cal = solve(procedure, fit, gravity, proc_settings, solver)
    scalars = {k: v for k, v in cal.info.items() if isinstance(v, int | float | str)}
    record = StepRecord(
        name="solve",
        # The run's settings as given, the solver's defaults filled in.
        settings={
            "procedure": procedure,
            "gravity": gravity,
            **proc_settings,
            **get(procedure).settings.parse(proc_settings).as_dict(),
        },
        statistics={
            **scalars,
            "seconds": round(time.perf_counter() - started, 4),
            "parameters": len(cal.parameters),
            "segments": len(fit),
            "sample_counts": cal.info.get("sample_counts", {}),
            "condition_number": cal.info.get("condition_number"),
            "turns": cal.info.get("turns"),
            "replaced_samples": cal.info.get("replaced_samples", {}),
            "held_out": sorted(held_out),
            "warnings": list(cal.warnings),
        },
    )
    return cal, record
