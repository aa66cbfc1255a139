"""Sensor-array single-position calibration (docs/methods.md 2.7).

Several IMUs of one type (or one IMU remounted) sit on a precision cube with
known mounting rotations C_s (cube to sensor: v_s = C_s v_c) and share one
error model. The cube stands with its z axis up; one static record, then one
counter-clockwise (+) and one clockwise (-) turn of n whole turns about the
vertical. In the sensor frame the specific force is f_s = C_s (0, 0, g) and
the turn is theta_s = +-2 pi n C_s e_z, so every sensor is a different
"position" of the shared model and everything is stacked least squares:

- accelerometer: m_s = (I + M_a) f_s + b_a, three equations per sensor (the
  patent's six IMUs: 18 equations for 12 unknowns), solved per output axis by
  `solve_accel_multi`;
- gyro bias and g-sensitivity: the static gyro means w_s = b_g + G f_s
  (`solve_gyro_static`), each sensor's static record pooled with its turns' static data
  (`_pooled_gyro`: the rests, and the cross-axis channels less their share of the turn);
- gyro scale and misalignment: the vertical turn keeps f_s constant, so the
  static mean S_s is exactly the rest reading during the turn, and
  J_s+- = integral (w - S_s) dt = (I + M_g) theta_s+-. The difference
  J_s+ - J_s- = (I + M_g) 4 pi n C_s e_z gives three equations per sensor,
  linear in the rows of I + M_g (the sum carries no information on them). A sensor
  turning about one of its axes has them read as the integral method's regression
  estimator reads them (each turn over its motion window, the cross-axis entries as
  slopes on the on-axis rate times the on-axis difference).

The mountings must point e_z along all three sensor axes (in either sense)
for every term to be separable; otherwise the solver says which terms are not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib_core import params
from calib_core.attitude import rot_x, rot_y
from calib_core.calibration import Calibration, SegmentResidual
from calib_core.recording import Recording
from calib_core.settings import Setting, Settings, SettingsIn
from calib_core.solvers.accel_models import solve_accel_multi
from calib_core.solvers.integral import (
    TURNS,
    clean_turn,
    noise_from_differences,
    record_spikes,
    regression_column,
    spike_counts,
    turn_rests,
)
from calib_core.solvers.multi_position import gyro_bias_and_gsens, segment_residual
from calib_core.solvers.turn_motion import face_rest_stats
from calib_core.stats import ChannelStats, channel_stats, trapezoid_weights

PHASES = ("static", "ccw", "cw")


# The procedure's settings (docs/procedures.md); its solver takes them typed.
SETTINGS = Settings(
    Setting("mounts", ("text", "table"), "1", "cube6",
            "\"cube6\" (the patent's six-IMU cube) or {sensor = 3x3 cube-to-sensor rotation}",
            choices=("cube6",)),
    TURNS,
    name="SensorArraySettings",
)  # fmt: skip


def cube_mounts() -> dict[str, np.ndarray]:
    """The patent's six-IMU cube: pairs on three faces, the up axis +x, -x, +y, -y, +z, -z.

    Returns name -> C_s (3, 3), cube to sensor.
    """
    return {
        "s1": rot_y(math.pi / 2),
        "s2": rot_y(-math.pi / 2),
        "s3": rot_x(-math.pi / 2),
        "s4": rot_x(math.pi / 2),
        "s5": np.eye(3),
        "s6": rot_x(math.pi),
    }


@dataclass(frozen=True)
class ArrayRecords:
    """The three records of one sensor of the array and its mounting."""

    name: str
    mount: np.ndarray  # (3, 3) cube -> sensor
    static: Recording
    ccw: Recording
    cw: Recording


def solve_array(
    records: list[ArrayRecords], gravity: float, turns: int | None = None
) -> Calibration:
    """Shared 12 + 12 + 9 parameter model of an array from its static and turn records.

    Parameters
    ----------
    records : one ArrayRecords per sensor (or mounting).
    gravity : local gravity, m/s^2.
    turns : whole turns of each rotation; None infers it from the integrals.

    Returns
    -------
    Calibration "sensor_array": acc.bias/scale/misalign, gyr.bias, gyr.gsens,
    gyr.scale/misalign with standard uncertainties; residuals per record.
    """
    if len(records) < 2:
        raise ValueError(f"sensor_array: need >= 2 sensors or mountings, got {len(records)}")
    up = np.array([0.0, 0.0, gravity])
    f = np.array([r.mount @ up for r in records])  # (S, 3) specific force in each sensor
    acc, gyr = _static_stats(records)
    cal = Calibration(procedure="sensor_array", gravity=gravity)
    acc_fit = solve_accel_multi(
        f, np.array([a.mean for a in acc]), np.array([a.sem for a in acc]), "full"
    )
    for name in acc_fit.names:
        cal.add(name, acc_fit.params[name], acc_fit.std[name])
    cal.warnings += acc_fit.warnings

    pooled, replaced = _pooled_gyro(records, gyr)
    record_spikes(cal, replaced)
    g_means = np.array([g.mean for g in pooled])
    g_sems = np.array([g.sem for g in pooled])
    gyro_bias_and_gsens(cal, f, g_means, g_sems)

    # Gyro matrix from the turns. Per sensor the ccw - cw difference
    # D_s = J+ - J- = (I + M_g) 4 pi n d_s (d_s = C_s e_z): the static mean's error
    # enters both integrals alike and cancels up to (T+ - T-), as in the integral
    # method, and the sensors' rows are independent.
    theta, D, U, sigmas, durations, inferred, used = _turn_differences(records, gyr, turns)
    cond = _fit_gyro_matrix(cal, theta, D, U)
    _add_residuals(cal, records, f, theta, D, sigmas, durations)
    cal.info.update(
        {
            "sensors": [r.name for r in records],
            "condition_number": acc_fit.condition_number,
            "gyro_turn_condition_number": cond,
            "misalignment_by": used,
            "acc_fit_chi2": [float(v) for v in acc_fit.chi2],
            "equations_acc": 3 * len(records),
            "turns": turns if turns is not None else sorted(set(inferred)),
            "sample_counts": {f"{r.name}_{p}": len(getattr(r, p)) for r in records for p in PHASES},
        }
    )
    return cal


def _static_stats(records: list[ArrayRecords]) -> tuple[list[ChannelStats], list[ChannelStats]]:
    """Accelerometer and gyro statistics of each sensor's static record; errors name it."""
    acc, gyr = [], []
    for r in records:
        try:
            acc.append(channel_stats(r.static.acc))
            gyr.append(channel_stats(r.static.gyr))
        except ValueError as exc:
            raise ValueError(f"sensor {r.name} static ({r.static.source}): {exc}") from None
    return acc, gyr


def _pooled_gyro(
    records: list[ArrayRecords], gyr: list[ChannelStats]
) -> tuple[list[ChannelStats], dict[str, dict]]:
    """Gyro statistics of each sensor's static record pooled with the static data of its
    turns, as the six-position family's regression estimator takes them
    (`integral.turn_rests`): the rests outside the turn's motion window on the turning
    channel, and each cross-axis channel less its proportion of the turn. The turn is
    about the vertical, so the specific force, hence b_g + G f_s, is that of the static
    record. A sensor whose vertical is not along one of its axes keeps its static record
    alone (the turns' cross-axis reading is per sensor axis).

    Returns the statistics per sensor and the despiker's counts of the turn records whose
    data were pooled (label -> `integral.spike_counts`, for `integral.record_spikes`): the
    turns' static data are despiked, the counts are archived.
    """
    out, replaced = [], {}
    for r, g in zip(records, gyr, strict=True):
        d = r.mount @ np.array([0.0, 0.0, 1.0])
        j = int(np.argmax(np.abs(d)))
        if not math.isclose(abs(d[j]), 1.0, abs_tol=1e-6):
            out.append(g)
            continue
        up = f"{params.AXES[j]}_up"
        turns = {f"{params.AXES[j]}_ccw": r.ccw, f"{params.AXES[j]}_cw": r.cw}
        rests = turn_rests(turns, {up: g.mean}, {up: g.std})
        out.append(face_rest_stats({up: r.static}, rests)[up])
        for sense, rec in (("ccw", r.ccw), ("cw", r.cw)):
            n_spikes = clean_turn(rec, g.mean, j, g.std, "whole_record")[3]
            replaced[f"{r.name}_{sense}"] = spike_counts(n_spikes, len(rec))
    return out, replaced


def _fit_gyro_matrix(cal: Calibration, theta: np.ndarray, D: np.ndarray, U: np.ndarray) -> float:
    """Add gyr.scale/misalign from the turn differences, row by row; their condition number.

    theta : (S, 3) rotation vector of each sensor's turns, rad; D : (S, 3) ccw - cw
    integral differences, rad; U : (S, 3) their standard uncertainties, rad.
    """
    if np.linalg.matrix_rank(theta / np.linalg.norm(theta, axis=1, keepdims=True), tol=1e-6) < 3:
        raise ValueError(
            "sensor_array: the mountings put the vertical along fewer than three sensor axes; "
            "the gyro scale and misalignment of the other axes are not separable"
        )
    names = params.matrix_names("gyr")
    for i in range(3):
        w = 1.0 / U[:, i]
        tw = theta * w[:, None]
        x = np.linalg.lstsq(tw, D[:, i] * w, rcond=None)[0]
        cov = np.linalg.inv(tw.T @ tw)
        for j in range(3):
            cal.add(names[i][j], x[j] - (1.0 if i == j else 0.0), math.sqrt(cov[j, j]))
    return float(np.linalg.cond(theta))


def _add_residuals(
    cal: Calibration,
    records: list[ArrayRecords],
    f: np.ndarray,
    theta: np.ndarray,
    D: np.ndarray,
    sigmas: np.ndarray,
    durations: np.ndarray,
) -> None:
    """Residuals of each sensor's static record (acc, gyr) and of its turns (gyr)."""
    acc_model = f @ (np.eye(3) + cal.matrix("acc")).T + cal.vector("acc", "bias")
    rest_model = f @ cal.gsens().T + cal.vector("gyr", "bias")
    gyr_matrix = np.eye(3) + cal.matrix("gyr")
    for s, r in enumerate(records):
        st = r.static
        cal.residuals.append(
            segment_residual(
                f"{r.name}_static", "acc", st.acc, np.broadcast_to(acc_model[s], st.acc.shape)
            )
        )
        cal.residuals.append(
            segment_residual(
                f"{r.name}_static", "gyr", st.gyr, np.broadcast_to(rest_model[s], st.gyr.shape)
            )
        )
        # The turns: the misfit of D_s as a mean rate over both records, rad/s, with
        # the sample noise of the gyro as the spread.
        miss = (D[s] - gyr_matrix @ theta[s]) / durations[s]
        cal.residuals.append(
            SegmentResidual(
                f"{r.name}_turns",
                "gyr",
                tuple(float(v) for v in miss),
                tuple(float(v) for v in sigmas[s]),
                len(r.ccw) + len(r.cw),
            )
        )


def array_records(
    segments: dict[str, Recording], mounts: dict[str, np.ndarray]
) -> list[ArrayRecords]:
    """Group segments "<sensor>_static", "<sensor>_ccw", "<sensor>_cw" by sensor."""
    out = []
    for name, mount in mounts.items():
        missing = [f"{name}_{p}" for p in PHASES if f"{name}_{p}" not in segments]
        if missing:
            raise ValueError(f"sensor_array: sensor {name!r} lacks segments {', '.join(missing)}")
        m = np.asarray(mount, dtype=float)
        if m.shape != (3, 3) or not np.allclose(m @ m.T, np.eye(3), atol=1e-6):
            raise ValueError(
                f"settings.mounts.{name}: expected a 3x3 rotation matrix, got {mount!r}"
            )
        out.append(ArrayRecords(name, m, *(segments[f"{name}_{p}"] for p in PHASES)))
    return out


def solve_sensor_array(
    segments: dict[str, Recording], gravity: float, settings: SettingsIn = None
) -> Calibration:
    """Procedure entry.

    settings : typed `SETTINGS` (a mapping is parsed): mounts ({sensor: 3x3
        cube-to-sensor rotation} or "cube6" for the patent's six-IMU cube, the default),
        turns (int or None).
    Segments are labelled "<sensor>_static", "<sensor>_ccw", "<sensor>_cw".
    """
    s = SETTINGS.parse(settings)
    mounts = cube_mounts() if s.mounts == "cube6" else s.mounts
    if not mounts:
        raise ValueError('settings.mounts: expected "cube6" or {sensor = 3x3 rotation matrix}')
    return solve_array(array_records(segments, mounts), gravity, s.turns)


def _turn_differences(records: list, gyr: list, turns: int | None) -> tuple:
    """Per sensor: the turn vector theta_s = 4 pi n d_s, the ccw - cw integral difference
    D_s (rad), its standard uncertainty U_s, the gyro noise, the turns' duration (s), the
    inferred turn counts (when `turns` is None) and, per sensor turning about one of its
    axes, how each cross-axis entry was read ("regression" or "integral").

    A sensor whose vertical is along one of its axes has its turns read as the integral
    method's regression estimator reads them (docs/methods.md 2.6): each turn integrated
    over its motion window, each cross-axis entry the slope on the on-axis rate times the
    on-axis difference where that holds and is the more precise (`integral.regression_column`);
    any other sensor's over the whole records."""
    axis_up = np.array([0.0, 0.0, 1.0])
    theta, D, U, sigmas, durations, inferred, used = [], [], [], [], [], [], {}
    for r, g in zip(records, gyr, strict=True):
        d = r.mount @ axis_up
        j = int(np.argmax(np.abs(d)))
        if math.isclose(abs(d[j]), 1.0, abs_tol=1e-6):
            diff, var, d_t, sigma, duration, cleaned = _windowed(r, g, j)
            used[r.name] = {}
            std = np.sqrt(var + (d_t * g.sem) ** 2)
            column, std = regression_column(params.AXES[j], diff, std, cleaned, used[r.name])
        else:
            sigma = noise_from_differences(r.static.gyr)
            w_ccw, w_cw = trapezoid_weights(r.ccw.t), trapezoid_weights(r.cw.t)
            column = w_ccw @ (r.ccw.gyr - g.mean) - w_cw @ (r.cw.gyr - g.mean)
            d_t = float(w_ccw.sum() - w_cw.sum())
            std = np.sqrt(sigma**2 * (w_ccw @ w_ccw + w_cw @ w_cw) + (d_t * g.sem) ** 2)
            duration = float(w_ccw.sum() + w_cw.sum())
        n = turns
        if n is None:
            n = max(1, round(abs(column @ d) / (4 * math.pi)))
            inferred.append(n)
        theta.append(4 * math.pi * n * d)
        D.append(column)
        U.append(std)
        sigmas.append(sigma)
        durations.append(duration)
    return np.array(theta), np.array(D), np.array(U), sigmas, durations, inferred, used


def _windowed(r: ArrayRecords, g: ChannelStats, j: int) -> tuple:
    """The ccw - cw difference of one sensor's turns about its channel j, each integrated
    over its motion window (`integral.clean_turn`, despiked): difference (3,) rad, its
    noise variance (3,) rad^2, the windows' duration difference and sum (s), the noise std
    (3,) and the despiked records with their noise (sense -> (gyr, sigma)), as
    `integral.regression_column` takes them."""
    parts, cleaned = {}, {}
    for sense, rec in (("ccw", r.ccw), ("cw", r.cw)):
        gyr_c, sigma, span, _ = clean_turn(rec, g.mean, j, g.std, "regression")
        t = rec.t[span]
        w = trapezoid_weights(t)
        T = float(t[-1] - t[0])
        parts[sense] = (w @ gyr_c[span] - g.mean * T, sigma**2 * float(w @ w), T)
        cleaned[sense] = (gyr_c, sigma)
    (j_p, v_p, t_p), (j_m, v_m, t_m) = parts["ccw"], parts["cw"]
    sigma = np.max([c[1] for c in cleaned.values()], axis=0)
    return j_p - j_m, v_p + v_m, t_p - t_m, sigma, t_p + t_m, cleaned
