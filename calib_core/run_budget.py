"""The uncertainty budget of a solved run: each parameter's GUM budget from its procedure's model.

Science only. `run_budgets` takes the solved Calibration, the segments it was solved from and the
reference equipment's specification (`uncertainty_sources.EquipmentSpec`, or None when the run
names no equipment) and returns a `Budget` per parameter that has a standard uncertainty:

- six_position / six_position_integral (default least-squares linear accelerometer model):
  local gravity and the fixture's face angles through the static accelerometer and gyro fits,
  and for the integral method the turn angle of each rotation and the same face angles through
  `uncertainty_sources.integral_matrix`;
- rate_table: the table's relative rate error through the rate-table solver;
- any other procedure or solver setting: the Type A part only, labelled so, with a note
  naming what is not modelled (never a smaller U presented as a full budget).

The Type A row is the archived standard uncertainty of the fit; its degrees of freedom are the
smallest effective sample count of the run's statics minus one (infinite when the solver does not
report one).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from calib_core.calibration import Calibration
from calib_core.recording import Recording
from calib_core.solvers.integral import ROTATION_LABELS
from calib_core.solvers.rate_table import rate_points
from calib_core.solvers.six_position import STATIC_LABELS
from calib_core.stats import channel_stats
from calib_core.uncertainty import Budget, InputQuantity, Solve, budgets
from calib_core.uncertainty_sources import (
    EquipmentSpec,
    integral_inputs,
    rate_table_solve,
    static_inputs,
    static_solve,
)

STATIC_PROCEDURES = ("six_position", "six_position_integral")
Model = tuple[Solve | None, list[InputQuantity], tuple[str, ...]]


def type_a_dof(cal: Calibration) -> float:
    """Degrees of freedom of the fit's standard uncertainties: min effective samples - 1."""
    counts = cal.info.get("effective_sample_counts_min") or {}
    return max(min(counts.values()) - 1.0, 1.0) if counts else math.inf


def run_budgets(
    cal: Calibration,
    segments: Mapping[str, Recording],
    settings: Mapping[str, Any],
    spec: EquipmentSpec | None,
) -> dict[str, Budget]:
    """GUM budget of every parameter of `cal` that has a standard uncertainty.

    Parameters
    ----------
    cal : the solved calibration (cal.procedure names the model).
    segments : label -> Recording the calibration was solved from (preprocessed, SI).
    settings : the run's solver settings (accel_solver, accel_model, settle_s, record_s, ...).
    spec : the reference equipment's specification; None when the run names no equipment.
    """
    dof = type_a_dof(cal)
    type_a = {n: (p.std, dof) for n, p in cal.parameters.items() if p.std is not None}
    units = {n: p.unit for n, p in cal.parameters.items()}
    estimates = {n: p.value for n, p in cal.parameters.items()}
    if spec is None:
        return budgets(_constant(estimates), [], type_a, units, estimates=estimates)
    solve, inputs, notes = _model(cal, segments, settings, spec)
    if solve is None:
        return budgets(_constant(estimates), [], type_a, units, estimates=estimates,
                       reason=notes[0])
    return budgets(solve, inputs, type_a, units, estimates=estimates, notes=notes)


def _constant(estimates: Mapping[str, float]) -> Solve:
    return lambda values: dict(estimates)


def _model(
    cal: Calibration, segments: Mapping[str, Recording], settings: Mapping[str, Any],
    spec: EquipmentSpec,
) -> Model:
    """The procedure's solve closure over its Type B inputs, the inputs and notes."""
    procedure = cal.procedure
    if procedure in STATIC_PROCEDURES:
        default = (settings.get("accel_solver", "least_squares") == "least_squares"
                   and settings.get("accel_model", "linear") == "linear")
        if default:
            return _static_model(cal, segments, spec)
        return None, [], ("Type B sources not modelled for accel_solver/accel_model "
                          "other than least_squares/linear",)
    if procedure == "rate_table":
        kwargs = {k: float(settings[k]) for k in ("settle_s", "record_s")
                  if settings.get(k) is not None}
        solve = rate_table_solve(rate_points(list(segments.values()), **kwargs))
        inputs = ([] if spec.table_rate_rel is None else
                  [InputQuantity("table.rate_rel", 0.0, spec.table_rate_rel, unit="1")])
        if not inputs:
            return None, [], spec.missing("table_rate_rel")
        return solve, inputs, ()
    return None, [], (f"Type B sources of procedure {procedure!r} not modelled",)


def _static_model(
    cal: Calibration, segments: Mapping[str, Recording], spec: EquipmentSpec
) -> Model:
    """Gravity and face angles through the static fits, turn angles through the integral."""
    labels = [label for label in STATIC_LABELS if label in segments]
    stats = [(channel_stats(segments[label].acc), channel_stats(segments[label].gyr))
             for label in labels]
    acc_mean, acc_sem = (np.array([getattr(a, f) for a, _ in stats]) for f in ("mean", "sem"))
    gyr_mean, gyr_sem = (np.array([getattr(g, f) for _, g in stats]) for f in ("mean", "sem"))
    rotations = [label for label in ROTATION_LABELS if label in segments]
    turns = cal.info.get("turns")
    integral = None
    if rotations and turns is not None:
        integral = (np.eye(3) + cal.matrix("gyr"), int(turns), rotations)
    solve = static_solve(labels, (acc_mean, acc_sem), (gyr_mean, gyr_sem), cal.gravity, integral)
    inputs = static_inputs(labels, cal.gravity, spec)
    notes = spec.missing("cube_angle")
    if integral is not None:
        inputs += integral_inputs(rotations, spec)
        notes += spec.missing("turn_angle")
    return solve, inputs, notes


def budgets_doc(budgets_: Mapping[str, Budget]) -> dict[str, dict[str, Any]]:
    """name -> Budget.to_dict(), sorted by name (the archive's and the reports' form)."""
    return {n: budgets_[n].to_dict() for n in sorted(budgets_)}

