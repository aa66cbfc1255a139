"""The uncertainty budget of a solved run: each parameter's GUM budget from its procedure's model.

Science only. `run_budgets` takes the solved Calibration, the segments it was solved from and the
reference equipment's specification (`uncertainty_sources.EquipmentSpec`, or None when the run
names no equipment) and returns a `Budget` per parameter that has a standard uncertainty:

The Type B model is the procedure object's (`calib_core.procedures.Procedure.uncertainty`, one
of the `uncertainty_sources.*_model` functions): for six_position / six_position_integral
(least-squares linear accelerometer model) local gravity and the fixture's face angles through
the static fits and the turn angles through the integral; for rate_table the table's relative
rate error. A procedure without a model, or a solver setting its model does not cover, gets
the Type A part only, labelled so, with a note naming what is not modelled (never a smaller U
presented as a full budget).

The Type A row is the archived standard uncertainty of the fit; its degrees of freedom are the
smallest effective sample count of the run's statics minus one (infinite when the solver does not
report one), or the position fit's own (K - 4) where its residuals set the uncertainty
(`misfit_dofs`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from calib_core import procedures
from calib_core.calibration import Calibration
from calib_core.params import AXES
from calib_core.recording import Recording
from calib_core.stats import misfit_scale
from calib_core.uncertainty import Budget, Solve, budgets
from calib_core.uncertainty_sources import EquipmentSpec


def type_a_dof(cal: Calibration) -> float:
    """Degrees of freedom of the fit's standard uncertainties: min effective samples - 1."""
    counts = cal.info.get("effective_sample_counts_min") or {}
    return max(min(counts.values()) - 1.0, 1.0) if counts else math.inf


def misfit_dofs(cal: Calibration) -> dict[str, float]:
    """Parameters whose standard uncertainty the position fit scaled by its residuals
    (`calib_core.stats.misfit_scale`) -> the fit's degrees of freedom: that uncertainty
    is estimated from those residuals, not from the samples' noise. The accelerometer
    row of a scaled axis (noise apart); of the gyro, the terms of its static fit (bias,
    g-sensitivity), not the turns' scale and misalignment."""
    dof = cal.info.get("fit_dof_per_axis")
    if dof is None:
        return {}
    dofs = list(dof) if isinstance(dof, list) else [dof] * 3
    out: dict[str, float] = {}
    for sensor, kinds in (("acc", None), ("gyr", ("bias", "gsens"))):
        chi2 = cal.info.get(f"{sensor}_fit_chi2")
        if chi2 is None:
            continue
        if sensor == "gyr" and "positions" in cal.info:  # its static fit is affine: K - 4
            dofs = [cal.info["positions"] - 4] * 3
        scaled = misfit_scale(np.asarray(chi2, dtype=float), np.asarray(dofs))
        for name in cal.parameters:
            part = name.split(".")
            if part[0] != sensor or part[1] == "noise" or (kinds and part[1] not in kinds):
                continue
            row = AXES.index(part[2][0])
            if scaled[row] > 1.0:
                out[name] = float(dofs[row])
    return out


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
    dof, misfit = type_a_dof(cal), misfit_dofs(cal)
    type_a = {
        n: (p.std, misfit.get(n, dof)) for n, p in cal.parameters.items() if p.std is not None
    }
    units = {n: p.unit for n, p in cal.parameters.items()}
    estimates = {n: p.value for n, p in cal.parameters.items()}
    # Type A only (the values as they are, no Type B input), with the reason if one is given.
    type_a_only = functools.partial(
        budgets, _constant(estimates), [], type_a, units, estimates=estimates
    )
    if spec is None:
        return type_a_only()
    proc = procedures.BY_NAME.get(cal.procedure)
    if proc is None or proc.uncertainty is None:
        reason = f"Type B sources of procedure {cal.procedure!r} not modelled"
        return type_a_only(reason=reason)
    # The model reads the procedure's settings as solved: typed, its defaults filled in.
    solve, inputs, notes = proc.uncertainty(cal, segments, proc.settings.parse(settings), spec)
    if solve is None:
        return type_a_only(reason=notes[0])
    return budgets(solve, inputs, type_a, units, estimates=estimates, notes=notes)


def _constant(estimates: Mapping[str, float]) -> Solve:
    return lambda values: dict(estimates)


def budgets_doc(budgets_: Mapping[str, Budget]) -> dict[str, dict[str, Any]]:
    """name -> Budget.to_dict(), sorted by name (the archive's and the reports' form)."""
    return {n: budgets_[n].to_dict() for n in sorted(budgets_)}
