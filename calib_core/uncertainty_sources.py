"""Type B sources of IMU calibration budgets and the solver closures they are propagated through.

Science only. `EquipmentSpec` carries the reference equipment's specifications (SI); its
defaults are documented in docs/uncertainty.md. `static_accel_budgets` propagates local gravity
and the orientation-fixture (cube) angle errors through the static least-squares solver
(calib_core.solvers.multi_position); `rate_table_budgets` propagates the table's rate accuracy
through calib_core.solvers.rate_table. Passing ``spec=None`` (equipment unknown) gives budgets
labelled Type A only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from calib_core import params
from calib_core.solvers.multi_position import solve_accel_linear
from calib_core.solvers.rate_table import RatePoint, solve_rate_table
from calib_core.solvers.six_position import axis_vector
from calib_core.uncertainty import Budget, InputQuantity, budgets, monte_carlo

DEG = math.pi / 180.0


@dataclass(frozen=True)
class EquipmentSpec:
    """Reference equipment specifications (SI).

    Attributes
    ----------
    gravity_expanded : expanded uncertainty (k = 2) of the local gravity value, m/s^2.
    cube_angle : half-width of the rectangular error of each fixture face angle, rad.
    table_rate_rel : half-width of the rectangular relative rate error of the rate table, 1.
    """

    gravity_expanded: float = 2.0e-3
    cube_angle: float = 0.05 * DEG
    table_rate_rel: float = 1.0e-4


def static_inputs(
    labels: Sequence[str], gravity: float, spec: EquipmentSpec
) -> list[InputQuantity]:
    """Gravity (normal, U at k = 2) and two tilt angles per position (rectangular)."""
    out = [InputQuantity("gravity", gravity, spec.gravity_expanded, "normal", 2.0, unit="m/s^2")]
    for label in labels:
        for t in _tilt_axes(label):
            out.append(InputQuantity(f"cube.{label}.tilt_{t}", 0.0, spec.cube_angle, unit="rad"))
    return out


def _tilt_axes(label: str) -> str:
    """The two body axes a face angle error of position `label` rotates about."""
    up = label.split("_")[0]
    return "".join(a for a in params.AXES if a != up)


def static_reference(labels: Sequence[str], values: Mapping[str, float]) -> np.ndarray:
    """(K, 3) reference specific force of each position given gravity and the tilt angles."""
    g = values.get("gravity")
    rows = []
    for label in labels:
        f0 = axis_vector(label, g)
        rotvec = np.zeros(3)
        for t in _tilt_axes(label):
            rotvec[params.AXIS_INDEX[t]] = values.get(f"cube.{label}.tilt_{t}", 0.0)
        rows.append(Rotation.from_rotvec(rotvec).apply(f0))
    return np.array(rows)


def static_accel_budgets(
    labels: Sequence[str], means: np.ndarray, sem: np.ndarray, dof: float, gravity: float,
    spec: EquipmentSpec | None, mc_draws: int = 0, rng: np.random.Generator | None = None,
) -> tuple[dict[str, Budget], dict[str, tuple[float, float, float]] | None]:
    """Budgets (and optionally the Monte Carlo intervals) of acc.bias/scale/misalign.

    Parameters
    ----------
    labels : position labels ("x_up", ...); means, sem : (K, 3) m/s^2; dof : degrees of freedom
    of the sems; gravity : m/s^2; spec : equipment or None (Type A only); mc_draws : 0 = no MC.
    """
    means, sem = np.asarray(means, float), np.asarray(sem, float)

    def solve(values: Mapping[str, float]) -> dict[str, float]:
        vals = {"gravity": gravity, **values}
        return solve_accel_linear(static_reference(labels, vals), means, sem).params

    fit = solve_accel_linear(static_reference(labels, {"gravity": gravity}), means, sem)
    type_a = {n: (s, dof) for n, s in fit.std.items()}
    inputs = static_inputs(labels, gravity, spec) if spec is not None else []
    units = {n: ("m/s^2" if ".bias." in n else "1") for n in type_a}
    out = budgets(solve, inputs, type_a, units)
    mc = monte_carlo(solve, inputs, type_a, mc_draws, rng) if mc_draws and inputs else None
    return out, mc


def rate_table_budgets(
    points: Sequence[RatePoint], dof: float, spec: EquipmentSpec | None, mc_draws: int = 0,
    rng: np.random.Generator | None = None,
) -> tuple[dict[str, Budget], dict[str, tuple[float, float, float]] | None]:
    """Budgets of the rate-table gyro parameters with the table's relative rate error (Type B)."""
    points = list(points)

    def solve(values: Mapping[str, float]) -> dict[str, float]:
        e = values.get("table.rate_rel", 0.0)
        cal = solve_rate_table([replace(p, table_rate=p.table_rate * (1 + e)) for p in points])
        return {n: p.value for n, p in cal.parameters.items()}

    cal = solve_rate_table(points)
    type_a = {n: (p.std, dof) for n, p in cal.parameters.items()}
    inputs = [] if spec is None else [
        InputQuantity("table.rate_rel", 0.0, spec.table_rate_rel, unit="1")]
    units = {n: ("rad/s" if ".bias." in n else "1") for n in type_a}
    out = budgets(solve, inputs, type_a, units)
    mc = monte_carlo(solve, inputs, type_a, mc_draws, rng) if mc_draws and inputs else None
    return out, mc
