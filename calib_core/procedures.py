"""Calibration procedures: from labelled segments to a Calibration.

A procedure takes the segments of one lab run (Recordings keyed by label), the
local gravity and its settings, and returns a Calibration with every parameter's
standard uncertainty, residuals per segment and solver facts in `info`.

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

Settings
--------
turns : int or None (infer from the data), integral method only.
gyro_range_dps : gyro full scale, deg/s (default 2000).
accel_solver : "least_squares" (default), "closed_form" (methods.md 2.1) or
    "kalman" (sequential filter over every sample, calib_core.solvers.kalman;
    agrees with least squares within its uncertainty).
accel_model : "linear" (default, 12 parameters) or "per_axis" (the reduced
    rate-table model of methods.md 1: bias and scale per axis, no cross-coupling).
rotation_directions : "both" (default; ccw and cw about each axis) or "any"
    (one rotation per axis suffices, Ferraris et al.; e.g. imucal sessions).

multi_position, equipment_free, sensor_array, rate_table, static_bias, centrifuge: see
their solver modules and docs/procedures.md for segment labels and settings.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from calib_core import params
from calib_core.calibration import Calibration, StepRecord
from calib_core.checks import check_physical_bounds
from calib_core.preprocess.motion import static_motion_checks
from calib_core.recording import Recording
from calib_core.solvers.centrifuge_segments import solve_centrifuge_segments
from calib_core.solvers.equipment_free import solve_equipment_free
from calib_core.solvers.integral import ROTATION_LABELS, rotation_static_means, solve_integral
from calib_core.solvers.kalman import kalman_accel_linear
from calib_core.solvers.multi_position import (
    segment_residual,
    solve_accel_linear,
    solve_gyro_static,
    solve_multi_position,
)
from calib_core.solvers.rate_table import rate_points, solve_rate_table
from calib_core.solvers.sensor_array import solve_sensor_array
from calib_core.solvers.six_position import (
    STATIC_LABELS,
    accel_closed_form,
    accel_closed_form_std,
    axis_vector,
    face_bias_checks,
)
from calib_core.solvers.static_bias import solve_static_bias
from calib_core.stats import ChannelStats, channel_stats, largest_std
from calib_core.units import DEG

DEFAULT_SETTINGS: dict[str, Any] = {
    "turns": None,
    "gyro_range_dps": 2000.0,
    "accel_solver": "least_squares",
    "accel_model": "linear",
    "rotation_directions": "both",
}
ACCEL_SOLVERS = ("least_squares", "closed_form", "kalman")
ACCEL_MODELS = ("linear", "per_axis")


def _settings(settings: dict[str, Any] | None) -> dict[str, Any]:
    """The solver's settings with defaults filled in, validated.

    Other keys (preprocessing settings of the same run) are ignored.
    """
    given = dict(settings or {})
    merged = {**DEFAULT_SETTINGS, **{k: v for k, v in given.items() if k in DEFAULT_SETTINGS}}
    if merged["accel_solver"] not in ACCEL_SOLVERS:
        raise ValueError(
            f"settings.accel_solver: {merged['accel_solver']!r}; "
            f"expected one of {list(ACCEL_SOLVERS)}"
        )
    if merged["accel_model"] not in ACCEL_MODELS:
        raise ValueError(
            f"settings.accel_model: {merged['accel_model']!r}; expected one of {list(ACCEL_MODELS)}"
        )
    if merged["rotation_directions"] not in ("both", "any"):
        raise ValueError(
            f"settings.rotation_directions: {merged['rotation_directions']!r}; "
            "expected 'both' (ccw and cw about each axis) or 'any' (one suffices)"
        )
    rng = merged["gyro_range_dps"]
    if not isinstance(rng, int | float) or isinstance(rng, bool) or rng <= 0:
        raise ValueError(
            f"settings.gyro_range_dps: expected a positive number (deg/s), got {rng!r}"
        )
    turns = merged["turns"]
    if turns is not None and (isinstance(turns, bool) or not isinstance(turns, int) or turns < 1):
        raise ValueError(f"settings.turns: expected a positive whole number or none, got {turns!r}")
    return merged


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
    return acc, gyr


def _solve_statics(
    segments: dict[str, Recording], gravity: float, settings: dict[str, Any], procedure: str
) -> tuple[Calibration, dict[str, ChannelStats]]:
    """Accelerometer 12, gyro bias + g-sensitivity 12, noise, static residuals."""
    acc, gyr = _static_stats(segments)
    f_true = np.array([axis_vector(label, gravity) for label in STATIC_LABELS])  # (6, 3)

    def stack(stats: dict[str, ChannelStats], field: str) -> np.ndarray:
        return np.array([getattr(stats[label], field) for label in STATIC_LABELS])

    cal = Calibration(procedure=procedure, gravity=gravity)
    if settings["accel_solver"] == "kalman":
        acc_fit = kalman_accel_linear(f_true, [segments[label].acc for label in STATIC_LABELS])
    else:
        acc_fit = solve_accel_linear(f_true, stack(acc, "mean"), stack(acc, "sem"))
    if settings["accel_solver"] == "closed_form":
        values = accel_closed_form({k: s.mean for k, s in acc.items()}, gravity)
        stds = accel_closed_form_std({k: s.sem for k, s in acc.items()}, gravity)
    else:
        values, stds = acc_fit.params, acc_fit.std
    if settings["accel_model"] == "per_axis":
        values, stds = _per_axis_fit(f_true, stack(acc, "mean"), stack(acc, "sem"))
    linear = settings["accel_model"] == "linear"
    if values is acc_fit.params:  # the least-squares fit: keep its covariance
        cal.add_fit(acc_fit.names, acc_fit.params, acc_fit.cov)
    else:
        for name in params.ACC_LINEAR if linear else values:
            cal.add(name, values[name], stds[name])
    gyr_fit = solve_gyro_static(f_true, stack(gyr, "mean"), stack(gyr, "sem"))
    cal.add_fit(gyr_fit.names, gyr_fit.params, gyr_fit.cov)

    # Noise: the paper's figure, the largest per-position std of each channel.
    for sensor, stats in (("acc", acc), ("gyr", gyr)):
        value, u = largest_std(stack(stats, "std"), stack(stats, "n_eff"))
        for i, a in enumerate(params.AXES):
            cal.add(f"{sensor}.noise.{a}", value[i], u[i])

    for label in STATIC_LABELS:
        rec = segments[label]
        # The true specific force is constant over a static: a (3,) model, not one per sample.
        f = axis_vector(label, gravity)
        cal.residuals.append(segment_residual(label, "acc", rec.acc, _acc_model(cal, f)))
        cal.residuals.append(segment_residual(label, "gyr", rec.gyr, _gyr_static_model(cal, f)))

    face_bias = face_bias_checks(
        {k: s.mean for k, s in acc.items()}, {k: s.sem for k, s in acc.items()}
    )
    cal.info.setdefault("solver_checks", []).extend(face_bias)
    cal.info["condition_number"] = acc_fit.condition_number
    cal.info["accel_solver"] = settings["accel_solver"]
    cal.info["acc_fit_chi2"] = [float(v) for v in acc_fit.chi2]
    cal.info["gyr_fit_chi2"] = [float(v) for v in gyr_fit.chi2]
    cal.info["fit_dof_per_axis"] = len(STATIC_LABELS) - 4
    cal.info["sample_counts"] = {label: len(segments[label]) for label in STATIC_LABELS}
    cal.info["effective_sample_counts_min"] = {
        label: float(min(acc[label].n_eff.min(), gyr[label].n_eff.min())) for label in STATIC_LABELS
    }
    return cal, gyr


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


def _gyr_static_model(cal: Calibration, f_true: np.ndarray) -> np.ndarray:
    return f_true @ cal.gsens().T + cal.vector("gyr", "bias")


def solve_six_position(
    segments: dict[str, Recording], gravity: float, settings: dict[str, Any] | None = None
) -> Calibration:
    """Six static positions: accelerometer 12, gyro bias and g-sensitivity, noise.

    Parameters
    ----------
    segments : label -> Recording; needs x_up, x_dn, y_up, y_dn, z_up, z_dn.
    gravity : local gravity, m/s^2.
    settings : see the module docstring.
    """
    merged = _settings(settings)
    _require(segments, STATIC_LABELS, "six_position")
    cal, _ = _solve_statics(segments, gravity, merged, "six_position")
    return cal


def solve_six_position_integral(
    segments: dict[str, Recording], gravity: float, settings: dict[str, Any] | None = None
) -> Calibration:
    """Six static positions plus the integral method for gyro scale and misalignment.

    Parameters
    ----------
    segments : label -> Recording; the six statics and x_ccw, x_cw, y_ccw,
        y_cw, z_ccw, z_cw.
    gravity : local gravity, m/s^2.
    settings : see the module docstring.
    """
    merged = _settings(settings)
    both = merged["rotation_directions"] == "both"
    _require(segments, STATIC_LABELS + (ROTATION_LABELS if both else ()), "six_position_integral")
    cal, gyr = _solve_statics(segments, gravity, merged, "six_position_integral")
    rotations = {label: segments[label] for label in ROTATION_LABELS if label in segments}
    integral = solve_integral(
        rotations,
        {label: s.mean for label, s in gyr.items()},
        {label: s.sem for label, s in gyr.items()},
        merged["gyro_range_dps"] * DEG,
        merged["turns"],
        # The static record of the same orientation gives the noise the integral collects.
        noise_std={label: s.std for label, s in gyr.items()},
        gravity=gravity,
        directions=merged["rotation_directions"],
    )
    cal = cal.merged(integral)
    # merged() takes the integral's info on top; keep this procedure's name.
    cal.procedure = "six_position_integral"
    # The accelerometer sees g along the rotation axis throughout a rotation.
    for label in rotations:
        rec = segments[label]
        f = axis_vector(label, gravity)  # constant over the rotation: a (3,) model
        cal.residuals.append(segment_residual(label, "acc", rec.acc, _acc_model(cal, f)))
        cal.info["sample_counts"][label] = len(rec)
    return cal


def solve_integral_procedure(
    segments: dict[str, Recording], gravity: float, settings: dict[str, Any] | None = None
) -> Calibration:
    """Stage 2 of the MPU-6000 program alone: the six rotations, no orientations.

    Gyro scale and misalignment by the integral method, each axis's static reading taken
    from its own ccw and cw rotations (`rotation_static_means`); no biases, g-sensitivity,
    accelerometer or noise (those are stage 1, procedure six_position).

    settings : turns, gyro_range_dps (see the module docstring).
    """
    merged = _settings(settings)
    _require(segments, ROTATION_LABELS, "integral")
    rotations = {label: segments[label] for label in ROTATION_LABELS}
    means, sems = rotation_static_means(rotations)
    cal = solve_integral(
        rotations, means, sems, merged["gyro_range_dps"] * DEG, merged["turns"], gravity=gravity
    )
    cal.info["static_reading_from"] = "rotations (stage 2 alone)"
    cal.info["sample_counts"] = {label: len(rec) for label, rec in rotations.items()}
    return cal


def solve_rate_table_procedure(
    segments: dict[str, Recording], gravity: float, settings: dict[str, Any] | None = None
) -> Calibration:
    """Rate-table gyro calibration: one segment per rate plateau, labelled "<axis>_<rate>"
    (e.g. "z_+100") with the table feedback in reference["table_rate"] (rad/s).

    settings : settle_s (default 20 s), record_s (default: to the end), full_scale_dps;
        gyro_bias "joint" (default, fitted with the scale factors) or "static" (fixed
        from the static run: the 0-rate points, or static_bias_dps [x, y, z] with
        static_bias_std_dps [x, y, z] of a separate static-bias run).
    """
    s = dict(settings or {})
    kwargs = {k: float(s[k]) for k in ("settle_s", "record_s") if s.get(k) is not None}
    points = rate_points(list(segments.values()), **kwargs)
    full = s.get("full_scale_dps")
    given = None
    if s.get("static_bias_dps") is not None:
        std = s.get("static_bias_std_dps", [0.0, 0.0, 0.0])
        given = (np.asarray(s["static_bias_dps"], float) * DEG, np.asarray(std, float) * DEG)
    cal = solve_rate_table(
        points,
        full_scale=None if full is None else float(full) * DEG,
        gyro_bias=str(s.get("gyro_bias", "joint")),
        static_bias=given,
    )
    cal.gravity = gravity
    return cal


def solve_static_bias_procedure(
    segments: dict[str, Recording], gravity: float, settings: dict[str, Any] | None = None
) -> Calibration:
    """Static bias and noise of one long static segment (any label).

    settings : up_axis ("+z", ...), latitude_deg, heading_deg, remove_earth_rate,
    n_sigma (see calib_core.solvers.static_bias.solve_static_bias).
    """
    if len(segments) != 1:
        raise ValueError(
            f"static_bias: expected one static segment, got {len(segments)} ({', '.join(segments)})"
        )
    s = dict(settings or {})
    keys = ("up_axis", "latitude_deg", "heading_deg", "remove_earth_rate", "n_sigma")
    return solve_static_bias(
        next(iter(segments.values())),
        gravity=gravity,
        **{k: s[k] for k in keys if s.get(k) is not None},
    )


PROCEDURES: dict[str, Callable[[dict[str, Recording], float, dict[str, Any]], Calibration]] = {
    "six_position": solve_six_position,
    "centrifuge": solve_centrifuge_segments,
    "six_position_integral": solve_six_position_integral,
    "integral": solve_integral_procedure,
    "multi_position": solve_multi_position,
    "equipment_free": solve_equipment_free,
    "sensor_array": solve_sensor_array,
    "rate_table": solve_rate_table_procedure,
    "static_bias": solve_static_bias_procedure,
}


def solve(
    procedure: str, segments: dict[str, Recording], gravity: float, settings: dict[str, Any]
) -> Calibration:
    """Run the named procedure on labelled segments.

    Parameters
    ----------
    procedure : a key of PROCEDURES.
    segments : label -> Recording (SI units).
    gravity : local gravity, m/s^2.
    settings : procedure settings (see the module docstring).

    Returns
    -------
    Calibration with every parameter's standard uncertainty, residuals per
    segment and solver facts (`info`).

    Raises
    ------
    ValueError for an unknown procedure, a gravity outside 9.7..9.9 m/s^2,
    missing segments, or a parameter beyond physical bounds (with what to check).
    """
    try:
        fn = PROCEDURES[procedure]
    except KeyError:
        raise ValueError(
            f"unknown procedure {procedure!r}; expected one of {sorted(PROCEDURES)}"
        ) from None
    if not (9.7 < gravity < 9.9):
        raise ValueError(f"gravity must be the local value in m/s^2 (9.7..9.9), got {gravity!r}")
    cal = fn(segments, gravity, settings)
    cal.info.setdefault("solver_checks", []).extend(static_motion_checks(procedure, segments))
    check_physical_bounds(cal, _BOUNDS_HINT.get(procedure, _BOUNDS_HINT[None]))
    return cal


# What to check when a scale factor or misalignment is beyond physical bounds.
_BOUNDS_HINT = {
    "multi_position": (
        "check the table's attitude convention (settings.attitude_convention: 'project' "
        "a_x = -g sin(pitch), 'rate_table_procedure' a_x = +g sin(pitch)), settings.table_axes "
        "and settings.mount"
    ),
    None: (
        "check the segment labels (which axis was up, the rotation sense), the units and "
        "the axis order of the columns"
    ),
}


def solve_step(
    segments: dict[str, Recording],
    settings: dict[str, Any],
    held_out: frozenset[str] | set[str] = frozenset(),
) -> tuple[Calibration, StepRecord]:
    """The solve step of a run: the one StepRecord a solve leaves in the archive.

    Parameters
    ----------
    segments : label -> Recording, after preprocessing.
    settings : {"procedure", "gravity" (m/s^2), ...} plus the run's settings; the
        procedure's own keys (module docstring) are taken, preprocessing tables ignored.
    held_out : labels of verification segments: kept out of the fit, checked after.

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
    cal = solve(procedure, fit, gravity, proc_settings)
    scalars = {k: v for k, v in cal.info.items() if isinstance(v, int | float | str)}
    record = StepRecord(
        name="solve",
        # The run's settings as given, the solver's defaults filled in.
        settings={"procedure": procedure, "gravity": gravity, **proc_settings,
                  **_settings(proc_settings)},  # fmt: skip
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
