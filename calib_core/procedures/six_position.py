"""The six-position family of procedures: from labelled segments to a Calibration.

A procedure takes the segments of one lab run (Recordings keyed by label), the
local gravity and its settings, and returns a Calibration with every parameter's
standard uncertainty, residuals per segment and solver facts in `info`. This module
holds the solvers of the three procedures that share the statics' and the integral
method's code, and the `six_position` procedure object; `six_position_integral` and
`integral` have their objects in their own modules.

Procedures
----------
six_position
    Statics only (x_up, x_dn, y_up, y_dn, z_up, z_dn): accelerometer bias,
    scale and misalignment (12), gyro bias and g-sensitivity (12), noise.
integral
    The six rotations alone (stage 2 of the MPU-6000 program): gyro scale and
    misalignment, each axis's static reading from its own ccw and cw records.
six_position_integral
    The statics plus n-turn ccw/cw rotations about each axis (x_ccw, x_cw, ...):
    adds gyro scale and misalignment by the integral method (MPU-6000 paper).

Settings: the typed `Setting`s below (docs/procedures.md); each solver takes its
procedure's parsed values (`Settings.parse`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calib_core import params
from calib_core.calibration import Calibration
from calib_core.procedures.base import ATTITUDES, ENVIRONMENT, Procedure, Setting, Settings
from calib_core.procedures.static_bias import HEADING_DEG, LATITUDE_DEG
from calib_core.recording import Recording
from calib_core.settings import SettingsIn
from calib_core.solvers.earth_rate_faces import faces_earth_rate, solve_gyro_earth_rate
from calib_core.solvers.integral import (
    ROTATION_LABELS,
    TURNS,
    pooled_static_gyro,
    rotation_static_means,
    solve_integral,
    turn_rests,
)
from calib_core.solvers.kalman import kalman_accel_linear
from calib_core.solvers.multi_position import (
    segment_residual,
    solve_accel_linear,
    solve_gyro_static,
)
from calib_core.solvers.six_position import (
    STATIC_LABELS,
    UP_CHANNEL,
    accel_closed_form,
    accel_closed_form_std,
    face_bias_checks,
    reference_up,
)
from calib_core.solvers.turn_motion import TURN_ESTIMATORS, pooled_stats
from calib_core.stats import ChannelStats, channel_stats, largest_std, no_scatter
from calib_core.uncertainty_sources import static_model
from calib_core.units import DEG

ACCEL_SOLVERS = ("least_squares", "closed_form", "kalman")
ACCEL_MODELS = ("linear", "per_axis")
ACCEL_SOLVER = Setting(
    "accel_solver", "text", "", "least_squares",
    "accelerometer fit: least squares, the closed form of docs/methods.md 2.1, or the sequential "
    "filter over every sample (calib_core.solvers.kalman)", choices=ACCEL_SOLVERS)  # fmt: skip
ACCEL_MODEL = Setting(
    "accel_model", "text", "", "linear",
    "accelerometer model: 12 parameters, or bias and scale per axis (no cross-coupling)",
    choices=ACCEL_MODELS)  # fmt: skip
GYRO_RANGE_DPS = Setting(
    "gyro_range_dps", "number", "deg/s", 2000.0,
    "gyro full scale: the integral method's saturation check; readings at it are refused",
    low=0.0, low_open=True)  # fmt: skip
ROTATION_DIRECTIONS = Setting(
    "rotation_directions", "text", "", "both",
    "rotations per axis: ccw and cw (both), or one suffices (any; Ferraris et al.)",
    choices=("both", "any"))  # fmt: skip
TURN_ESTIMATOR = Setting(
    "turn_estimator", "text", "", "regression",
    "integral method: each turn's motion window, misalignments by regression on the on-axis "
    "rate, the rests as static data (regression); or every rate integrated over the whole "
    "record, the paper's literal reading (whole_record; docs/methods.md 2.6)",
    choices=TURN_ESTIMATORS)  # fmt: skip
GYRO_FROM_EARTH_RATE = Setting(
    "gyro_from_earth_rate", "bool", "", False,
    "gyro bias, scale and misalignment from the statics with Earth rate as the input (FOG/RLG "
    "grade; needs latitude_deg and heading_deg; replaces the gyro g-sensitivity fit)")  # fmt: skip
# The settings the statics' solver reads (`_solve_statics`), with the integral method's.
STATICS_SETTINGS = Settings(
    ACCEL_SOLVER, ACCEL_MODEL, GYRO_FROM_EARTH_RATE, LATITUDE_DEG, HEADING_DEG,
    name="SixPositionSettings",
)  # fmt: skip
INTEGRAL_SETTINGS = Settings(
    TURNS, GYRO_RANGE_DPS, ACCEL_SOLVER, ACCEL_MODEL, ROTATION_DIRECTIONS, TURN_ESTIMATOR,
    name="SixPositionIntegralSettings",
)  # fmt: skip
INTEGRAL_ONLY_SETTINGS = Settings(TURNS, GYRO_RANGE_DPS, TURN_ESTIMATOR, name="IntegralSettings")


def _require(segments: dict[str, Recording], labels: tuple[str, ...], procedure: str) -> None:
    missing = [label for label in labels if label not in segments]
    if missing:
        raise ValueError(
            f"procedure {procedure!r}: missing segments {', '.join(missing)} "
            f"(needs {', '.join(labels)})"
        )


def _static_stats(
    segments: dict[str, Recording],
) -> tuple[dict[str, ChannelStats], dict[str, ChannelStats]]:
    acc: dict[str, ChannelStats] = {}
    gyr: dict[str, ChannelStats] = {}
    for label in STATIC_LABELS:
        rec = segments[label]
        try:
            acc[label] = channel_stats(rec.acc)
            gyr[label] = channel_stats(rec.gyr)
        except ValueError as exc:
            raise ValueError(f"segment {label} ({rec.source or 'no source'}): {exc}") from None
        _scatters(label, acc[label], "accelerometer", "m/s^2")
        _scatters(label, gyr[label], "gyro", "rad/s")
    return acc, gyr


def _scatters(label: str, stats: ChannelStats, sensor: str, unit: str) -> None:
    """ValueError when a channel's samples show no scatter (`no_scatter`): its mean would
    weigh in the fits as exact, and its uncertainty would come out undefined."""
    flat = no_scatter(stats)
    if flat.any():
        axis = int(np.argmax(flat))
        raise ValueError(
            f"segment {label}, {sensor} {'xyz'[axis]}: its {stats.n} samples show no scatter (std "
            f"{stats.std[axis]:.3g} {unit} about the mean {stats.mean[axis]:.6g} {unit}): "
            "one reading repeated (a stuck sensor or a repeated log line) gives no "
            "uncertainty of its mean; record this position again"
        )


def _solve_statics(
    segments: dict[str, Recording],
    gravity: float,
    settings: Any,
    procedure: str,
    turn_estimator: str = "whole_record",
) -> tuple[Calibration, dict[str, ChannelStats], dict[str, ChannelStats]]:
    """Accelerometer 12, gyro bias + g-sensitivity 12, noise, static residuals.

    settings : the statics' typed settings (`STATICS_SETTINGS.parse`).
    Returns the calibration, the faces' gyro statistics and those the gyro fit used: the
    faces' pooled with the turns' rests under turn_estimator "regression"."""
    acc, gyr = _static_stats(segments)
    gyr_fit_stats = gyr
    if turn_estimator == "regression":
        gyr_fit_stats = pooled_static_gyro(segments, gyr)
    # (6, 3); a face found not square carries its true direction (reference_up).
    f_true = np.array([reference_up(label, segments[label], gravity) for label in STATIC_LABELS])

    def stack(stats: dict[str, ChannelStats], field: str) -> np.ndarray:
        return np.array([getattr(stats[label], field) for label in STATIC_LABELS])

    cal = Calibration(procedure=procedure, gravity=gravity)
    if settings.accel_solver == "kalman":
        acc_fit = kalman_accel_linear(f_true, [segments[label].acc for label in STATIC_LABELS])
    else:
        acc_fit = solve_accel_linear(f_true, stack(acc, "mean"), stack(acc, "sem"))
    tilted = [k for k in STATIC_LABELS if UP_CHANNEL in segments[k].reference]
    if tilted and settings.accel_solver == "closed_form":
        raise ValueError(
            f"accel_solver closed_form assumes square cube faces; positions {', '.join(tilted)} "
            "have a corrected reference direction: solve with least_squares or kalman"
        )
    if settings.accel_solver == "closed_form":
        values = accel_closed_form({k: s.mean for k, s in acc.items()}, gravity)
        stds = accel_closed_form_std({k: s.sem for k, s in acc.items()}, gravity)
    else:
        values, stds = acc_fit.params, acc_fit.std
    if settings.accel_model == "per_axis":
        values, stds = _per_axis_fit(f_true, stack(acc, "mean"), stack(acc, "sem"))
    linear = settings.accel_model == "linear"
    if values is acc_fit.params:  # the least-squares fit: keep its covariance
        cal.add_fit(acc_fit.names, acc_fit.params, acc_fit.cov)
        cal.warnings += acc_fit.warnings
    else:
        for name in params.ACC_LINEAR if linear else values:
            cal.add(name, values[name], stds[name])
    # The gyro's static input: Earth rate (FOG case) or none (g-sensitivity fit).
    w_true = np.zeros((len(STATIC_LABELS), 3))
    if settings.gyro_from_earth_rate:
        w_true = _earth_rate_input(segments, settings)
        gyr_fit, observable = solve_gyro_earth_rate(w_true, stack(gyr, "mean"), stack(gyr, "sem"))
        cal.info.setdefault("solver_checks", []).append(observable)
        cal.info["gyro_input"] = "earth_rate"
        cal.info["gyro_earth_rate"] = {
            k: w.tolist() for k, w in zip(STATIC_LABELS, w_true, strict=True)
        }
    else:
        fit_mean, fit_sem = stack(gyr_fit_stats, "mean"), stack(gyr_fit_stats, "sem")
        gyr_fit = solve_gyro_static(f_true, fit_mean, fit_sem)
    cal.add_fit(gyr_fit.names, gyr_fit.params, gyr_fit.cov)
    cal.warnings += gyr_fit.warnings

    # Noise: the paper's figure, the largest per-position std of each channel.
    for sensor, stats in (("acc", acc), ("gyr", gyr)):
        value, u = largest_std(stack(stats, "std"), stack(stats, "n_eff"))
        for i, a in enumerate(params.AXES):
            cal.add(f"{sensor}.noise.{a}", value[i], u[i])

    for k, label in enumerate(STATIC_LABELS):
        rec = segments[label]
        # The true specific force is constant over a static: a (3,) model, not one per sample.
        f = reference_up(label, rec, gravity)
        cal.residuals.append(segment_residual(label, "acc", rec.acc, _acc_model(cal, f)))
        gyr_model = _gyr_static_model(cal, f, w_true[k])
        cal.residuals.append(segment_residual(label, "gyr", rec.gyr, gyr_model))

    face_bias = face_bias_checks(
        {k: s.mean for k, s in acc.items()}, {k: s.sem for k, s in acc.items()}
    )
    cal.info.setdefault("solver_checks", []).extend(face_bias)
    cal.info["condition_number"] = acc_fit.condition_number
    cal.info["accel_solver"] = settings.accel_solver
    cal.info["acc_fit_chi2"] = [float(v) for v in acc_fit.chi2]
    cal.info["gyr_fit_chi2"] = [float(v) for v in gyr_fit.chi2]
    cal.info["fit_dof_per_axis"] = len(STATIC_LABELS) - 4
    cal.info["sample_counts"] = {label: len(segments[label]) for label in STATIC_LABELS}
    cal.info["effective_sample_counts_min"] = {
        label: float(min(acc[label].n_eff.min(), gyr[label].n_eff.min())) for label in STATIC_LABELS
    }
    if gyr_fit_stats is not gyr:  # the faces' samples and the turns' rests
        cal.info["gyro_static_samples"] = {k: s.n for k, s in gyr_fit_stats.items()}
    return cal, gyr, gyr_fit_stats


def _per_axis_fit(
    f_true: np.ndarray, means: np.ndarray, sem: np.ndarray
) -> tuple[dict[str, float], dict[str, float]]:
    """Reduced model m_k,i = b_i + (1 + s_i) f_k,i: weighted least squares per axis.

    Parameters
    ----------
    f_true : (K, 3) true specific force, m/s^2.
    means, sem : (K, 3) mean output and its standard uncertainty, m/s^2.

    Returns
    -------
    (values, stds) of acc.bias.* and acc.scale.* (no misalignment: the model has none).
    """
    values: dict[str, float] = {}
    stds: dict[str, float] = {}
    for i, a in enumerate(params.AXES):
        w = 1.0 / sem[:, i]
        design = np.column_stack([np.ones(len(f_true)), f_true[:, i]]) * w[:, None]
        coef, *_ = np.linalg.lstsq(design, (means[:, i] - f_true[:, i]) * w, rcond=None)
        cov = np.linalg.inv(design.T @ design)
        values[f"acc.bias.{a}"], values[f"acc.scale.{a}"] = coef
        stds[f"acc.bias.{a}"], stds[f"acc.scale.{a}"] = np.sqrt(np.diag(cov))
    return values, stds


def _acc_model(cal: Calibration, f_true: np.ndarray) -> np.ndarray:
    return f_true @ (np.eye(3) + cal.matrix("acc")).T + cal.vector("acc", "bias")


def _gyr_static_model(cal: Calibration, f_true: np.ndarray, w_true: np.ndarray) -> np.ndarray:
    return (
        w_true @ (np.eye(3) + cal.matrix("gyr")).T
        + f_true @ cal.gsens().T
        + cal.vector("gyr", "bias")
    )


def _earth_rate_input(segments: dict[str, Recording], settings: Any) -> np.ndarray:
    """(6, 3) Earth rate of the statics in their body frames, rad/s (faces_earth_rate);
    ValueError for a face with a corrected up direction, whose heading axis is not known."""
    tilted = [k for k in STATIC_LABELS if UP_CHANNEL in segments[k].reference]
    if tilted:
        raise ValueError(
            f"gyro_from_earth_rate assumes square faces on a level fixture; positions "
            f"{', '.join(tilted)} have a corrected up direction, so their Earth-rate input is "
            "not known: solve without gyro_from_earth_rate"
        )
    return faces_earth_rate(settings.latitude_deg, settings.heading_deg)


def solve_six_position(
    segments: dict[str, Recording], gravity: float, settings: SettingsIn = None
) -> Calibration:
    """Six static positions: accelerometer 12, gyro bias and g-sensitivity, noise.

    Parameters
    ----------
    segments : label -> Recording; needs x_up, x_dn, y_up, y_dn, z_up, z_dn.
    gravity : local gravity, m/s^2.
    settings : typed `STATICS_SETTINGS` (a mapping is parsed; docs/procedures.md).
    """
    s = STATICS_SETTINGS.parse(settings)
    _require(segments, STATIC_LABELS, "six_position")
    cal, _, _ = _solve_statics(segments, gravity, s, "six_position")
    return cal


def solve_six_position_integral(
    segments: dict[str, Recording], gravity: float, settings: SettingsIn = None
) -> Calibration:
    """Six static positions plus the integral method for gyro scale and misalignment.

    Parameters
    ----------
    segments : label -> Recording; the six statics and x_ccw, x_cw, y_ccw,
        y_cw, z_ccw, z_cw.
    gravity : local gravity, m/s^2.
    settings : typed `INTEGRAL_SETTINGS` (a mapping is parsed; docs/procedures.md).
    """
    s = INTEGRAL_SETTINGS.parse(settings)
    both = s.rotation_directions == "both"
    _require(segments, STATIC_LABELS + (ROTATION_LABELS if both else ()), "six_position_integral")
    statics = STATICS_SETTINGS.parse({"accel_solver": s.accel_solver, "accel_model": s.accel_model})
    cal, gyr, gyr_fit = _solve_statics(
        segments, gravity, statics, "six_position_integral", s.turn_estimator
    )
    rotations = {label: segments[label] for label in ROTATION_LABELS if label in segments}
    integral = solve_integral(
        rotations,
        {label: st.mean for label, st in gyr_fit.items()},
        {label: st.sem for label, st in gyr_fit.items()},
        s.gyro_range_dps * DEG,
        s.turns,
        # The static record of the same orientation gives the noise the integral collects.
        noise_std={label: st.std for label, st in gyr.items()},
        gravity=gravity,
        directions=s.rotation_directions,
        estimator=s.turn_estimator,
    )
    cal = cal.merged(integral)
    # merged() takes the integral's info on top; keep this procedure's name.
    cal.procedure = "six_position_integral"
    # The accelerometer sees g along the rotation axis throughout a rotation.
    for label in rotations:
        rec = segments[label]
        f = reference_up(label, rec, gravity)  # constant over the rotation: a (3,) model
        cal.residuals.append(segment_residual(label, "acc", rec.acc, _acc_model(cal, f)))
        cal.info["sample_counts"][label] = len(rec)
    return cal


def solve_integral_procedure(
    segments: dict[str, Recording], gravity: float, settings: SettingsIn = None
) -> Calibration:
    """Stage 2 of the MPU-6000 program alone: the six rotations, no orientations.

    Gyro scale and misalignment by the integral method, each axis's static reading taken
    from its own ccw and cw rotations (`rotation_static_means`); no biases, g-sensitivity,
    accelerometer or noise (those are stage 1, procedure six_position).

    settings : typed `INTEGRAL_ONLY_SETTINGS`: turns, gyro_range_dps (a mapping is parsed).
    """
    s = INTEGRAL_ONLY_SETTINGS.parse(settings)
    _require(segments, ROTATION_LABELS, "integral")
    rotations = {label: segments[label] for label in ROTATION_LABELS}
    means, sems = rotation_static_means(rotations)
    estimator = s.turn_estimator
    if estimator == "regression":  # the turns' static data, where each channel has some
        for label, rests in turn_rests(rotations, means).items():
            counts = np.sum(~np.isnan(np.concatenate(rests)), axis=0)
            if counts.min() >= 2:
                stats = pooled_stats(rests)
                means[label], sems[label] = stats.mean, stats.sem
    cal = solve_integral(
        rotations,
        means,
        sems,
        s.gyro_range_dps * DEG,
        s.turns,
        gravity=gravity,
        estimator=estimator,
    )
    cal.info["static_reading_from"] = "rotations (stage 2 alone)"
    cal.info["sample_counts"] = {label: len(rec) for label, rec in rotations.items()}
    return cal


SIX_POSITION = Procedure(
    name="six_position",
    summary="six statics: accelerometer bias, scale and misalignment (12), gyro bias and "
    "g-sensitivity (12), or with gyro_from_earth_rate gyro bias, scale and misalignment "
    "(12) with Earth rate as the input, noise",
    segments="six statics x_up, x_dn, y_up, y_dn, z_up, z_dn (the named axis reads +g / -g), "
    'listed by hand or cut by [run.settings.segmentation] (labels = "faces")',
    solver=solve_six_position,
    settings=STATICS_SETTINGS,
    conditions=ENVIRONMENT + ATTITUDES,
    reference="docs/methods.md 2.1; MPU-6000 manual stage 1",
    labels=STATIC_LABELS + ROTATION_LABELS,
    required=STATIC_LABELS,
    uncertainty=static_model,
    model_checks="each face's bias from its up/down pair against the fit (face_bias); "
    "chi2 of the accelerometer and gyro fits; residuals per static; with "
    "gyro_from_earth_rate, whether the noise lets the Earth rate be seen "
    "(earth_rate_observable)",
    static_segments="all but turns",
)
