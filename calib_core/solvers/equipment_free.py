"""Equipment-free multi-position calibration (Tedaldi, Pretto, Menegatti, ICRA 2014).

No table, no known attitudes: the IMU is held still in many (>= 9, better
30+) orientations, moved by hand in between. Two facts carry the calibration:

1. At rest the calibrated specific force has the norm of local gravity, so the
   accelerometer parameters theta_a minimise sum_k rho((|f_k(theta_a)| - g) / s_k)
   over the static intervals k, where f_k = (I + M_a)^-1 (m_k - b_a) is the
   calibrated mean and s_k its standard uncertainty along f_k. rho is Huber's
   loss at 3 sigma, so a badly held pose does not pull the fit.
2. Between two consecutive rests the calibrated gyro, integrated as a rotation
   (quaternions, `calib_core.attitude.integrate_rotation`), must carry the
   gravity direction of one rest into the next: u_k+1 = R_k^T u_k. The gyro
   matrix minimises sum_k |u_k+1 - R_k(theta_g)^T u_k|^2. The gyro bias is the
   mean of the first (long) rest, as in the paper.

Frame: the norm is unchanged by a rotation of the true frame, so only 9 of the
12 accelerometer parameters are observable. The body frame is fixed by the
accelerometer: x along the x sensing axis, y in the plane of the x and y
sensing axes, i.e. I + M_a is lower triangular (acc.misalign.xy = xz = yz = 0).
The gyro matrix (all 9 terms) is then relative to that frame.

Uncertainties: from the Gauss-Newton covariance (J^T J)^-1 of the whitened
accelerometer residuals, inflated by the Birge ratio sqrt(chi2/dof) when it
exceeds 1 (hand tremor, model errors); for the gyro from the residual scatter,
s^2 (J^T J)^-1, with 2 degrees of freedom per motion (a rotation about gravity
does not change u).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib_core import params
from calib_core.attitude import integrate_rotations
from calib_core.calibration import Calibration, SegmentResidual
from calib_core.preprocess.segments import Interval, StaticDetector, detect_static
from calib_core.recording import Recording
from calib_core.settings import Setting, Settings, SettingsIn
from calib_core.solvers.multi_position import segment_residual
from calib_core.stats import channel_stats

# Lower-triangular off-diagonal entries of I + M_a that the norm can see.
ACC_MISALIGN = ((1, 0), (2, 0), (2, 1))
HUBER_SCALE = 3.0  # whitened residuals beyond 3 sigma are down-weighted
# Scaled-Jacobian condition number above which the accelerometer misalignments
# count as unobservable. Poses near the six faces see them only through the
# off-axis components (~0.05 rad for a hand-held IMU), squared: conditions of
# 1e4 and more; 30 spread poses give ~10.
ACC_CONDITION_LIMIT = 1e3

# The procedure's settings (docs/procedures.md); its solver takes them typed.
SETTINGS = Settings(
    Setting("window_s", "number", "s", 1.0, "static detector's variance window", low=0.0,
            low_open=True),
    Setting("init_static_s", "number", "s", 10.0,
            "initial rest the threshold is scaled from", low=0.0, low_open=True),
    Setting("k", "number", "1", 6.0,
            "static threshold as a multiple of the initial rest's variance", low=0.0,
            low_open=True),
    Setting("min_duration_s", "number", "s", 1.0, "shortest rest kept", low=0.0,
            low_open=True),
    Setting("settle_s", "number", "s", 0.5, "time dropped at each end of a rest", low=0.0),
    Setting("min_keep_s", "number", "s", 0.5, "shortest part of a rest left after the settle",
            low=0.0),
    Setting("min_intervals", "integer", "1", 9,
            "fewest rests for the fit (fewer: the threshold is searched)", low=1),
    Setting("segment", "text", "", None,
            "the segment that holds the session (absent: the run's only segment)"),
    name="EquipmentFreeSettings",
)  # fmt: skip


# imu_tk (Tedaldi et al.) searches the static threshold over multiples of the
# initial variance and keeps the one whose accelerometer fit has the least
# residual. We do the same, but only when the operator's k finds too few rests.
# Up to 256: a hand holds a pose with tremor of 10-15 times the noise std of the first
# rest on a table (variance 100-200 times: a hand-held MPU-6050 session's rests appear
# at k >= 100), and the Birge ratio, not the grid's end, must decide.
THRESHOLD_SEARCH_K = (
    2.0,
    3.0,
    4.0,
    6.0,
    8.0,
    12.0,
    16.0,
    24.0,
    32.0,
    48.0,
    64.0,
    96.0,
    128.0,
    192.0,
    256.0,
)
# Detector settings the refusal tries, as factors of the given ones, to name what works.
RELAXED_FACTORS = (0.5, 0.25)
# Fewer accelerometer degrees of freedom than this and the residual scale (Birge
# ratio) is itself uncertain by more than 1/sqrt(2 * 9) = 24 %: too few poses to
# judge the fit or to scale the covariance by it.
MIN_ACC_DOF = 9
# A parameter that moves by more than its standard uncertainty when the detector
# threshold takes its neighbouring grid values is not determined by the session.
DETECTOR_SHIFT_LIMIT_SIGMA = 1.0


@dataclass(frozen=True)
class StaticSet:
    """Static intervals of a recording with their accelerometer statistics.

    intervals : detected intervals in time order.
    acc_mean, acc_sem : (K, 3) mean and standard uncertainty of the mean, m/s^2.
    k : the detector threshold factor that found them.
    """

    intervals: list[Interval]
    acc_mean: np.ndarray
    acc_sem: np.ndarray
    k: float


def statics_at(rec: Recording, settings: Any, k: float) -> StaticSet:
    """Static intervals found with threshold factor `k` (detect_static) and their means."""
    detector = StaticDetector(
        window_s=settings.window_s,
        init_static_s=settings.init_static_s,
        k=k,
        min_duration_s=settings.min_duration_s,
        settle_s=settings.settle_s,
        min_keep_s=settings.min_keep_s,
    )
    intervals = detect_static(rec, detector)
    stats = [channel_stats(rec.acc[iv.slice]) for iv in intervals]
    shape = (len(stats), 3)
    return StaticSet(
        intervals,
        np.array([st.mean for st in stats]).reshape(shape),
        np.array([st.sem for st in stats]).reshape(shape),
        float(k),
    )


def find_statics(rec: Recording, settings: Any, gravity: float) -> StaticSet:
    """The static intervals at settings.k, or from the threshold search if too few.

    The search tries every factor of THRESHOLD_SEARCH_K and keeps, among those
    finding >= min_intervals rests, the one whose norm-condition fit has the
    smallest Birge ratio (imu_tk's criterion). Raises ValueError naming the
    counts found when no factor finds enough.
    """
    need = settings.min_intervals
    found = statics_at(rec, settings, settings.k)
    if len(found.intervals) >= need:
        return found
    tried = {k: statics_at(rec, settings, k) for k in THRESHOLD_SEARCH_K if k != settings.k}
    usable = [st for st in tried.values() if len(st.intervals) >= need]
    if not usable:
        counts = ", ".join(f"k={k:g}: {len(st.intervals)}" for k, st in tried.items())
        raise ValueError(
            f"equipment_free ({rec.source or 'recording'}): found {len(found.intervals)} static "
            f"intervals, need >= {need} (9 accelerometer unknowns); the threshold search found "
            f"{counts}; {_advice(rec, settings, [found, *tried.values()])}"
        )
    return min(usable, key=lambda st: solve_accel_norm(st, gravity)[2]["acc_birge_ratio"])


def _advice(rec: Recording, settings: Any, tried: list[StaticSet]) -> str:
    """What would give enough rests: a shorter min_duration_s or window_s that does (tried
    on the threshold grid), else how many more still orientations the session needs."""
    need = settings.min_intervals
    best: tuple[int, str, float, float] | None = None  # (rests, key, value, k)
    for key in ("min_duration_s", "window_s"):
        for factor in RELAXED_FACTORS:
            relaxed = replace(settings, **{key: getattr(settings, key) * factor})
            for k in THRESHOLD_SEARCH_K:
                try:
                    n = len(statics_at(rec, relaxed, k).intervals)
                except ValueError:
                    break  # the relaxed windows do not fit the record
                if n >= need and (best is None or n > best[0]):
                    best = (n, key, getattr(relaxed, key), k)
    if best is not None:
        n, key, value, k = best
        given = getattr(settings, key)
        return (
            f"settings.{key} = {value:g} (instead of {given:g}) finds {n} rests at "
            f"k = {k:g}: the rests are shorter than the detector asks"
        )
    most = max(len(st.intervals) for st in tried)
    return (
        f"no threshold up to k = {THRESHOLD_SEARCH_K[-1]:g} nor a shorter min_duration_s or "
        f"window_s finds more than {most}: hold the IMU still in at least {need - most} more "
        f"orientations, each for >= {settings.min_duration_s:g} s plus the settle time "
        f"({settings.settle_s:g} s)"
    )


ACC_NAMES = (
    [params.bias("acc", x) for x in params.AXES]
    + [f"acc.scale.{x}" for x in params.AXES]
    + [f"acc.misalign.{params.AXES[i]}{params.AXES[j]}" for i, j in ACC_MISALIGN]
)


def acc_matrix(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(I + M_a, b_a) from theta = [b (3), scale (3), M_yx, M_zx, M_zy]."""
    a = np.diag(1.0 + theta[3:6])
    for (i, j), v in zip(ACC_MISALIGN, theta[6:9], strict=True):
        a[i, j] = v
    return a, theta[0:3]


def _acc_residuals(theta: np.ndarray, means: np.ndarray, sems: np.ndarray, g: float) -> np.ndarray:
    a, b = acc_matrix(theta)
    f = np.linalg.solve(a, (means - b).T).T
    norm = np.linalg.norm(f, axis=1)
    # Uncertainty of |f| from the per-axis uncertainties of the mean, along f.
    s = np.sqrt((((f / norm[:, None]) * sems) ** 2).sum(axis=1))
    return (norm - g) / s


def _covariance(jac: np.ndarray, scale2: float) -> np.ndarray:
    return scale2 * np.linalg.pinv(jac.T @ jac)


def _fit_norm(
    means: np.ndarray, sems: np.ndarray, gravity: float, free: np.ndarray
) -> tuple[np.ndarray, object]:
    """Robust fit of the free entries of theta (the others stay 0)."""

    def fun(x: np.ndarray) -> np.ndarray:
        theta = np.zeros(9)
        theta[free] = x
        return _acc_residuals(theta, means, sems, gravity)

    from scipy.optimize import least_squares  # slow to import: only for equipment-free runs

    res = least_squares(
        fun,
        np.zeros(free.size),
        loss="huber",
        f_scale=HUBER_SCALE,
        x_scale=np.r_[np.full(3, 0.1), np.full(6, 1e-2)][free],
        xtol=1e-10,
        ftol=1e-10,
    )
    theta = np.zeros(9)
    theta[free] = res.x
    return theta, res


def _scaled_condition(jac: np.ndarray) -> float:
    """Condition number of a Jacobian with unit-norm columns (scale-free)."""
    j = np.asarray(jac)
    return float(np.linalg.cond(j / np.maximum(np.linalg.norm(j, axis=0), 1e-300)))


def solve_accel_norm(statics: StaticSet, gravity: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """Accelerometer theta (9,) and covariance (9, 9) from the norm condition.

    If the poses cannot see the misalignments (all near the faces: the norm
    depends on them only to second order), the scaled Jacobian is nearly
    singular (condition > ACC_CONDITION_LIMIT); the misalignments are then
    fixed at 0 (covariance rows 0) and info["acc_misalign_observable"] is False.

    Returns
    -------
    (theta, cov, info) with info: chi2, dof, birge ratio, norm rms before and
    after, condition number, observability of the misalignments.
    """
    means, sems = statics.acc_mean, statics.acc_sem
    free = np.arange(9)
    theta, res = _fit_norm(means, sems, gravity, free)
    condition = _scaled_condition(res.jac)
    observable = condition <= ACC_CONDITION_LIMIT
    if not observable:
        free = np.arange(6)
        theta, res = _fit_norm(means, sems, gravity, free)
    r = _acc_residuals(theta, means, sems, gravity)
    a, b = acc_matrix(theta)
    norm_after = np.linalg.norm(np.linalg.solve(a, (means - b).T), axis=0)
    dof = max(r.size - free.size, 1)
    chi2 = float(r @ r)
    birge2 = max(1.0, chi2 / dof)
    cov = np.zeros((9, 9))
    cov[np.ix_(free, free)] = _covariance(res.jac, birge2)
    info = {
        "acc_chi2": chi2,
        "acc_dof": dof,
        "acc_birge_ratio": float(np.sqrt(chi2 / dof)),
        "acc_norm_rms_before": float(
            np.sqrt(np.mean((np.linalg.norm(means, axis=1) - gravity) ** 2))
        ),
        "acc_norm_rms_after": float(np.sqrt(np.mean((norm_after - gravity) ** 2))),
        "acc_outliers_huber": int(np.sum(np.abs(r) > HUBER_SCALE)),
        "acc_condition_number": condition,
        "acc_misalign_observable": bool(observable),
    }
    return theta, cov, info


def _motions(
    rec: Recording, intervals: list[Interval], bias: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(t, gyr - bias) of each motion, from the last sample of one rest to the first of the next."""
    out = []
    for before, after in zip(intervals[:-1], intervals[1:], strict=True):
        s = slice(before.end_index - 1, after.start_index + 1)
        out.append((rec.t[s], rec.gyr[s] - bias))
    return out


def _gyr_residuals(theta: np.ndarray, motions: list, up: np.ndarray) -> np.ndarray:
    a_inv = np.linalg.inv(np.eye(3) + theta.reshape(3, 3))
    r = integrate_rotations(motions, a_inv)  # (K-1, 3, 3)
    # u_k+1 = R_k^T u_k
    return (up[1:] - np.einsum("kji,kj->ki", r, up[:-1])).ravel()


def solve_gyro_rotations(
    rec: Recording, statics: StaticSet, up: np.ndarray, bias: np.ndarray
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Gyro matrix M_g (9,) (row-major) and covariance from gravity carried between rests.

    Parameters
    ----------
    rec : the whole recording.
    statics : its static intervals.
    up : (K, 3) calibrated unit gravity direction of each rest.
    bias : (3,) gyro bias, rad/s.
    """
    motions = _motions(rec, statics.intervals, bias)
    from scipy.optimize import least_squares

    x0 = np.zeros(9)
    res = least_squares(
        _gyr_residuals, x0, args=(motions, up), x_scale=1e-2, xtol=1e-10, ftol=1e-10
    )
    r = res.fun
    before = _gyr_residuals(x0, motions, up)
    dof = max(2 * len(motions) - 9, 1)
    s2 = float(r @ r) / dof
    cov = _covariance(res.jac, s2)
    info = {
        "gyr_motions": len(motions),
        "gyr_dof": dof,
        # Per degree of freedom: 3 components carry 2 degrees of freedom per motion.
        "gyr_residual_rms_rad_before": float(np.sqrt(before @ before / (2 * len(motions)))),
        "gyr_residual_rms_rad_after": float(np.sqrt(s2)),
    }
    return res.x, cov, info


def calibrate_equipment_free(
    rec: Recording, gravity: float, settings: SettingsIn = None
) -> Calibration:
    """Equipment-free calibration of one hand-held multi-pose recording.

    Parameters
    ----------
    rec : one continuous recording starting with >= init_static_s at rest,
        then many still poses joined by motions; SI units.
    gravity : local gravity, m/s^2.
    settings : static detection (window_s, init_static_s, k, min_duration_s,
        settle_s, min_keep_s) and min_intervals.

    Returns
    -------
    Calibration "equipment_free": acc.bias.*, acc.scale.*, acc.misalign.{yx,zx,zy}
    (frame convention in the module docstring), gyr.bias.* (first rest),
    gyr.scale.*, gyr.misalign.*; residuals per static interval; info with the
    fit statistics, the number of intervals and the frame convention.
    """
    s = SETTINGS.parse(settings)
    statics = find_statics(rec, s, gravity)
    theta_a, cov_a, info_a = solve_accel_norm(statics, gravity)
    a, b = acc_matrix(theta_a)
    f_cal = np.linalg.solve(a, (statics.acc_mean - b).T).T
    up = f_cal / np.linalg.norm(f_cal, axis=1, keepdims=True)

    first = channel_stats(rec.gyr[statics.intervals[0].slice])
    theta_g, cov_g, info_g = solve_gyro_rotations(rec, statics, up, first.mean)

    cal = Calibration(procedure="equipment_free", gravity=gravity)
    std_a = np.sqrt(np.diag(cov_a))
    names_a = ACC_NAMES
    n_acc = 9 if info_a["acc_misalign_observable"] else 6
    for name, v, u in list(zip(names_a, theta_a, std_a, strict=True))[:n_acc]:
        cal.add(name, v, u)
    if n_acc == 6:
        cal.warnings.append(
            "equipment_free: the static poses are all near the six faces, so the norm "
            f"condition cannot see the accelerometer misalignments (condition number "
            f"{info_a['acc_condition_number']:.3g}); they were fixed at 0. Add tilted poses"
        )
    for i, x in enumerate(params.AXES):
        cal.add(params.bias("gyr", x), first.mean[i], first.sem[i])
    std_g = np.sqrt(np.diag(cov_g))
    flat_names = [n for row in params.matrix_names("gyr") for n in row]
    for name, v, u in zip(flat_names, theta_g, std_g, strict=True):
        cal.add(name, v, u)

    residuals: list[SegmentResidual] = []
    for k, iv in enumerate(statics.intervals):
        label = f"static_{k:02d}"
        acc = rec.acc[iv.slice]
        # Model: the calibrated direction at exactly g, through the error model.
        model = (gravity * up[k]) @ a.T + b
        residuals.append(segment_residual(label, "acc", acc, np.broadcast_to(model, acc.shape)))
        residuals.append(segment_residual(label, "gyr", rec.gyr[iv.slice], first.mean))
    cal.residuals = residuals
    cal.info.update(info_a)
    cal.info.update(info_g)
    cal.info.update(
        {
            "static_intervals": len(statics.intervals),
            "static_seconds": float(sum(iv.duration for iv in statics.intervals)),
            "frame": "accelerometer-defined: I + M_a lower triangular (acc.misalign.xy/xz/yz = 0)",
            "acc_correlation_max": float(
                np.max(
                    np.abs(
                        np.triu(cov_a[:n_acc, :n_acc] / np.outer(std_a, std_a)[:n_acc, :n_acc], 1)
                    )
                )
            ),
        }
    )
    cal.info["static_threshold_k"] = statics.k
    raised = []
    if statics.k != s.k:
        cal.warnings.append(
            f"equipment_free: k = {s.k:g} found too few rests; the threshold search "
            f"took k = {statics.k:g} ({len(statics.intervals)} rests)"
        )
        # A finding about the record: its rests are less still than the setting expects.
        raised.append(
            {
                "name": "record:threshold:static_k",
                "value": float(statics.k),
                "limit": float(s.k),
                "passed": False,
                "detail": f"{cal.warnings[-1]}: the rests were found with a relaxed threshold",
            }
        )
    cal.info.setdefault("solver_checks", []).extend(
        [
            *raised,
            _dof_check(info_a["acc_dof"]),
            _detector_check(detector_shifts(rec, s, statics, theta_a, cov_a, gravity)),
        ]
    )
    if info_a["acc_outliers_huber"]:
        cal.warnings.append(
            f"{info_a['acc_outliers_huber']} of {len(statics.intervals)} static intervals miss "
            f"the norm condition by more than {HUBER_SCALE:g} sigma (down-weighted)"
        )
    return cal


def detector_shifts(
    rec: Recording,
    settings: Any,
    statics: StaticSet,
    theta: np.ndarray,
    cov: np.ndarray,
    gravity: float,
) -> dict[str, float]:
    """How far each accelerometer parameter moves, in its standard uncertainties,
    when the detector threshold takes the neighbouring values of the search grid.

    Only the accelerometer fit is repeated: it is what the rests decide directly
    (the gyro fit then follows from the same rests). Neighbours that find too few
    rests are skipped; returns name -> largest |change| / std (empty if none).
    """
    grid = sorted({*THRESHOLD_SEARCH_K, statics.k})
    i = grid.index(statics.k)
    std = np.sqrt(np.diag(cov))
    shifts: dict[str, float] = {}
    for k in grid[max(i - 1, 0) : i] + grid[i + 1 : i + 2]:
        other = statics_at(rec, settings, k)
        if len(other.intervals) < settings.min_intervals:
            continue
        theta_k, cov_k, _ = solve_accel_norm(other, gravity)
        both = (std > 0) & (np.diag(cov_k) > 0)  # misalignments may be fixed in one fit
        for j in np.flatnonzero(both):
            z = abs(theta_k[j] - theta[j]) / std[j]
            shifts[ACC_NAMES[j]] = max(shifts.get(ACC_NAMES[j], 0.0), float(z))
    return shifts


def _dof_check(dof: int) -> dict[str, Any]:
    return {
        "name": "model:acc_dof",
        "value": float(dof),
        "limit": float(MIN_ACC_DOF),
        "passed": dof >= MIN_ACC_DOF,
        "detail": "accelerometer degrees of freedom (rests minus free parameters), at least; "
        "fewer and the fit cannot be judged: hold the IMU in more poses",
    }


def _detector_check(shifts: dict[str, float]) -> dict[str, Any]:
    detail = (
        "largest change of an accelerometer parameter, in its standard uncertainties, "
        "between the static detector's threshold and its neighbours"
    )
    if not shifts:  # sensitivity unknown: not a pass
        detail += "; no neighbouring threshold found enough rests to compare"
        worst = None
    else:
        worst = max(shifts.values())
        moved = sorted(n for n, z in shifts.items() if z > DETECTOR_SHIFT_LIMIT_SIGMA)
        detail += f"; not determined by this session: {', '.join(moved)}" if moved else ""
    return {
        "name": "model:detector_sensitivity",
        "value": worst,
        "limit": DETECTOR_SHIFT_LIMIT_SIGMA,
        "passed": worst is not None and worst <= DETECTOR_SHIFT_LIMIT_SIGMA,
        "detail": detail,
    }


def solve_equipment_free(
    segments: dict[str, Recording], gravity: float, settings: SettingsIn = None
) -> Calibration:
    """Procedure entry: the one segment of the run (or settings.segment) is the session."""
    s = SETTINGS.parse(settings)
    label = s.segment
    if label is None:
        if len(segments) != 1:
            raise ValueError(
                f"equipment_free: expected one continuous segment, got {len(segments)} "
                f"({', '.join(segments)}); name it with settings.segment"
            )
        label = next(iter(segments))
    if label not in segments:
        raise ValueError(
            f"equipment_free: settings.segment {label!r} is not among {list(segments)}"
        )
    cal = calibrate_equipment_free(segments[label], gravity, s)
    cal.info["segment"] = label
    return cal


def transport_residual_rms(rec: Recording, cal: Calibration, settings: SettingsIn = None) -> float:
    """How well a calibration's gyro carries gravity between the rests of a session, rad.

    Any calibration (e.g. a six-position + integral one) can be judged on a
    hand-held session: the accelerometer of `cal` gives the gravity direction of
    each rest, its gyro bias and matrix the rotations between them. Returns the
    rms miss |u_k+1 - R_k^T u_k| per degree of freedom (2 per motion).
    """
    s = SETTINGS.parse(settings)
    statics = find_statics(rec, s, cal.gravity)
    f_cal, _ = cal.correct(statics.acc_mean, np.zeros_like(statics.acc_mean))
    up = f_cal / np.linalg.norm(f_cal, axis=1, keepdims=True)
    motions = _motions(rec, statics.intervals, cal.vector("gyr", "bias"))
    r = _gyr_residuals(cal.matrix("gyr").ravel(), motions, up)
    return float(np.sqrt(r @ r / (2 * len(motions))))
