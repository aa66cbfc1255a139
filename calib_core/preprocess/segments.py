"""Segmentation: static intervals, rotations, rate plateaus, and their labels.

Static detection follows equipment-free calibration (Tedaldi et al. 2014): the
local variance of the signals over a short window is compared with a threshold
k times the variance of an initial static period, so the threshold adapts to
the sensor's own noise. A gyro-mean test is added so a slow steady rotation
(small variance, non-zero rate) is not taken for rest.

Labels come from the data, not from the order of the segments: a static face is
named by the direction of gravity in the sensor frame (x_up .. z_dn), a rotation
by the axis and sign of its integrated rate (ccw = positive), a rate plateau by
its level.

Settle time: the first `settle_s` of each static interval (rate plateau) is
discarded, but at least `min_keep_s` is kept. An interval shorter than
settle_s + min_keep_s is flagged `short` and keeps its middle instead: it loses
settle_fraction of its duration d at the end, and max(settle_fraction * d,
d - settle_fraction * d - min_keep_s) at the start, so it keeps
min((1 - 2 settle_fraction) d, min_keep_s) (continuous with the long rule at
d = settle_s + min_keep_s). Hand-held procedures (seconds per face) thus keep
the middle half of each face; lab procedures get the full settle.

Why the end cut for short intervals: by hand, the operator's grip reaches the
unit before it visibly moves, and the detector's centred window still calls
rest up to half a window into the pick-up. On imucal's real Ferraris session
the detected rest runs 0.7 .. 1.5 s past the annotated face ends (the sensor
is still, the annotation is conservative); a quarter of each face (1.4 .. 2.2
s there) keeps the kept samples inside the annotated faces at both ends.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from calib_core.calibration import StepRecord
from calib_core.params import AXES
from calib_core.recording import Recording

POSITION_SETTLE_S = 30.0
RATE_SETTLE_S = 20.0


@dataclass(frozen=True)
class Interval:
    """A stretch of samples [start_index, end_index) of a recording.

    start_s, end_s : times of the first sample and of the last sample + one
        interval, s. For static intervals and plateaus the settle time is
        already cut off; `detected_start_*` is where the detector saw rest begin.
    kind : "static", "rotation" or "plateau".
    settle_s : time discarded at the start, s.
    end_cut_s : time discarded at the end (short intervals), s.
    detected_end_index, detected_end_s : where the detector saw rest end (the
        index after the last rest sample; its time + one interval).
    short : True if the interval was too short for the full settle time.
    level : plateau rate, rad/s (plateaus only).
    angle : (3,) integrated, bias-corrected gyro over a rotation, rad.
    """

    start_index: int
    end_index: int
    start_s: float
    end_s: float
    kind: str
    detected_start_index: int
    detected_start_s: float
    settle_s: float = 0.0
    short: bool = False
    level: float | None = None
    angle: tuple[float, float, float] | None = None
    end_cut_s: float = 0.0
    detected_end_index: int | None = None
    detected_end_s: float | None = None

    @property
    def duration(self) -> float:
        return self.end_s - self.start_s

    @property
    def slice(self) -> slice:
        return slice(self.start_index, self.end_index)


def _local_variance(x: np.ndarray, w: int) -> np.ndarray:
    """Centred moving variance of each column of x (N, C) over w samples, summed over columns."""
    from scipy.ndimage import uniform_filter1d  # slow to import: only where segments are found

    x = x - np.median(x, axis=0)  # centring keeps E[x^2] - E[x]^2 from cancelling badly
    m1 = uniform_filter1d(x, w, axis=0, mode="nearest")
    m2 = uniform_filter1d(x * x, w, axis=0, mode="nearest")
    return np.maximum(m2 - m1 * m1, 0.0).sum(axis=1)


def _runs(mask: np.ndarray) -> np.ndarray:
    """(K, 2) [start, end) index pairs of the True runs of a boolean array."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return np.column_stack([np.flatnonzero(d == 1), np.flatnonzero(d == -1)])


def _settle(
    t: np.ndarray,
    start: int,
    end: int,
    dt: float,
    settle_s: float,
    min_keep_s: float,
    settle_fraction: float,
) -> tuple[int, int, float, float, bool]:
    """Kept [start, end) of run [start, end) by the settle rule (module docstring).

    dt is the sample interval, s (the last sample covers one interval).
    Returns (new start, new end, start cut s, end cut s, short flag)."""
    duration = t[end - 1] - t[start] + dt
    short = duration < settle_s + min_keep_s
    if short:
        end_cut = settle_fraction * duration
        cut = max(settle_fraction * duration, duration - end_cut - min_keep_s)
    else:
        end_cut, cut = 0.0, settle_s
    new_start = min(int(np.searchsorted(t, t[start] + cut, side="left")), end - 1)
    new_end = min(int(np.searchsorted(t, t[end - 1] - end_cut, side="right")), end)
    return new_start, max(new_end, new_start + 1), cut, end_cut, short


def _intervals(
    t: np.ndarray,
    runs: np.ndarray,
    kind: str,
    min_duration_s: float,
    settle_s: float,
    min_keep_s: float,
    settle_fraction: float,
) -> list[Interval]:
    dt = float(np.median(np.diff(t)))
    out = []
    for start, end in runs:
        if t[end - 1] - t[start] + dt < min_duration_s:
            continue
        s, e, cut, end_cut, short = _settle(
            t, start, end, dt, settle_s, min_keep_s, settle_fraction
        )
        out.append(
            Interval(
                int(s),
                int(e),
                float(t[s]),
                float(t[e - 1] + dt),
                kind,
                int(start),
                float(t[start]),
                float(cut),
                bool(short),
                end_cut_s=float(end_cut),
                detected_end_index=int(end),
                detected_end_s=float(t[end - 1] + dt),
            )
        )
    return out


@dataclass(frozen=True)
class StaticDetector:
    """Settings of the static detector (`detect_static`; the run's ``[segmentation]`` table).

    window_s : local-variance window, s.
    init_static_s : initial rest period for the automatic threshold, s.
    k : threshold factor (Tedaldi et al.'s multiple of the initial variance).
        Windows of w samples estimate a variance to a relative std of
        sqrt(2/(3w)) (three axes), so k = 6 leaves noise far below the line.
    threshold : explicit (acc (m/s^2)^2, gyro (rad/s)^2) thresholds instead.
    min_duration_s : rest runs shorter than this are ignored, s.
    settle_s, min_keep_s, settle_fraction : settle-time rule (module docstring).
    """

    window_s: float = 1.0
    init_static_s: float = 10.0
    k: float = 6.0
    threshold: tuple[float, float] | None = None
    min_duration_s: float = 2.0
    settle_s: float = POSITION_SETTLE_S
    min_keep_s: float = 10.0
    settle_fraction: float = 0.25

    def settings(self) -> dict[str, Any]:
        """The settings for a step record (``threshold`` only when given)."""
        return {k: v for k, v in asdict(self).items() if k != "threshold" or v is not None}

    def mask(self, rec: Recording) -> tuple[np.ndarray, dict]:
        """Per-sample rest flag from local variances (see `detect_static`) and the thresholds."""
        from scipy.ndimage import uniform_filter1d

        where = rec.source or "recording"
        fs = rec.sample_rate
        w = max(3, int(round(self.window_s * fs)))
        if len(rec) < 2 * w:
            raise ValueError(
                f"detect_static ({where}): {len(rec)} samples, need >= 2 windows ({2 * w})"
            )
        var_acc = _local_variance(rec.acc, w)
        var_gyr = _local_variance(rec.gyr, w)
        n0 = int(round(self.init_static_s * fs))
        init = rec.gyr[:n0]
        if self.threshold is None:
            if len(rec) < n0 or n0 < w:
                raise ValueError(
                    f"detect_static ({where}): init_static_s = {self.init_static_s} s needs "
                    f"{n0} samples (>= one window of {w}); the record has {len(rec)}. Give a "
                    "shorter initial static period or explicit thresholds"
                )
            thr_acc = self.k * float(rec.acc[:n0].var(axis=0).sum())
            thr_gyr = self.k * float(init.var(axis=0).sum())
        else:
            thr_acc, thr_gyr = self.threshold
        # The window-mean gyro must stay near its value at rest: its squared distance
        # from the initial mean is held to the same threshold as the variance.
        bias = init.mean(axis=0) if n0 >= w else np.median(rec.gyr, axis=0)
        mean_gyr = uniform_filter1d(rec.gyr, w, axis=0, mode="nearest")
        rate_sq = ((mean_gyr - bias) ** 2).sum(axis=1)
        rest = (var_acc < thr_acc) & (var_gyr < thr_gyr) & (rate_sq < thr_gyr)
        info = {
            "window_samples": w,
            "threshold_acc": thr_acc,
            "threshold_gyr": thr_gyr,
            "k": self.k,
            "init_static_s": self.init_static_s,
        }
        return rest, info

    def intervals(self, rec: Recording, rest: np.ndarray) -> list[Interval]:
        """The static Intervals of the rest flag `rest` (N,), settled (module docstring)."""
        return _intervals(
            rec.t,
            _runs(rest),
            "static",
            self.min_duration_s,
            self.settle_s,
            self.min_keep_s,
            self.settle_fraction,
        )


DEFAULT_STATICS = StaticDetector()


def detect_static(rec: Recording, detector: StaticDetector = DEFAULT_STATICS) -> list[Interval]:
    """Static intervals of a recording.

    A sample is at rest when, over a centred window of `window_s`, the summed
    per-axis variance of the accelerometer and of the gyro are both below
    k times their variance over the first `init_static_s` of the record (which
    must be at rest), and the window-mean gyro is within the same gyro threshold
    (squared distance) of the initial mean.

    Parameters
    ----------
    rec : the whole run, SI units.
    detector : the settings (window, initial rest, k or explicit thresholds, settle rule).

    Returns
    -------
    list of Interval(kind="static"), in time order.
    """
    rest, _ = detector.mask(rec)
    return detector.intervals(rec, rest)


def detect_rotations(
    rec: Recording,
    statics: list[Interval],
    *,
    min_angle_deg: float = 270.0,
    min_dominance: float = 0.9,
) -> list[Interval]:
    """Turns about one axis between consecutive static intervals.

    The gyro is integrated (trapezoid rule) from the end of one static interval
    to the detected start of the next, after removing the gyro bias (mean of the
    two neighbouring statics). A motion counts as a rotation if the angle about
    its dominant axis is at least `min_angle_deg` (whole turns of the integral
    method, not the 90/180 deg flips between faces) and that axis carries at
    least `min_dominance` of the angle vector's norm.

    Parameters
    ----------
    rec : the whole run.
    statics : its static intervals (from `detect_static`).

    Returns
    -------
    list of Interval(kind="rotation") with `angle` (3,) rad.
    """
    out = []
    for before, after in zip(statics[:-1], statics[1:], strict=True):
        # From the last rest sample the detector saw (not the end of the kept part).
        last_rest = (
            before.end_index if before.detected_end_index is None else before.detected_end_index
        )
        i0, i1 = last_rest - 1, after.detected_start_index + 1
        bias = 0.5 * (rec.gyr[before.slice].mean(axis=0) + rec.gyr[after.slice].mean(axis=0))
        angle = np.trapezoid(rec.gyr[i0:i1] - bias, rec.t[i0:i1], axis=0)
        dom = int(np.argmax(np.abs(angle)))
        big = np.degrees(abs(angle[dom])) >= min_angle_deg
        if big and abs(angle[dom]) >= min_dominance * np.linalg.norm(angle):
            out.append(
                Interval(
                    i0,
                    i1,
                    float(rec.t[i0]),
                    float(rec.t[i1 - 1]),
                    "rotation",
                    i0,
                    float(rec.t[i0]),
                    angle=tuple(float(a) for a in angle),
                )
            )
    return out


def detect_rate_plateaus(
    t: np.ndarray,
    rate: np.ndarray,
    *,
    window_s: float = 1.0,
    k: float = 5.0,
    tolerance: float = 1e-4,
    min_duration_s: float = 5.0,
    settle_s: float = RATE_SETTLE_S,
    min_keep_s: float = 10.0,
    settle_fraction: float = 0.25,
) -> list[Interval]:
    """Intervals of constant rate (rate-table plateaus, including rest).

    The local slope is the difference between the means of the window after and
    the window before each sample. On a plateau it is noise only, with std
    sigma * sqrt(2 / w) for white noise of std sigma (estimated robustly from
    the first differences); a sample is on a plateau if the difference is
    within k times that, or `tolerance` (rad/s) for noise-free feedback.

    Parameters
    ----------
    t : (N,) s. rate : (N,) rad/s (table feedback or the gyro along the axis).
    Other parameters as in `detect_static`; settle_s defaults to 20 s (rate points).

    Returns
    -------
    list of Interval(kind="plateau") with `level` = mean rate after settling, rad/s.
    """
    from scipy.ndimage import uniform_filter1d

    t, rate = np.asarray(t, float), np.asarray(rate, float)
    if t.shape != rate.shape or t.ndim != 1:
        raise ValueError(f"detect_rate_plateaus: t {t.shape} and rate {rate.shape} must be (N,)")
    dt = float(np.median(np.diff(t)))
    w = max(2, int(round(window_s / dt)))
    # NaN (reference samples lost in a gap) never belongs to a plateau; fill it
    # for the moving means so it does not spread.
    missing = np.isnan(rate)
    if missing.all():
        raise ValueError("detect_rate_plateaus: every rate sample is NaN")
    if missing.any():
        rate = rate.copy()
        rate[missing] = np.interp(t[missing], t[~missing], rate[~missing])
    d = np.diff(rate)
    sigma = 1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0)
    mean = uniform_filter1d(rate, w, mode="nearest", origin=0)
    # mean of [i, i+w) minus mean of [i-w, i): the centred mean shifted by w/2 each way.
    ahead = np.roll(mean, -(w // 2))
    behind = np.roll(mean, w - w // 2)
    step = np.abs(ahead - behind)
    flat = step <= max(k * sigma * np.sqrt(2.0 / w), tolerance)
    flat[:w] = flat[-w:] = False  # rolled ends are not real neighbours
    # Also off a plateau: anything within a window of a missing sample (the
    # threshold 0.5 / (2w) is half of one missing sample's share of the mean).
    flat &= uniform_filter1d(missing.astype(float), 2 * w, mode="nearest") < 0.25 / w
    out = []
    for iv in _intervals(
        t, _runs(flat), "plateau", min_duration_s, settle_s, min_keep_s, settle_fraction
    ):
        level = float(rate[iv.slice].mean())
        out.append(Interval(**{**iv.__dict__, "level": level}))
    return out


def label_position(
    acc_mean: np.ndarray, gravity: float, *, tilt_tol_deg: float = 20.0, norm_tol: float = 0.15
) -> str:
    """Face label ("x_up" .. "z_dn") of a mean specific force (3,), m/s^2.

    "up" means that axis reads +g. Raises ValueError if the vector's norm is not
    within norm_tol (relative) of gravity or it is tilted more than tilt_tol_deg
    from the nearest axis.
    """
    f = np.asarray(acc_mean, float)
    norm = float(np.linalg.norm(f))
    if abs(norm / gravity - 1.0) > norm_tol:
        raise ValueError(
            f"mean specific force {norm:.4f} m/s^2 differs from gravity {gravity:.4f} by more "
            f"than {norm_tol:.0%}; not a static face"
        )
    i = int(np.argmax(np.abs(f)))
    tilt = float(np.degrees(np.arccos(min(1.0, abs(f[i]) / norm))))
    if tilt > tilt_tol_deg:
        raise ValueError(
            f"gravity is {tilt:.1f} deg from the nearest axis ({AXES[i]}); "
            f"more than {tilt_tol_deg} deg: a tilted position, not a face"
        )
    return f"{AXES[i]}_{'up' if f[i] > 0 else 'dn'}"


def label_positions(statics: list[Recording], gravity: float, **tolerances) -> list[str]:
    """Face label of each static segment from its gravity direction (not its order).

    Errors name the segment (its `source` or index).
    """
    labels = []
    for n, seg in enumerate(statics):
        try:
            labels.append(label_position(seg.acc.mean(axis=0), gravity, **tolerances))
        except ValueError as err:
            raise ValueError(f"static segment {seg.source or n}: {err}") from None
    return labels


def label_rotations(rotations: list[Interval]) -> list[str]:
    """Rotation labels "x_ccw", "z_cw", ... by dominant axis and sign (ccw = positive)."""
    labels = []
    for r in rotations:
        if r.angle is None:
            raise ValueError(f"interval at {r.start_s:.3f} s has no integrated angle")
        i = int(np.argmax(np.abs(r.angle)))
        labels.append(f"{AXES[i]}_{'ccw' if r.angle[i] > 0 else 'cw'}")
    return labels


@dataclass(frozen=True)
class Segmentation:
    """Result of `segment`: statics with their face labels, rotations with theirs."""

    statics: list[Interval]
    static_labels: list[str | None]
    rotations: list[Interval]
    rotation_labels: list[str]


def segment(
    rec: Recording,
    *,
    gravity: float,
    detector: StaticDetector = DEFAULT_STATICS,
    min_angle_deg: float = 270.0,
) -> tuple[Segmentation, StepRecord]:
    """Find and label static faces and rotations of a multi-position / integral run.

    Statics whose gravity direction is not near an axis (tilted positions) get
    the label None. `detector` as in `detect_static`, min_angle_deg as in
    `detect_rotations`.

    Returns
    -------
    (Segmentation, StepRecord listing every interval with its label).
    """
    rest, info = detector.mask(rec)
    statics = detector.intervals(rec, rest)
    labels: list[str | None] = []
    for iv in statics:
        try:
            labels.append(label_position(rec.acc[iv.slice].mean(axis=0), gravity))
        except ValueError:
            labels.append(None)
    rotations = detect_rotations(rec, statics, min_angle_deg=min_angle_deg)
    rot_labels = label_rotations(rotations)
    record = StepRecord(
        name="segment",
        settings={**detector.settings(), "min_angle_deg": min_angle_deg, "gravity": gravity},
        statistics={
            "source": rec.source,
            "threshold_acc": info["threshold_acc"],
            "threshold_gyr": info["threshold_gyr"],
            "fraction_at_rest": float(rest.mean()),
            "statics": [
                {
                    "label": lab,
                    "start_s": iv.start_s,
                    "end_s": iv.end_s,
                    "settle_s": iv.settle_s,
                    "end_cut_s": iv.end_cut_s,
                    "detected_start_s": iv.detected_start_s,
                    "detected_end_s": iv.detected_end_s,
                    "n_samples": iv.end_index - iv.start_index,
                    "short": iv.short,
                }
                for iv, lab in zip(statics, labels, strict=True)
            ],
            "rotations": [
                {
                    "label": lab,
                    "start_s": iv.start_s,
                    "end_s": iv.end_s,
                    "angle_deg": np.degrees(iv.angle).tolist(),
                }
                for iv, lab in zip(rotations, rot_labels, strict=True)
            ],
        },
    )
    return Segmentation(statics, labels, rotations, rot_labels), record
