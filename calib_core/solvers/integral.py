"""Integral method: gyro scale and misalignment without a rate table (docs/methods.md 2.6).

The fixture is turned n whole turns counter-clockwise (+) and clockwise (-)
about each axis A in turn, with A pointing up. With the true rotation only
about A and the specific force constant (g along A), channel c reads

    w_c(t) = (delta_cA + M_cA) w_A(t) + S_c,    S_c = b_c + (G f)_c,

where S_c is exactly what the gyro reads at rest in the same orientation (the
"A up" static position). Integrating over each record with the trapezoid rule
and subtracting S_c times the record's own duration T explicitly,

    J_c+- = I_c+- - S_c T+- = +-(delta_cA + M_cA) 2 pi n + noise,

so (J_c+ - J_c-) / (4 pi n) = delta_cA + M_cA. This is the paper's formula
(Gxx = (I^X_x+ - I^X_x-)/(2 * 360 n) - 1, ...) in radians, written directly in
the matrix convention: gyr.misalign.cA is M[c, A] (the paper's Gxz is M[x, y],
Gxy is -M[x, z], Gyz is -M[y, x], Gyx is M[y, z], Gzy is M[z, x], Gzx is
-M[z, y]). Because the static reading is subtracted per record, cw and ccw
records of different lengths do not bias the result.

That is the literal reading (``estimator="whole_record"``). The default
(``"regression"``, `turn_motion`) integrates each record over its turn's motion window
only and reads each cross-axis entry as its least-squares proportion to the on-axis rate
times the on-axis entry: the same column (I + M) e_A, at the Cramer-Rao bound on a rigid
turn (docs/methods.md 2.6).

Uncertainty: white noise of std sigma_c gives the integral a std sigma_c ||w||
(w: trapezoid weights); the subtracted static mean enters as (T+ - T-) times
its standard error. Both are propagated.
"""

from __future__ import annotations

import math

import numpy as np

from calib_core import params
from calib_core.calibration import Calibration
from calib_core.preprocess.replaced import replaced_check
from calib_core.recording import Recording
from calib_core.settings import Setting
from calib_core.solvers.six_position import UP_CHANNEL, reference_up
from calib_core.solvers.turn_motion import (
    REST_S,
    REST_SAMPLES,
    TURN_ESTIMATORS,
    cross_axis_ratios,
    face_rest_stats,
    motion_window,
)
from calib_core.stats import ChannelStats, row_medians, trapezoid_weights
from calib_core.units import DEG, STANDARD_GRAVITY

# Rotation records: n whole turns about the axis, axis up; ccw = positive rate.
ROTATION_LABELS = ("x_ccw", "x_cw", "y_ccw", "y_cw", "z_ccw", "z_cw")
# The setting of the procedures that integrate turns (six_position_integral, integral,
# sensor_array).
TURNS = Setting(
    "turns", "integer", "1", None,
    "whole turns of each rotation (absent: inferred from the data)", low=1)  # fmt: skip

# A rate within this fraction of full scale counts as saturated (sensors clip at
# 32767/32768 of the range, files round to the last digit).
SATURATION_MARGIN = 1e-3
# |n_est - round(n_est)| above this means the turn count cannot be inferred.
TURN_TOLERANCE = 0.25


def noise_from_differences(gyr: np.ndarray) -> np.ndarray:
    """Per-sample white-noise std per channel from second differences, rad/s.

    For white noise, the second difference has std sqrt(6) sigma; the smooth
    rotation contributes little to it, and the median (MAD) ignores outliers.

    Parameters
    ----------
    gyr : (N, 3) rad/s.

    Returns
    -------
    (3,) rad/s.
    """
    # One contiguous row per channel: the medians partition rows in place.
    d2 = np.diff(np.ascontiguousarray(np.asarray(gyr, dtype=float).T), n=2, axis=1)
    deviation = np.abs(d2 - row_medians(d2.copy())[:, None])
    return row_medians(deviation) / 0.6744897501960817 / math.sqrt(6.0)


# A rotation sample further than this many local stds (of r in `despike`) from its
# neighbours' mean, with both neighbours off by half as much the other way, is a spike.
# White noise alone passes the first test with probability 2 Q(5) = 5.7e-7 per sample.
SPIKE_SIGMA = 5.0
SPIKE_FALSE_ALARM = 5.733031438470704e-07  # 2 Q(SPIKE_SIGMA)
# The local scatter a spike must stand out of: the 4th largest |r| among the 19 samples on
# each side of it beyond its neighbours (38 values its own r's do not touch), over its
# median for white noise (1.651, simulated). A hand-turned rotation's tremor, heavy-tailed
# and spanning several samples at 100-200 Hz, raises it with the motion; another spike
# within 20 samples (3 values) does not.
SPIKE_WINDOW_SIDE = 19
SPIKE_LOCAL_RANK = 4
SPIKE_LOCAL_TO_SIGMA = 1.0 / 1.651
# The motion's jumps a spike must stand out of: the 3rd largest |x_j+1 - x_j| (about the
# local slope) among the 39 around the two the sample makes, over its median for white
# noise (1.80 std of a difference, simulated); another spike's two jumps do not count.
# A turned-by-hand rate dips and recovers within 2-3 samples: its jumps are as large as
# a lone dip's, a glitch's are not.
SPIKE_JUMP_RANK = 3
SPIKE_JUMP_TO_SIGMA = 1.0 / 1.80
# Local stds within which both neighbours must be what a lone spike makes of them, and
# beyond which another axis at the same sample counts as moving.
SPIKE_NEIGHBOUR_SIGMA = 3.0


def despike(gyr: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Replace isolated spikes in a rotation record by the mean of their neighbours.

    A spike is one sample that stands out of its surroundings in every way a lone
    glitch does and motion does not:

    - off the line through its neighbours (r) by SPIKE_SIGMA times the larger of the
      noise and the motion's own scatter of r over the 20 samples either side;
    - both neighbours off by half as much the other way (within 3 local stds) and
      agreeing with each other (a rate step leaves the sample near one of them);
    - both its jumps (onto it, off it) SPIKE_SIGMA times beyond the motion's jumps
      around it (a hand-turned rate dips and recovers within 2-3 samples);
    - no other axis moving at that sample beyond 3 local stds without a spike's shape
      (a jerk of the fixture shows on several axes; a glitch is spike-shaped wherever
      it shows).

    A hand-turned rotation is continuous over several samples at the rate it is
    sampled, so its sharpest samples fail at least one of these.

    Parameters
    ----------
    gyr : (N, 3) rad/s.
    sigma : (3,) white-noise std per channel, rad/s (robust: `noise_from_differences`
        or the static record's).

    Returns
    -------
    (cleaned (N, 3), spikes replaced per channel (3,)). The integral of a spike is its
    height times the sample period; a few of them double the integral's error. A
    channel with sigma 0 (noise-free data) is left as it is.
    """
    gyr = np.asarray(gyr, dtype=float)
    if gyr.shape[0] < 3:
        return gyr, np.zeros(3, dtype=int)
    sigma = np.asarray(sigma, dtype=float) * math.sqrt(1.5)  # std of r below
    # r_i = x_i - (x_i-1 + x_i+1) / 2: a spike h gives r_i = h and r_i+-1 = -h/2 (both
    # neighbours); a kink of the rate profile gives r at one sample only, a smooth rate ~0.
    r = np.zeros_like(gyr)
    r[1:-1] = gyr[1:-1] - 0.5 * (gyr[:-2] + gyr[2:])
    # The window filters (scipy.ndimage's rank and median filters, mode "nearest") are
    # taken only at the rows where they are read: every sample's cost them more than the
    # rest of the solve. `_rank_at` picks the same element of the same window.
    side = SPIKE_WINDOW_SIDE + 1  # i - w - 1 .. i + w + 1
    # Candidates (rare: the scale is never below the noise's, so white noise passes the
    # first test at most SPIKE_FALSE_ALARM of the time), then their neighbours' tests.
    # The sample's own three r values are the largest of a spike's window: rank past them.
    rows = 1 + np.flatnonzero((np.abs(r[1:-1]) > SPIKE_SIGMA * sigma).any(axis=1))
    local = SPIKE_LOCAL_TO_SIGMA * _rank_at(np.abs(r), rows, 2 * side - 2 - SPIKE_LOCAL_RANK, side)
    scale = np.zeros_like(gyr)
    scale[rows] = np.maximum(local, sigma)
    k, ch = np.nonzero((np.abs(r[rows]) > SPIKE_SIGMA * scale[rows]) & (sigma > 0))
    i = rows[k]
    # Jumps d_j = x_j+1 - x_j about the local slope (their median over the window); the
    # sample's own two are d_i-1 and d_i, the largest of a spike's window. Row i of the
    # jumps is d's row min(i, n - 2) (the last sample repeats the last jump's).
    d = np.diff(gyr, axis=0)
    last = len(d) - 1
    at = np.minimum(i, last)
    around = (at[:, None] + np.arange(-side, side + 1)).ravel()
    need = np.unique(np.clip(np.concatenate([i - 1, around]), 0, last))
    d_rel = np.zeros_like(d)
    d_rel[need] = d[need] - _rank_at(d, need, side, side)
    jumps = _rank_at(np.abs(d_rel), at, 2 * side - 1 - SPIKE_JUMP_RANK, side)
    jumps = jumps[np.arange(i.size), ch]  # per candidate
    jump_scale = np.maximum(SPIKE_JUMP_TO_SIGMA * jumps, sigma[ch] / math.sqrt(0.75))
    d = d_rel
    # A lone spike h makes r_i+-1 = -h/2 exactly; what is left, r_i+-1 + r_i / 2, is the
    # noise (std sqrt(14) / 4 sigma = 0.76 std of r) on a smooth rate, and the motion's
    # own curvature when the turn shakes: held to 3 of the local stds.
    near = SPIKE_NEIGHBOUR_SIGMA * math.sqrt(14.0 / 16.0 / 1.5) * scale[i, ch]
    shaped = (
        (np.abs(r[i - 1, ch] + 0.5 * r[i, ch]) < near)
        & (np.abs(r[i + 1, ch] + 0.5 * r[i, ch]) < near)
        # The neighbours agree with each other about the local slope (a turn's ramp
        # moves them apart by twice a step's slope): the sample stands out from each by at
        # least half its height. A step of the rate (a turn starting or stopping within
        # a sample) leaves the sample near one neighbour: motion, not a spike.
        & (np.abs(d[i - 1, ch] + d[i, ch]) < np.abs(r[i, ch]))
        # Both jumps, onto the sample and off it, beyond the motion's own jumps around it.
        & (np.minimum(np.abs(d[i - 1, ch]), np.abs(d[i, ch])) > SPIKE_SIGMA * jump_scale)
    )
    i, ch = i[shaped], ch[shaped]
    # A jerk of the fixture moves the other axes at the same sample beyond their noise
    # without a spike's shape; an electrical glitch is spike-shaped wherever it shows.
    moving = np.abs(r[i]) > SPIKE_NEIGHBOUR_SIGMA * scale[i]
    # ... unless that axis has a spike of its own next to the sample (a glitch on another
    # channel one sample away: its neighbour's r is -1/2 of it, the larger of the two).
    beside = np.maximum(np.abs(r[np.maximum(i - 1, 0)]), np.abs(r[np.minimum(i + 1, len(r) - 1)]))
    moving &= ~(beside > 1.5 * np.abs(r[i]))
    moving[np.arange(i.size), ch] = False
    for j in range(i.size):  # candidates are rare: spike-shaped others do not count
        moving[j, ch[(i == i[j])]] = False
    lone = ~moving.any(axis=1)
    i, ch = i[lone], ch[lone]
    cleaned = gyr.copy()
    cleaned[i, ch] = gyr[i, ch] - r[i, ch]  # the neighbours' mean
    return cleaned, np.bincount(ch, minlength=3)


def _rank_at(x: np.ndarray, rows: np.ndarray, rank: int, side: int) -> np.ndarray:
    """Per channel, the `rank`-th smallest (0-based) of x's rows ``row - side .. row +
    side`` (clipped to the record: scipy.ndimage's mode "nearest") for each of `rows`:
    what ``rank_filter(x, rank, size=(2 * side + 1, 1), mode="nearest")[rows]`` gives.

    Parameters
    ----------
    x : (N, 3). rows : (k,) row indices. rank : 0 .. 2 * side. side : samples each side.

    Returns
    -------
    (k, 3), in x's unit.
    """
    if rows.size == 0:
        return np.zeros((0, x.shape[1]))
    window = np.clip(rows[:, None] + np.arange(-side, side + 1), 0, len(x) - 1)
    return np.partition(x[window], rank, axis=1)[:, rank]


def spike_counts(n_spikes: np.ndarray, n_samples: int) -> dict:
    """One rotation's despiker counts: replaced samples per channel and samples tested."""
    return {
        "replaced": {f"gyr.{a}": int(n) for a, n in zip(params.AXES, n_spikes, strict=True)},
        "tested": 3 * max(n_samples - 2, 0),
    }


def record_spikes(cal: Calibration, replaced: dict[str, dict]) -> None:
    """Put the despiker's counts in ``cal.info["replaced_samples"]["despike"]`` (archived
    with the solve step) and one ``model:replaced:despike:<segment>`` check per rotation:
    failed when it replaced more samples than its false alarms explain."""
    cal.info.setdefault("replaced_samples", {})["despike"] = {
        label: c["replaced"] for label, c in replaced.items()
    }
    checks = cal.info.setdefault("solver_checks", [])
    for label, c in replaced.items():
        checks.append(
            replaced_check("despike", label, c["replaced"], c["tested"], SPIKE_FALSE_ALARM)
        )


def _check_range(rec: Recording, label: str, gyro_range: float) -> None:
    peak = float(np.max(np.abs(rec.gyr)))
    if peak >= gyro_range * (1.0 - SATURATION_MARGIN):
        raise ValueError(
            f"rotation {label}: gyro rate reached {peak / DEG:.1f} deg/s, the sensor range is "
            f"{gyro_range / DEG:.1f} deg/s; the integral would be wrong: repeat the rotation "
            "more slowly"
        )


def solve_integral(
    rotations: dict[str, Recording],
    static_means: dict[str, np.ndarray],
    static_sems: dict[str, np.ndarray],
    gyro_range: float,
    turns: int | None = None,
    *,
    noise_std: dict[str, np.ndarray] | None = None,
    gravity: float = STANDARD_GRAVITY,
    directions: str = "both",
    estimator: str = "regression",
) -> Calibration:
    """Gyro scale errors and misalignments by the integral method.

    Parameters
    ----------
    rotations : label -> Recording for x_ccw, x_cw, y_ccw, y_cw, z_ccw, z_cw.
    static_means : static label ("x_up", ...) -> (3,) mean gyro output at rest,
        rad/s; the "A_up" mean is subtracted from the A rotations.
    static_sems : static label -> (3,) standard uncertainty of that mean, rad/s.
    gyro_range : gyro full scale, rad/s; a rotation reaching it is rejected.
    turns : whole turns per rotation, or None to infer it from the rotation-axis
        integrals (all three axes must show the same whole number).
    noise_std : static label -> (3,) per-sample gyro noise std, rad/s (from the
        static record of the same orientation). None: estimated from the second
        differences of each rotation record.
    gravity : m/s^2, recorded in the result only (the method does not use it).
    directions : "both" (default): ccw and cw about every axis. "any": per axis
        one rotation suffices (Ferraris et al. 1995, e.g. imucal sessions); a
        lone rotation gives the column J / (+-2 pi n), its bias removed by the
        static mean alone instead of cancelling in the ccw - cw difference.
    estimator : "regression" (default): each turn integrated over its motion window,
        each cross-axis integral as its least-squares proportion to the on-axis rate
        times the on-axis integral (`turn_motion`); "whole_record": the paper's literal
        reading, every channel integrated over the whole record.

    Returns
    -------
    Calibration (procedure "integral") with gyr.scale.* and gyr.misalign.*,
    each with its standard uncertainty; info["turns"] and
    info["integral_closure_rad"] (ccw + cw angle mismatch per axis, rad).

    Raises
    ------
    ValueError naming the segment: a missing rotation or static mean, a rotation
    that reached the gyro range, a turn count that is not a whole number.
    """
    _check_inputs(rotations, static_means, gyro_range, turns, directions, estimator)
    at_rest = check_turns_at_rest(rotations, static_means)
    replaced: dict[str, dict] = {}
    J, var, duration, cleaned = _integrals(rotations, static_means, noise_std, replaced, estimator)
    n = _turn_count(J, turns)
    check_closure(J, var, duration, static_sems, rotations)
    used: dict[str, str] = {}

    cal = Calibration(procedure="integral", gravity=gravity)
    closure: dict[str, float] = {}
    C, std = np.zeros((3, 3)), np.zeros((3, 3))
    for j, a in enumerate(params.AXES):
        denom = 2.0 * math.pi * n * len(J[a])  # 4 pi n with both senses
        dT = _signed_sum(duration[a])
        sem = np.asarray(static_sems[f"{a}_up"], dtype=float)
        std[:, j] = np.sqrt(sum(var[a].values()) + (dT * sem) ** 2) / denom
        C[:, j] = _signed_sum(J[a]) / denom  # (I + M_g) times the rotation axis
        if estimator == "regression":
            C[:, j], std[:, j] = regression_column(a, C[:, j], std[:, j], cleaned[a], used)
        if len(J[a]) == 2:
            closure[a] = float((J[a]["ccw"][j] + J[a]["cw"][j]) / 2.0)
    axes = _rotation_axes(rotations)
    # Rotations about true axes U (a face not square): C = (I + M_g) U. U is within a
    # small angle of I, so the columns' uncertainties carry over to first order.
    I_M = C if axes is None else C @ np.linalg.inv(axes)
    for j in range(3):
        for i in range(3):
            name = params.matrix_names("gyr")[i][j]
            cal.add(name, I_M[i, j] - (1.0 if i == j else 0.0), std[i, j])
    single = [a for a in params.AXES if len(J[a]) == 1]
    if single:
        cal.warnings.append(
            f"integral method: one rotation direction only about {', '.join(single)}; the "
            "gyro bias is removed by the static mean alone (no ccw/cw cancellation)"
        )
    cal.info["turns"] = n
    cal.info.setdefault("solver_checks", []).extend(at_rest)
    cal.info["turn_estimator"] = estimator
    if estimator == "regression":
        cal.info["misalignment_by"] = used
    record_spikes(cal, replaced)
    cal.info["integral_closure_rad"] = closure
    cal.info["rotation_durations_s"] = {
        f"{a}_{s}": duration[a][s] for a in params.AXES for s in ("ccw", "cw") if s in duration[a]
    }
    return cal


# A turn begins and ends at rest: the mean rate over its first and last REST_S (at least
# REST_SAMPLES samples; turn_motion's) may differ from the static reading of its orientation
# by REST_FRACTION of the turn's peak rate plus REST_SIGMA standard errors of that mean.
# Beyond it the turn is a finding (a record cut a little early: imucal's annotated x_cw ends
# at 11 % of its peak); beyond MOVING_FRACTION of the peak it was cut mid-turn (a log cut at
# 1.5 rad/s was archived 3134 standard uncertainties off) and is refused.
REST_FRACTION = 0.05
REST_SIGMA = 6.0
MOVING_FRACTION = 0.25
# The angles of a ccw and a cw turn about one axis agree within CLOSURE_SIGMA standard
# uncertainties of their mean (the common part, which the scale's difference cancels): a
# turn cut a little short of its end (at rest, or in its last slow degrees) shifts the
# scale by as many of its own standard uncertainties as the closure (same variance), so a
# closure within 6 keeps the scale within 6 of the whole turns'.
CLOSURE_SIGMA = 6.0


def check_turns_at_rest(
    rotations: dict[str, Recording], static_means: dict[str, np.ndarray]
) -> list[dict]:
    """The ``record:rest:<label>`` finding of each rotation that does not quite begin or end
    at rest (CheckResult fields); ValueError naming the segment, its file and the rate
    measured for one cut mid-turn."""
    findings = []
    for label, rec in rotations.items():
        S = np.asarray(static_means[f"{label[0]}_up"], dtype=float)
        peak = float(np.linalg.norm(rec.gyr - S, axis=1).max())
        step = float(np.median(np.diff(rec.t))) if len(rec) > 1 else 0.0
        m = max(REST_SAMPLES, int(round(REST_S / step)) if step > 0 else REST_SAMPLES)
        m = min(m, max(len(rec) // 4, 1))
        sigma = float(np.linalg.norm(noise_from_differences(rec.gyr)))
        limit = REST_FRACTION * peak + REST_SIGMA * sigma / math.sqrt(m)
        worst = max(
            (float(np.linalg.norm(part.mean(axis=0) - S)), where)
            for where, part in (("begins", rec.gyr[:m]), ("ends", rec.gyr[-m:]))
        )
        if worst[0] <= limit:
            continue
        what = (
            f"rotation {label} ({rec.source or 'recording'}) {worst[1]} turning: "
            f"{worst[0] / DEG:.3g} deg/s from its rest reading over its "
            f"{'first' if worst[1] == 'begins' else 'last'} {m} samples (peak "
            f"{peak / DEG:.3g} deg/s; at rest: at most {limit / DEG:.3g} deg/s)"
        )
        if worst[0] > MOVING_FRACTION * peak + REST_SIGMA * sigma / math.sqrt(m):
            raise ValueError(
                f"{what}: a turn must begin and end at rest; the record was cut mid-turn, "
                "repeat or re-cut the rotation"
            )
        findings.append(
            {
                "name": f"record:rest:{label}",
                "value": worst[0],
                "limit": limit,
                "passed": False,
                "detail": f"{what}: part of the turn may be outside the record",
            }
        )
    return findings


def check_closure(
    J: dict[str, dict[str, np.ndarray]],
    var: dict[str, dict[str, np.ndarray]],
    duration: dict[str, dict[str, float]],
    static_sems: dict[str, np.ndarray],
    rotations: dict[str, Recording],
) -> None:
    """Refuse an axis whose ccw and cw turns' angles differ from the commanded whole turns by
    more than CLOSURE_SIGMA standard uncertainties of their mean (ValueError naming the
    axis, the mismatch and its uncertainty)."""
    for j, a in enumerate(params.AXES):
        if len(J[a]) != 2:
            continue
        closure = float(J[a]["ccw"][j] + J[a]["cw"][j]) / 2.0
        sem = float(np.asarray(static_sems[f"{a}_up"], dtype=float)[j])
        span = duration[a]["ccw"] + duration[a]["cw"]
        std = math.sqrt(float(var[a]["ccw"][j] + var[a]["cw"][j]) + (span * sem) ** 2) / 2.0
        if abs(closure) > CLOSURE_SIGMA * std:
            files = ", ".join(str(rotations[f"{a}_{k}"].source) for k in ("ccw", "cw"))
            raise ValueError(
                f"rotations {a}_ccw and {a}_cw ({files}): their angles differ from whole turns by "
                f"{math.degrees(closure):+.4g} deg in common ({abs(closure) / std:.1f} of its "
                f"standard uncertainty {math.degrees(std):.3g} deg; at most "
                f"{CLOSURE_SIGMA:g}): a turn is incomplete (a record cut short) or the fixture "
                "did not come back to its start; repeat the rotations"
            )


def _rotation_axes(rotations: dict[str, Recording]) -> np.ndarray | None:
    """(3, 3) true rotation axis per column (unit frame) when a rotation carries its
    ``reference_up`` channel (the face it rests on is not square), else None."""
    if not any(UP_CHANNEL in r.reference for r in rotations.values()):
        return None
    U = np.eye(3)
    for j, a in enumerate(params.AXES):
        recs = [rotations[k] for k in (f"{a}_ccw", f"{a}_cw") if k in rotations]
        U[:, j] = reference_up(f"{a}_ccw", recs[0] if recs else None, 1.0)
    return U


def _signed_sum(per_sense: dict):
    """ccw value minus cw value, whichever of the two is present (the other counts as 0)."""
    return per_sense.get("ccw", 0.0) - per_sense.get("cw", 0.0)


def _check_inputs(
    rotations: dict[str, Recording],
    static_means: dict[str, np.ndarray],
    gyro_range: float,
    turns: int | None,
    directions: str,
    estimator: str,
) -> None:
    """Refuse missing segments, a bad turn count and rotations that reached the range."""
    if estimator not in TURN_ESTIMATORS:
        raise ValueError(
            f"integral method: turn_estimator must be one of {TURN_ESTIMATORS}, got {estimator!r}"
        )
    if directions not in ("both", "any"):
        raise ValueError(f"integral method: directions must be 'both' or 'any', got {directions!r}")
    if directions == "both":
        missing = [label for label in ROTATION_LABELS if label not in rotations]
    else:
        missing = [
            f"{a}_ccw or {a}_cw"
            for a in params.AXES
            if f"{a}_ccw" not in rotations and f"{a}_cw" not in rotations
        ]
    missing += [f"{a}_up" for a in params.AXES if f"{a}_up" not in static_means]
    if missing:
        raise ValueError(f"integral method: missing segments {missing}")
    if turns is not None and (int(turns) != turns or turns < 1):
        raise ValueError(f"integral method: turns must be a positive whole number, got {turns!r}")
    for label in (label for label in ROTATION_LABELS if label in rotations):
        rec = rotations[label]
        if len(rec) < 3:
            raise ValueError(f"rotation {label}: {len(rec)} samples, too short to integrate")
        _check_range(rec, label, gyro_range)


def clean_turn(
    rec: Recording,
    rest: np.ndarray,
    axis: int,
    noise_std: np.ndarray | None = None,
    estimator: str = "regression",
) -> tuple[np.ndarray, np.ndarray, slice, np.ndarray]:
    """One rotation record made ready to integrate: despiked (`despike`), its noise std,
    the span integrated (the whole record, or with `estimator` "regression" the turn's
    motion window, `turn_motion.motion_window`) and the spikes replaced per channel.

    Parameters
    ----------
    rec : the rotation. rest : (3,) static reading of its orientation, rad/s.
    axis : its rotation axis's channel. noise_std : (3,) per-sample noise std from the
        static record of the orientation, rad/s; None: from the record's second
        differences (`noise_from_differences`).
    """
    robust = noise_from_differences(rec.gyr)
    sigma = robust if noise_std is None else np.asarray(noise_std, dtype=float)
    gyr, n_spikes = despike(rec.gyr, robust)
    span = slice(0, len(rec))
    if estimator == "regression":
        # The record's own noise finds the turn; the static's tells its ends at rest.
        rest_std = None if noise_std is None else float(sigma[axis])
        span = motion_window(gyr, rec.t, axis, np.asarray(rest), float(robust[axis]), rest_std)
    return gyr, sigma, span, n_spikes


def turn_rests(
    rotations: dict[str, Recording],
    static_means: dict[str, np.ndarray],
    noise_std: dict[str, np.ndarray] | None = None,
) -> dict[str, list[np.ndarray]]:
    """Static data of each orientation "A_up" from the turns about A (despiked), (N, 3)
    arrays with NaN where a channel has none: the on-axis channel's rests (the samples
    outside the motion window); with both senses turned, each cross-axis channel where the
    regression holds (`turn_motion.cross_axis_ratios`) over the whole records less its
    proportion of the turn, w_c - r_cA (w_A - S_A), which is S_c plus noise at every
    sample. A turn or face with a corrected up direction (``reference_up``) is left out:
    its orientation may not be the face's."""
    rests: dict[str, list[np.ndarray]] = {}
    for a in params.AXES:
        up, j = f"{a}_up", params.AXIS_INDEX[a]
        labels = [f"{a}_{k}" for k in ("ccw", "cw") if f"{a}_{k}" in rotations]
        if up not in static_means or any(UP_CHANNEL in rotations[k].reference for k in labels):
            continue
        noise = None if noise_std is None else noise_std[up]
        cleaned = [clean_turn(rotations[k], static_means[up], j, noise) for k in labels]
        holds, ratio = np.zeros(3, dtype=bool), np.zeros(3)
        if len(cleaned) == 2:
            sigma = np.max([c[1] for c in cleaned], axis=0)
            ratio, _, holds = cross_axis_ratios([c[0] for c in cleaned], j, sigma)
        holds[j] = False
        for gyr, _, span, _ in cleaned:
            part = np.full(gyr.shape, np.nan)
            part[: span.start, j], part[span.stop :, j] = gyr[: span.start, j], gyr[span.stop :, j]
            moving = gyr[:, j] - static_means[up][j]
            part[:, holds] = gyr[:, holds] - np.outer(moving, ratio[holds])
            rests.setdefault(up, []).append(part)
    return rests


def pooled_static_gyro(
    segments: dict[str, Recording], faces: dict[str, ChannelStats]
) -> dict[str, ChannelStats]:
    """Gyro statistics of each face pooled with the rests of the turns made in its
    orientation (`turn_rests`, `turn_motion.face_rest_stats`): the static data of the
    gyro's bias and g-sensitivity fit with turn_estimator "regression".

    Parameters
    ----------
    segments : the run's segments (the faces, and the rotations present).
    faces : label -> ChannelStats of each face's gyro alone.
    """
    rotations = {k: segments[k] for k in ROTATION_LABELS if k in segments}
    tilted = {k for k in faces if UP_CHANNEL in segments[k].reference}
    means = {k: s.mean for k, s in faces.items() if k not in tilted}
    rests = turn_rests(rotations, means, {k: s.std for k, s in faces.items()})
    return face_rest_stats({k: segments[k] for k in faces}, rests)


def _integrals(
    rotations: dict[str, Recording],
    static_means: dict[str, np.ndarray],
    noise_std: dict[str, np.ndarray] | None,
    replaced: dict[str, dict],
    estimator: str = "whole_record",
) -> tuple[dict, dict, dict, dict]:
    """Per axis and sense: the bias-removed integral J (3,) rad, its variance (3,) rad^2,
    the integrated span, s, and (despiked gyro (N, 3), noise std (3,)) of the record
    (each a dict axis -> sense -> value). The span is the whole record, or with
    `estimator` "regression" the turn's motion window (`turn_motion.motion_window`). The
    despiker's counts go into `replaced` (label -> `spike_counts`)."""
    J: dict[str, dict[str, np.ndarray]] = {}
    var: dict[str, dict[str, np.ndarray]] = {}
    duration: dict[str, dict[str, float]] = {}
    cleaned: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    for j, a in enumerate(params.AXES):
        S = np.asarray(static_means[f"{a}_up"], dtype=float)
        J[a], var[a], duration[a], cleaned[a] = {}, {}, {}, {}
        for sense in ("ccw", "cw"):
            if f"{a}_{sense}" not in rotations:
                continue
            rec = rotations[f"{a}_{sense}"]
            noise = None if noise_std is None else noise_std[f"{a}_up"]
            gyr, sigma, span, n_spikes = clean_turn(rec, S, j, noise, estimator)
            replaced[f"{a}_{sense}"] = spike_counts(n_spikes, len(rec))
            t = rec.t[span]
            w = trapezoid_weights(t)
            T = float(t[-1] - t[0])
            J[a][sense] = w @ gyr[span] - S * T
            var[a][sense] = sigma**2 * float(w @ w)
            duration[a][sense] = T
            cleaned[a][sense] = (gyr, sigma)
    return J, var, duration, cleaned


def regression_column(
    axis: str,
    column: np.ndarray,
    std: np.ndarray,
    records: dict[str, tuple[np.ndarray, np.ndarray]],
    used: dict[str, str],
) -> tuple[np.ndarray, np.ndarray]:
    """Column A of I + M with its cross-axis entries as r_cA times the on-axis entry
    (`turn_motion.cross_axis_ratios`) and their standard uncertainties, where the
    regression holds and is the more precise; elsewhere (a wobbling turn, a rate profile
    that favours the integral) the integrals' entry stays. `used` gets
    "gyr.misalign.<c><A>" -> "regression" or "integral" per cross-axis entry."""
    j = params.AXIS_INDEX[axis]
    sigma = np.max([s for _, s in records.values()], axis=0)
    ratio, ratio_std, holds = cross_axis_ratios([g for g, _ in records.values()], j, sigma)
    on = column[j]
    reg_std = np.hypot(ratio_std * on, ratio * std[j])
    holds &= reg_std < std
    holds[j] = True
    out = np.where(holds, ratio * on, column)
    out_std = np.where(holds, reg_std, std)
    out_std[j] = std[j]
    for c, a in enumerate(params.AXES):
        if c != j:
            used[f"gyr.misalign.{a}{axis}"] = "regression" if holds[c] else "integral"
    return out, out_std


def _turn_count(J: dict[str, dict[str, np.ndarray]], turns: int | None) -> int:
    """Whole turns per rotation: the rotation-axis integrals are +-(1 + scale) 2 pi n."""
    n_est = {
        a: _signed_sum(J[a])[i] / (2.0 * math.pi * len(J[a])) for i, a in enumerate(params.AXES)
    }
    if turns is not None:
        n = int(turns)
        off = {a: v for a, v in n_est.items() if abs(v - n) > TURN_TOLERANCE * n}
        if off:
            detail = ", ".join(f"{a}_ccw/{a}_cw: {v:.2f}" for a, v in off.items())
            raise ValueError(f"integral method: settings say {n} turns but the gyro shows {detail}")
        return n
    rounded = {a: round(v) for a, v in n_est.items()}
    bad = {a: v for a, v in n_est.items() if rounded[a] < 1 or abs(v - rounded[a]) > TURN_TOLERANCE}
    if bad:
        detail = ", ".join(
            f"{a} ({'/'.join(f'{a}_{k}' for k in J[a])}): {v:.2f}" for a, v in bad.items()
        )
        raise ValueError(
            f"integral method: the rotations are not whole turns ({detail} turns); "
            "give the number of turns in the settings or repeat the rotations"
        )
    if len(set(rounded.values())) != 1:
        raise ValueError(
            f"integral method: axes turned different whole numbers of turns: {rounded}"
        )
    return rounded["x"]


def rotation_static_means(
    rotations: dict[str, Recording],
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The "A up" static reading S_A of each axis from its ccw and cw rotations alone.

    For stage 2 of the MPU-6000 program (rotations without the six orientations): with
    I+- = +-(1 + M_AA) 2 pi n + S T+- (whole turns, S constant over both records),
    S = (I+ + I-) / (T+ + T-), the bias and g-sensitivity term the rotations carry.

    Returns
    -------
    ({"x_up": (3,) rad/s, ...}, {"x_up": (3,) standard uncertainty, ...}); the
    uncertainty is that of (I+ + I-) / (T+ + T-) from the white noise of both records.
    Using it in `solve_integral` as an independent static mean is exact for equal record
    lengths and approximate (first order in (T+ - T-)/(T+ + T-)) otherwise.
    """
    missing = [label for label in ROTATION_LABELS if label not in rotations]
    if missing:
        raise ValueError(f"integral method (rotations only): missing segments {missing}")
    means, sems = {}, {}
    for a in params.AXES:
        total, var, span = np.zeros(3), np.zeros(3), 0.0
        for sense in ("ccw", "cw"):
            rec = rotations[f"{a}_{sense}"]
            w = trapezoid_weights(rec.t)
            sigma = noise_from_differences(rec.gyr)
            gyr, _ = despike(rec.gyr, sigma)  # counted by solve_integral on the same records
            total += w @ gyr
            var += sigma**2 * float(w @ w)
            span += float(rec.t[-1] - rec.t[0])
        means[f"{a}_up"], sems[f"{a}_up"] = total / span, np.sqrt(var) / span
    return means, sems
