"""Preprocessing chain of one run: sync -> segmentation -> outliers -> low-pass.

The science half of the pipeline's preprocessing, one pure function (`preprocess`)
over the run's segments and its ``run.settings`` tables: each step validates its
table, runs, and returns a StepRecord for the archive. No I/O.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from calib_core.calibration import StepRecord
from calib_core.preprocess.filters import lowpass
from calib_core.preprocess.outliers import METHODS, POLICIES, remove_outliers
from calib_core.preprocess.replaced import replaced_check
from calib_core.preprocess.segments import (
    POSITION_SETTLE_S,
    Interval,
    Segmentation,
    StaticDetector,
    segment,
)
from calib_core.preprocess.sync import synchronise
from calib_core.recording import Recording
from calib_core.settings import Setting, SettingError, Settings

# How segmentation names what it finds: by face and axis, or by sensor and phase.
SEGMENT_LABELLING = ("faces", "array")
_POS = {"low": 0.0, "low_open": True}  # a positive number
_NONNEG = {"low": 0.0}

SYNC = Settings(
    Setting("signal", "text", "", "table_rate", "reference channel of the table's feedback"),
    Setting("signal_kind", "text", "", "rate", "the channel holds a rate (rad/s) or an angle "
            "(rad; differentiated)", choices=("rate", "angle")),
    Setting("imu_axis", "integer", "1", None, "gyro axis along the table axis (0, 1, 2; "
            "absent: the one with the largest variance)", low=0, high=2),
    Setting("max_offset_s", "number", "s", 1.0, "largest clock offset searched", **_POS),
    Setting("max_drift_ppm", "number", "ppm", 200.0, "largest clock drift expected", **_NONNEG),
    Setting("window_s", "number", "s", 30.0, "windows whose local offsets are fitted", **_POS),
    Setting("max_gap_s", "number", "s", None, "a larger spacing in a log is a gap (absent: 5 "
            "sample intervals)", **_POS),
)  # fmt: skip
SEGMENTATION = Settings(
    Setting("window_s", "number", "s", 1.0, "static detector's variance window", **_POS),
    Setting("init_static_s", "number", "s", 10.0, "initial rest the threshold is scaled from",
            **_POS),
    Setting("k", "number", "1", 6.0, "static threshold as a multiple of the initial rest's "
            "variance", **_POS),
    Setting("min_duration_s", "number", "s", 2.0, "shortest rest kept", **_POS),
    Setting("settle_s", "number", "s", POSITION_SETTLE_S, "time dropped at the start of each "
            "rest", **_NONNEG),
    Setting("min_keep_s", "number", "s", 10.0, "shortest part of a rest kept after the settle",
            **_NONNEG),
    Setting("settle_fraction", "number", "1", 0.25, "share of a short rest (under settle_s + "
            "min_keep_s) dropped at each end", low=0.0, high=0.5),
    Setting("min_angle_deg", "number", "deg", 270.0, "smallest turn taken as a rotation", **_POS),
    Setting("labels", "text", "", "faces", "statics by face and axis (x_up, x_ccw) or by sensor "
            "(<sensor>_static, _ccw, _cw)", choices=SEGMENT_LABELLING),
)  # fmt: skip
OUTLIERS = Settings(
    Setting("method", "text", "", "sigma", "detector (none: the step is skipped)",
            choices=(*METHODS, "none")),
    Setting("n_sigma", "number", "1", 3.0, "threshold in standard deviations", **_POS),
    Setting("alpha", "number", "1", 0.05, "significance level (grubbs)", low=0.0, high=1.0,
            low_open=True),
    Setting("window", "integer", "1", None, "samples of the moving window (hampel)", low=1),
    Setting("policy", "text", "", "interpolate", "what happens to a flagged sample",
            choices=POLICIES),
    Setting("channels", "list", "", ["acc", "gyr"], "channels cleaned: acc, gyr"),
)  # fmt: skip
LOWPASS = Settings(
    Setting("cutoff_hz", "number", "Hz", None, "cutoff (or bandwidth_hz with fraction)", **_POS),
    Setting("bandwidth_hz", "number", "Hz", None, "the IMU's bandwidth", **_POS),
    Setting("fraction", "number", "1", 0.25, "cutoff as a share of the bandwidth (the filter "
            "keeps it within 1/5 .. 1/3)", low=0.0, high=1.0, low_open=True),
    Setting("order", "integer", "1", 4, "Butterworth order", low=1),
    Setting("apply_to", "text", "", "static", "the static segments or all",
            choices=("static", "all")),
)  # fmt: skip
# The preprocessing tables of ``[run.settings]`` (docs/manifest.md, "Preprocessing settings").
PREPROCESSING = {
    "sync": SYNC, "segmentation": SEGMENTATION, "outliers": OUTLIERS, "lowpass": LOWPASS
}  # fmt: skip
# The outlier step runs unless turned off (method "none"): these of its settings apply.
DEFAULT_OUTLIERS = {k: OUTLIERS.items[k].default for k in ("method", "n_sigma", "policy")}


def is_static(label: str) -> bool:
    """Static positions: `<axis>_up` / `<axis>_dn`; a sensor array's `<sensor>_static`."""
    return label.endswith(("_up", "_dn", "_static"))


def settings_table(settings: dict[str, Any], name: str, table: Settings) -> dict[str, Any] | None:
    """The ``[run.settings.<name>]`` table as given, checked against its declaration
    (`Settings.validate`: SettingError naming the key); None if absent."""
    given = settings.get(name)
    if given is None:
        return None
    if not isinstance(given, dict):
        raise SettingError(name, f"expected a table of settings, got {given!r}")
    table.validate(given, name)
    return dict(given)


def sync_segments(
    segments: dict[str, Recording], cfg: dict[str, Any]
) -> tuple[dict[str, Recording], StepRecord]:
    """Align the rate-table feedback of every segment that has it with the IMU clock.

    The table channels come from ``[format.reference_columns]``, logged on the
    IMU's rows but on the table's clock (latency, drift); `synchronise`
    estimates offset and drift from the gyro and puts them on the IMU time base.
    """
    signal = cfg.get("signal", "table_rate")
    out: dict[str, Recording] = {}
    per_segment: dict[str, Any] = {}
    used: dict[str, Any] = dict(cfg)
    for label, rec in segments.items():
        if signal not in rec.reference:
            out[label] = rec
            continue
        out[label], record = synchronise(rec, rec.t, dict(rec.reference), **cfg)
        per_segment[label] = record.statistics
        used = record.settings
    if not per_segment:
        raise ValueError(
            f"run.settings.sync: no segment has the reference channel {signal!r} "
            "(name it in [format.reference_columns])"
        )
    return out, StepRecord("synchronise", settings=used, statistics={"segments": per_segment})


def segment_recordings(
    recordings: dict[str, Recording], cfg: dict[str, Any], gravity: float
) -> tuple[dict[str, Recording], StepRecord]:
    """Cut continuous recordings into labelled statics and rotations (automatic segmentation).

    Statics are labelled by the direction of gravity (x_up .. z_dn), rotations
    by axis and sense (x_ccw, z_cw, ...): `calib_core.preprocess.segments.segment`.
    With ``labels = "array"`` (a sensor array, docs/methods.md 2.7) each recording is
    one sensor's session (static, cw, static, ccw, static about the vertical),
    named by its segment label: statics become ``<sensor>_static`` whatever
    their face, turns ``<sensor>_ccw`` / ``<sensor>_cw`` by their sense about
    the vertical (`array_labels`).

    Where a label is found more than once (a face held again, the rest around a
    turn), the longest interval is kept; the others, and tilted statics, are
    listed as unused in the step record.
    """
    cfg = dict(cfg)
    labelling = cfg.pop("labels", "faces")  # checked with the table (SEGMENTATION)
    rotations = {"min_angle_deg": cfg.pop("min_angle_deg")} if "min_angle_deg" in cfg else {}
    detector = StaticDetector(**cfg)
    candidates: dict[str, list[tuple[Recording, dict[str, Any]]]] = {}
    unused: list[dict[str, Any]] = []
    per_recording: dict[str, Any] = {}
    for name, rec in recordings.items():
        seg, record = segment(rec, gravity=gravity, detector=detector, **rotations)
        per_recording[name] = record.statistics
        if labelling == "array":
            intervals = array_labels(name, rec, seg)
        else:
            intervals = list(zip(seg.statics, seg.static_labels, strict=True))
            intervals += list(zip(seg.rotations, seg.rotation_labels, strict=True))
        for iv, label in intervals:
            where = {"recording": name, "start_s": iv.start_s, "end_s": iv.end_s}
            if label is None:
                unused.append({**where, "label": None, "reason": "tilted"})
                continue
            part = dataclasses.replace(
                rec.select(iv.slice, label=label),
                source=f"{rec.source or name} t in [{iv.start_s:.3f}, {iv.end_s:.3f}) s",
            )
            candidates.setdefault(label, []).append((part, {**where, "n_samples": len(part)}))
    chosen: dict[str, Recording] = {}
    used: dict[str, Any] = {}
    for label, hits in candidates.items():
        hits.sort(key=lambda hit: -len(hit[0]))  # longest first; stable: earliest of equals
        (chosen[label], used[label]), rest = hits[0], hits[1:]
        unused += [{**where, "label": label, "reason": "shorter repeat"} for _, where in rest]
    if not chosen:
        raise ValueError(
            "automatic segmentation found no labelled static face or rotation in "
            f"{', '.join(recordings)}; check run.settings.segmentation (init_static_s, k)"
        )
    ordered = dict(sorted(chosen.items(), key=lambda kv: used[kv[0]]["start_s"]))
    return ordered, StepRecord(
        "segment",
        settings={**cfg, "labels": labelling, "gravity": gravity},
        statistics={
            "segments": {k: used[k] for k in ordered},
            "unused": unused,
            "recordings": per_recording,
        },
    )


def array_labels(name: str, rec: Recording, seg: Segmentation) -> list[tuple[Interval, str | None]]:
    """Labels of one sensor's session of a sensor array: ``<name>_static|_ccw|_cw``.

    The sense of a turn is that of its angle about the vertical, which the
    sensor sees as the direction of the specific force in the static before the
    turn (ccw seen from above = positive about up), so any mounting gives the
    right sense; the face of a static does not matter.
    """
    out: list[tuple[Interval, str | None]] = [(iv, f"{name}_static") for iv in seg.statics]
    for rot in seg.rotations:
        before = [iv for iv in seg.statics if iv.start_index < rot.start_index]
        up = rec.acc[before[-1].slice].mean(axis=0)
        about_up = float(np.dot(rot.angle, up) / np.linalg.norm(up))
        out.append((rot, f"{name}_{'ccw' if about_up > 0 else 'cw'}"))
    return out


def lowpass_segments(
    segments: dict[str, Recording], cfg: dict[str, Any]
) -> tuple[dict[str, Recording], StepRecord]:
    """Zero-phase low-pass of the static segments (``apply_to = "static"``) or of all.

    Averages are unchanged (DC gain exactly 1), but filtered samples are
    correlated: the uncertainty of a mean then comes from the effective sample
    count (calib_core.stats), not from N.
    """
    kwargs = dict(cfg)
    apply_to = kwargs.pop("apply_to", "static")  # checked with the table (LOWPASS)
    out: dict[str, Recording] = {}
    per_segment: dict[str, Any] = {}
    used: dict[str, Any] = {}
    for label, rec in segments.items():
        if apply_to == "static" and not is_static(label):
            out[label] = rec
            continue
        out[label], record = lowpass(rec, **kwargs)
        per_segment[label] = record.statistics
        used = record.settings
    return out, StepRecord(
        "lowpass", settings={**used, "apply_to": apply_to}, statistics={"segments": per_segment}
    )


def preprocess(
    segments: dict[str, Recording], settings: dict[str, Any], gravity: float | None = None
) -> tuple[dict[str, Recording], list[StepRecord]]:
    """Preprocessing chain of one run, each step from its ``run.settings`` table.

    In order: ``sync`` (table feedback onto the IMU clock; only if given),
    ``segmentation`` (continuous recordings cut into labelled segments; only if
    given, needs `gravity`, m/s^2), ``outliers`` (static segments only, never
    across a rotation where the signal moves; DEFAULT_OUTLIERS, ``{"method":
    "none"}`` turns it off), ``lowpass`` (only if given). Outliers go before
    the low-pass, which would smear a spike over its neighbours.

    Returns the segments and one StepRecord per step that ran (settings used,
    what was found, removed or changed).
    """
    steps: list[StepRecord] = []
    sync_cfg = settings_table(settings, "sync", SYNC)
    if sync_cfg is not None:
        segments, record = sync_segments(segments, sync_cfg)
        steps.append(record)
    seg_cfg = settings_table(settings, "segmentation", SEGMENTATION)
    if seg_cfg is not None:
        if gravity is None:
            raise ValueError(
                "run.settings.segmentation: automatic segmentation needs the local gravity"
            )
        segments, record = segment_recordings(segments, seg_cfg, gravity)
        steps.append(record)

    cfg = {**DEFAULT_OUTLIERS, **(settings_table(settings, "outliers", OUTLIERS) or {})}
    segments, record = outliers_segments(segments, cfg)
    steps.append(record)

    lp_cfg = settings_table(settings, "lowpass", LOWPASS)
    if lp_cfg is not None:
        segments, record = lowpass_segments(segments, lp_cfg)
        steps.append(record)
    return segments, steps


def outliers_segments(
    segments: dict[str, Recording], cfg: dict[str, Any]
) -> tuple[dict[str, Recording], StepRecord]:
    """Outlier removal on the static segments only (never across a rotation, where the
    signal moves); ``{"method": "none"}`` records the step as skipped."""
    if cfg["method"] == "none":
        return segments, StepRecord("outliers", settings=cfg, statistics={"skipped": True})
    kwargs = {k: v for k, v in cfg.items() if k != "method"}
    if "channels" in kwargs:
        kwargs["channels"] = tuple(kwargs["channels"])
    cleaned: dict[str, Recording] = {}
    per_segment: dict[str, Any] = {}
    for label, rec in segments.items():
        if not is_static(label):
            cleaned[label] = rec
            continue
        cleaned[label], record = remove_outliers(rec, method=cfg["method"], **kwargs)
        st = record.statistics
        verb = "deleted" if record.settings["policy"] == "delete" else "interpolated"
        st["check"] = replaced_check(
            "outliers",
            label,
            st["n_flagged"],
            st["n_samples"] * len(st["n_flagged"]),
            st["p_false_alarm"],
            verb,
        )
        per_segment[label] = st
    return cleaned, StepRecord("outliers", settings=cfg, statistics={"segments": per_segment})


def replaced_checks(steps: list[StepRecord]) -> list[dict]:
    """The ``model:replaced:<step>:<segment>`` checks the preprocessing steps made (one
    per segment of the outlier step), for the run's checks: a segment with more samples
    flagged than the detector's false alarms explain is sent for review."""
    return [
        seg["check"]
        for step in steps
        for seg in step.statistics.get("segments", {}).values()
        if isinstance(seg, dict) and "check" in seg
    ]
