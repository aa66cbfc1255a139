"""Type B sources of IMU calibration budgets and the solver closures they are propagated through.

Science only. `EquipmentSpec` carries the reference equipment's specifications (SI); its
defaults are documented in docs/uncertainty.md. `static_accel_budgets` propagates local gravity
and the orientation-fixture (cube) angle errors through the static least-squares solver
(calib_core.solvers.multi_position); `integral_gyro_budgets` propagates the turn angle error of
each rotation and the same fixture angles through the integral method
(calib_core.solvers.integral); `rate_table_budgets` propagates the table's rate accuracy through
calib_core.solvers.rate_table. Passing ``spec=None`` (equipment unknown) gives budgets labelled
Type A only; a field of the spec set to None is a source whose equipment the run does not name
(not evaluated, and said in the budget's notes).

A procedure's uncertainty model (`calib_core.procedures.Procedure.uncertainty`) is one of the
`*_model` functions here: (cal, segments, settings, spec) -> (solve closure or None, the Type B
inputs, notes); None as closure means Type A only, the first note saying why.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from calib_core import params
from calib_core.calibration import Calibration
from calib_core.recording import Recording
from calib_core.solvers.integral import ROTATION_LABELS, pooled_static_gyro
from calib_core.solvers.multi_position import solve_accel_linear, solve_gyro_static
from calib_core.solvers.rate_table import RatePoint, plateau_window, rate_points, solve_rate_table
from calib_core.solvers.six_position import STATIC_LABELS, axis_vector
from calib_core.stats import channel_stats
from calib_core.uncertainty import Budget, InputQuantity, budgets, monte_carlo
from calib_core.units import DEG

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class EquipmentSpec:
    """Reference equipment specifications (SI).

    Attributes
    ----------
    gravity_expanded : expanded uncertainty (k = 2) of the local gravity value, m/s^2.
    cube_angle : half-width of the rectangular error of each fixture face angle, rad.
    table_rate_rel : half-width of the rectangular relative rate error of the rate table, 1.
    turn_angle : half-width of the rectangular error of the angle each integral-method rotation
        turns (the fixture stopping off its start mark), rad.

    None: the run does not name the equipment; the source is not evaluated.
    """

    gravity_expanded: float = 2.0e-3
    cube_angle: float | None = 0.05 * DEG
    table_rate_rel: float | None = 1.0e-4
    turn_angle: float | None = 0.1 * DEG

    def missing(self, *names: str) -> tuple[str, ...]:
        """Notes for the named sources that are not evaluated (their equipment unknown)."""
        return tuple(
            f"{n} not evaluated: equipment not named in the run"
            for n in names
            if getattr(self, n) is None
        )


def static_inputs(
    labels: Sequence[str], gravity: float, spec: EquipmentSpec
) -> list[InputQuantity]:
    """Gravity (normal, U at k = 2) and two tilt angles per position (rectangular)."""
    out = [InputQuantity("gravity", gravity, spec.gravity_expanded, "normal", 2.0, unit="m/s^2")]
    if spec.cube_angle is None:
        return out
    for label in labels:
        for t in _tilt_axes(label):
            out.append(InputQuantity(f"cube.{label}.tilt_{t}", 0.0, spec.cube_angle, unit="rad"))
    return out


def _tilt_axes(label: str) -> str:
    """The two body axes a face angle error of position `label` rotates about."""
    up = label.split("_")[0]
    return "".join(a for a in params.AXES if a != up)


def reference_forces(labels: Sequence[str], values: Mapping[str, float]) -> np.ndarray:
    """(K, 3) reference specific force of each position given gravity and the tilt angles."""
    g = values.get("gravity")
    return np.array([_tilt(label, values).apply(axis_vector(label, g)) for label in labels])


def _tilt(label: str, values: Mapping[str, float]) -> Rotation:
    """The fixture's face-angle error of position `label` (identity when not given)."""
    # scipy.spatial is slow to import: only for the budgets of static positions.
    from scipy.spatial.transform import Rotation

    rotvec = np.zeros(3)
    for t in _tilt_axes(label):
        rotvec[params.AXIS_INDEX[t]] = values.get(f"cube.{label}.tilt_{t}", 0.0)
    return Rotation.from_rotvec(rotvec)


def integral_inputs(rotations: Sequence[str], spec: EquipmentSpec) -> list[InputQuantity]:
    """The turn angle error of each rotation record (rectangular), when the spec knows it."""
    if spec.turn_angle is None:
        return []
    return [InputQuantity(f"turn.{label}", 0.0, spec.turn_angle, unit="rad") for label in rotations]


def integral_matrix(
    estimate: np.ndarray, turns: int, rotations: Sequence[str], values: Mapping[str, float]
) -> np.ndarray:
    """(3, 3) I + M of the integral method with the rotation angles and axes given by `values`.

    The method divides the ccw - cw integral J_A by the nominal 2 pi n per record about body
    axis A (`estimate` = I + M so found). A rotation that turned 2 pi n + delta about the
    vertical, which the fixture's face-angle error of "A_up" tilts in the body frame exactly as
    it tilts gravity, has J_A = (I + M) r_A with r_A = sum of +-(2 pi n + delta) R_tilt e_A;
    solving with those r_A gives I + M = J R^-1.
    """
    nominal = np.zeros((3, 3))
    actual = np.zeros((3, 3))
    for label in rotations:
        axis, sense = label.split("_")
        j = params.AXIS_INDEX[axis]
        angle = 2.0 * math.pi * turns
        nominal[j, j] += angle  # both senses add: ccw +angle minus cw -angle
        tilted = _tilt(f"{axis}_up", values).apply(np.eye(3)[j])
        actual[:, j] += (angle + values.get(f"turn.{label}", 0.0)) * tilted
    J = estimate @ nominal
    return J @ np.linalg.inv(actual)


def static_solve(
    labels: Sequence[str],
    acc: tuple[np.ndarray, np.ndarray],
    gyr: tuple[np.ndarray, np.ndarray],
    gravity: float,
    integral: tuple[np.ndarray, int, Sequence[str]] | None = None,
) -> Callable[[Mapping[str, float]], dict[str, float]]:
    """The static fits (and the integral method) as a function of the Type B inputs.

    Parameters
    ----------
    labels : static position labels; acc, gyr : (means, sems), each (K, 3), SI.
    gravity : m/s^2 (nominal; "gravity" in the values overrides it).
    integral : (I + M estimated by the integral method, turns, rotation labels) or None.

    Returns
    -------
    values -> {acc.bias/scale/misalign, gyr.bias/gsens, and gyr.scale/misalign with `integral`}.
    """

    def solve(values: Mapping[str, float]) -> dict[str, float]:
        ref = reference_forces(labels, {"gravity": gravity, **values})
        out = {**solve_accel_linear(ref, *acc).params, **solve_gyro_static(ref, *gyr).params}
        if integral is not None:
            m = integral_matrix(*integral, values) - np.eye(3)
            out.update(
                {
                    n: float(m[i, j])
                    for i, row in enumerate(params.matrix_names("gyr"))
                    for j, n in enumerate(row)
                }
            )
        return out

    return solve


def static_accel_budgets(
    labels: Sequence[str],
    means: np.ndarray,
    sem: np.ndarray,
    dof: float,
    gravity: float,
    spec: EquipmentSpec | None,
    mc_draws: int = 0,
    rng: np.random.Generator | None = None,
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
        return solve_accel_linear(reference_forces(labels, vals), means, sem).params

    fit = solve_accel_linear(reference_forces(labels, {"gravity": gravity}), means, sem)
    type_a = {n: (s, dof) for n, s in fit.std.items()}
    inputs = static_inputs(labels, gravity, spec) if spec is not None else []
    units = {n: ("m/s^2" if ".bias." in n else "1") for n in type_a}
    out = budgets(solve, inputs, type_a, units)
    mc = monte_carlo(solve, inputs, type_a, mc_draws, rng) if mc_draws and inputs else None
    return out, mc


def rate_table_solve(points: Sequence[RatePoint]) -> Callable[[Mapping[str, float]], dict]:
    """The rate-table solve with the table's rates scaled by 1 + "table.rate_rel"."""
    points = list(points)

    def solve(values: Mapping[str, float]) -> dict[str, float]:
        e = values.get("table.rate_rel", 0.0)
        cal = solve_rate_table([replace(p, table_rate=p.table_rate * (1 + e)) for p in points])
        return {n: p.value for n, p in cal.parameters.items()}

    return solve


def rate_table_budgets(
    points: Sequence[RatePoint],
    dof: float,
    spec: EquipmentSpec | None,
    mc_draws: int = 0,
    rng: np.random.Generator | None = None,
) -> tuple[dict[str, Budget], dict[str, tuple[float, float, float]] | None]:
    """Budgets of the rate-table gyro parameters with the table's relative rate error (Type B)."""
    points = list(points)
    solve = rate_table_solve(points)
    cal = solve_rate_table(points)
    type_a = {n: (p.std, dof) for n, p in cal.parameters.items()}
    inputs = (
        []
        if spec is None or spec.table_rate_rel is None
        else [InputQuantity("table.rate_rel", 0.0, spec.table_rate_rel, unit="1")]
    )
    units = {n: ("rad/s" if ".bias." in n else "1") for n in type_a}
    out = budgets(solve, inputs, type_a, units)
    mc = monte_carlo(solve, inputs, type_a, mc_draws, rng) if mc_draws and inputs else None
    return out, mc


Model = tuple["Callable[[Mapping[str, float]], dict] | None", list[InputQuantity], tuple[str, ...]]


def static_model(
    cal: Calibration,
    segments: Mapping[str, Recording],
    settings: Any,
    spec: EquipmentSpec,
) -> Model:
    """The six-position procedures' model: gravity and face angles through the static fits,
    turn angles through the integral; only for the least-squares linear accelerometer fit.

    `settings` : the procedure's typed settings as solved (calib_core.run_budget).
    """
    if getattr(settings, "gyro_from_earth_rate", False):  # six_position's only
        return None, [], ("Type B sources not modelled for gyro_from_earth_rate",)
    default = settings.accel_solver == "least_squares" and settings.accel_model == "linear"
    if not default:
        return (
            None,
            [],
            (
                "Type B sources not modelled for accel_solver/accel_model "
                "other than least_squares/linear",
            ),
        )
    labels = [label for label in STATIC_LABELS if label in segments]
    stats = [
        (channel_stats(segments[label].acc), channel_stats(segments[label].gyr)) for label in labels
    ]
    acc_mean, acc_sem = (np.array([getattr(a, f) for a, _ in stats]) for f in ("mean", "sem"))
    rotations = [label for label in ROTATION_LABELS if label in segments]
    gyr_stats = [g for _, g in stats]
    if rotations and getattr(settings, "turn_estimator", None) == "regression":  # as solved
        pooled = pooled_static_gyro(dict(segments), dict(zip(labels, gyr_stats, strict=True)))
        gyr_stats = [pooled[label] for label in labels]
    gyr_mean, gyr_sem = (np.array([getattr(g, f) for g in gyr_stats]) for f in ("mean", "sem"))
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


def rate_table_model(
    cal: Calibration,
    segments: Mapping[str, Recording],
    settings: Any,
    spec: EquipmentSpec,
) -> Model:
    """The rate-table procedure's model: the table's relative rate error through its solver.

    `settings` : its typed settings (the solve's plateau window).
    """
    if spec.table_rate_rel is None:
        return None, [], spec.missing("table_rate_rel")
    solve = rate_table_solve(rate_points(list(segments.values()), **plateau_window(settings)))
    return solve, [InputQuantity("table.rate_rel", 0.0, spec.table_rate_rel, unit="1")], ()
