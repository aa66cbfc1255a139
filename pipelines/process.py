"""One lab run from its files to the archive: ingest, preprocess, solve, check, archive.

Each stage is a plain function; `process_run` strings them together and turns
any error into a failed outcome (nothing archived) so a batch goes on. The
Prefect flows in `pipelines.flows` wrap `process_run` and nothing else.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
import pyarrow as pa

from calib_core import procedures
from calib_core.calibration import Calibration, CheckResult, StepRecord
from calib_core.checks import ToleranceProfile, check_parameters, check_residuals
from calib_core.preprocess.filters import lowpass
from calib_core.preprocess.outliers import remove_outliers
from calib_core.preprocess.segments import segment
from calib_core.preprocess.sync import synchronise
from calib_core.recording import Recording
from calib_core.verification import (
    RunValues,
    comparable_runs,
    diagnose_residuals,
    overall_verdict,
    repeatability,
    static_reference,
    verify_points,
)
from pipelines.ingest import LoadedRun, RunSource, load_run
from pipelines.ingest.errors import IngestError
from pipelines.provenance import SOFTWARE_VERSION, source_revision
from pipelines.reports.protocol import render_protocol
from pipelines.tolerances import load_profile
from storage import queries, rawstore
from storage.archive import ArchiveResult, RawFileIn, RunIn, archive_run, raw_hash_of, run_id_of
from storage.db import Archive

log = logging.getLogger("calib.process")

DEFAULT_OUTLIERS = {"method": "sigma", "n_sigma": 3.0, "policy": "interpolate"}
# Keys each [run.settings.<step>] table may hold (docs/manifest.md, "Preprocessing settings").
OUTLIER_KEYS = {"method", "n_sigma", "alpha", "window", "policy", "channels"}
LOWPASS_KEYS = {"cutoff_hz", "bandwidth_hz", "fraction", "order", "apply_to"}
SEGMENTATION_KEYS = {
    "window_s",
    "init_static_s",
    "k",
    "min_duration_s",
    "settle_s",
    "min_keep_s",
    "settle_fraction",
    "min_angle_deg",
}
SYNC_KEYS = {
    "signal",
    "signal_kind",
    "imu_axis",
    "max_offset_s",
    "max_drift_ppm",
    "window_s",
    "max_gap_s",
}


def is_static(label: str) -> bool:
    """Static positions are labelled `<axis>_up` / `<axis>_dn`."""
    return label.endswith(("_up", "_dn"))


def settings_table(settings: dict[str, Any], name: str, allowed: set[str]) -> dict[str, Any] | None:
    """The ``[run.settings.<name>]`` table, checked against its known keys; None if absent."""
    given = settings.get(name)
    if given is None:
        return None
    if not isinstance(given, dict):
        raise ValueError(f"run.settings.{name}: expected a table of settings, got {given!r}")
    unknown = sorted(set(given) - allowed)
    if unknown:
        raise ValueError(
            f"run.settings.{name}: unknown setting(s) {', '.join(unknown)}; "
            f"expected some of: {', '.join(sorted(allowed))}"
        )
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
    Where a label is found more than once (a face held again, the rest around a
    turn), the longest interval is kept; the others, and tilted statics, are
    listed as unused in the step record.
    """
    candidates: dict[str, list[tuple[Recording, dict[str, Any]]]] = {}
    unused: list[dict[str, Any]] = []
    per_recording: dict[str, Any] = {}
    for name, rec in recordings.items():
        seg, record = segment(rec, gravity=gravity, **cfg)
        per_recording[name] = record.statistics
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
        settings={**cfg, "gravity": gravity},
        statistics={
            "segments": {k: used[k] for k in ordered},
            "unused": unused,
            "recordings": per_recording,
        },
    )


def lowpass_segments(
    segments: dict[str, Recording], cfg: dict[str, Any]
) -> tuple[dict[str, Recording], StepRecord]:
    """Zero-phase low-pass of the static segments (``apply_to = "static"``) or of all.

    Averages are unchanged (DC gain exactly 1), but filtered samples are
    correlated: the uncertainty of a mean then comes from the effective sample
    count (calib_core.stats), not from N.
    """
    kwargs = dict(cfg)
    apply_to = kwargs.pop("apply_to", "static")
    if apply_to not in ("static", "all"):
        raise ValueError(
            f"run.settings.lowpass.apply_to: expected 'static' or 'all', got {apply_to!r}"
        )
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
    sync_cfg = settings_table(settings, "sync", SYNC_KEYS)
    if sync_cfg is not None:
        segments, record = sync_segments(segments, sync_cfg)
        steps.append(record)
    seg_cfg = settings_table(settings, "segmentation", SEGMENTATION_KEYS)
    if seg_cfg is not None:
        if gravity is None:
            raise ValueError(
                "run.settings.segmentation: automatic segmentation needs the local gravity"
            )
        segments, record = segment_recordings(segments, seg_cfg, gravity)
        steps.append(record)

    cfg = {**DEFAULT_OUTLIERS, **(settings_table(settings, "outliers", OUTLIER_KEYS) or {})}
    if cfg["method"] == "none":
        steps.append(StepRecord("outliers", settings=cfg, statistics={"skipped": True}))
    else:
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
            per_segment[label] = record.statistics
        segments = cleaned
        steps.append(StepRecord("outliers", settings=cfg, statistics={"segments": per_segment}))

    lp_cfg = settings_table(settings, "lowpass", LOWPASS_KEYS)
    if lp_cfg is not None:
        segments, record = lowpass_segments(segments, lp_cfg)
        steps.append(record)
    return segments, steps


def samples_table(segments: dict[str, Recording]) -> pa.Table:
    """All segments' samples as one Arrow table (segment, t, acc_*, gyr_*, temp), SI units."""
    names = ("t", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z", "temp")
    if not segments:
        return pa.table({k: np.array([]) for k in ("segment", *names)})
    cols: dict[str, list[np.ndarray]] = {k: [] for k in names}
    for rec in segments.values():
        cols["t"].append(rec.t)
        for i, a in enumerate("xyz"):
            cols[f"acc_{a}"].append(rec.acc[:, i])
            cols[f"gyr_{a}"].append(rec.gyr[:, i])
        cols["temp"].append(np.full(len(rec), np.nan) if rec.temp is None else rec.temp)
    # The label column from one code per sample and the labels once (a string per
    # sample built in Python costs more than all the numeric columns together);
    # decoded to plain strings, so the table and its Parquet file are as before.
    codes = np.repeat(
        np.arange(len(segments), dtype=np.int32), [len(rec) for rec in segments.values()]
    )
    label = pa.DictionaryArray.from_arrays(codes, pa.array(list(segments), pa.string()))
    return pa.table(
        {"segment": label.cast(pa.string()), **{k: np.concatenate(v) for k, v in cols.items()}}
    )


def _check_dicts(checks: list[CheckResult]) -> list[dict[str, Any]]:
    return [c.to_dict() for c in checks]


def run_outcome(
    *,
    source: str,
    serial: str,
    status: str,
    run_id: str = "",
    error: str | None = None,
    cal: Calibration | None = None,
    checks: list[CheckResult] | None = None,
    protocol: str | None = None,
    verdict_: str | None = None,
    message: str | None = None,
) -> dict[str, Any]:
    """One entry of the `calib process --json` document (docs/cli.md)."""
    return {
        "run_id": run_id,
        "serial": serial,
        "status": status,
        "error": error,
        "parameters": {}
        if cal is None
        else {
            n: {"value": p.value, "std": p.std, "unit": p.unit}
            for n, p in sorted(cal.parameters.items())
        },
        "checks": [
            {"name": c.name, "value": c.value, "limit": c.limit, "passed": c.passed}
            for c in (checks or [])
        ],
        "protocol": protocol,
        "verdict": verdict_,
        "source": source,
        "message": message,
    }


def solve_loaded(loaded: LoadedRun) -> tuple[Calibration, list[StepRecord], dict[str, Any]]:
    """Preprocess and solve a loaded run; returns the calibration, step records and settings."""
    m = loaded.manifest
    settings = dict(m.run.settings)
    started = time.perf_counter()
    segments, steps = preprocess(loaded.segments, settings, gravity=m.gravity())
    # Wall time per stage ("seconds" of ingest, solve, check; here the whole preprocessing
    # chain, on its last step), for the batch benchmark and for spotting slow runs.
    steps[-1].statistics["preprocess_seconds"] = round(time.perf_counter() - started, 4)
    started = time.perf_counter()
    # Verification segments stay out of the fit (docs/reports.md); they are checked after.
    fit = {k: v for k, v in segments.items() if k not in loaded.verification_labels}
    cal = procedures.solve(m.run.procedure, fit, m.gravity(), settings)
    steps.append(
        StepRecord(
            "solve",
            settings={"procedure": m.run.procedure, **settings},
            statistics={
                "seconds": round(time.perf_counter() - started, 4),
                "parameters": len(cal.parameters),
                "held_out": sorted(loaded.verification_labels),
                "warnings": list(cal.warnings),
                **{k: v for k, v in cal.info.items() if isinstance(v, int | float | str)},
            },
        )
    )
    return cal, steps, settings


def verify_run(
    loaded: LoadedRun, cal: Calibration, profile: ToleranceProfile, archive: Archive
) -> tuple[list[CheckResult], dict[str, Any]]:
    """Held-out verification points, repeatability against the archive, residual diagnosis.

    Repeatability is judged when a run is archived, against the current
    calibrations of the runs of the same serial and procedure already in the
    archive under the same conditions (`comparable_runs`). Earlier runs keep
    their verdicts (the archive is append-only); `calib repeatability SERIAL`
    judges a whole group on demand.

    Returns
    -------
    (checks "verify:..." and "repeat:...", statistics for the check step:
    diagnosis, repeatability_group, verification_points).
    """
    m = loaded.manifest
    factor = m.format.acc_reference_factor()  # acc_unit, or acc_scale_unit for counts
    given = {s.label: s.reference_acc for s in m.segments}
    refs = [
        static_reference(
            label,
            cal.gravity,
            None if given.get(label) is None else np.asarray(given[label]) * factor,
        )
        for label in sorted(loaded.verification_labels)
    ]
    checks = verify_points(cal, loaded.segments, refs, profile)
    run_id = run_id_of(raw_hash_of([f.sha256 for f in loaded.raw_files]))
    current = RunValues(
        run_id,
        m.environment.temperature_c,
        {n: (p.value, p.std) for n, p in cal.parameters.items()},
    )
    others = [
        RunValues(c["run_id"], (c["environment"] or {}).get("temperature_c"), c["parameters"])
        for c in queries.repeatability_candidates(
            archive, m.unit.serial, m.run.procedure, exclude_run_id=run_id
        )
    ]
    rules = profile.repeatability
    group = comparable_runs(current, others, rules["temperature_tol_c"], int(rules["max_runs"]))
    checks += repeatability(group, profile)
    return checks, {
        "diagnosis": diagnose_residuals(cal, profile).to_dict(),
        "repeatability_group": [r.run_id for r in group],
        "verification_points": [r.label for r in refs],
    }


def process_run(
    source: RunSource,
    archive: Archive,
    *,
    reraise: Callable[[BaseException], bool] | None = None,
) -> dict[str, Any]:
    """Ingest, preprocess, solve, check and archive one run. Never raises for bad input.

    Parameters
    ----------
    source : the run on disk.
    archive : where it goes.
    reraise : errors for which ``reraise(exc)`` is true are raised instead of
        becoming a failed outcome, so a caller can retry them (the batch flow
        does, for transient errors: a locked database, a vanished network share).

    Returns the run's entry of the `calib process --json` document.
    """
    where = str(source.folder)
    serial = source.serial or ""
    # The raw files are copied towards the archive's object store as they are hashed
    # at ingest, and archive_run commits those copies: each file is read and hashed
    # once. Whatever is not archived (a failed run, a duplicate) is deleted on close.
    pending = rawstore.PendingFiles()
    try:
        started = time.perf_counter()
        loaded = load_run(source, hash_file=partial(pending.stage_raw, archive.root))
        m = loaded.manifest
        serial = m.unit.serial
        ingest_step = StepRecord(
            "ingest",
            settings={"format": m.format.model_dump(mode="json")},
            statistics={
                "files": len(loaded.raw_files),
                "samples": {k: len(r) for k, r in loaded.segments.items()},
                "seconds": round(time.perf_counter() - started, 4),
            },
        )
        cal, steps, settings = solve_loaded(loaded)
        steps.insert(0, ingest_step)
        started = time.perf_counter()
        profile = load_profile(m.run.tolerance_profile)
        checks = check_parameters(cal, profile) + check_residuals(cal, profile)
        more_checks, judged = verify_run(loaded, cal, profile, archive)
        checks += more_checks
        verdict_ = overall_verdict(checks)
        steps.append(
            StepRecord(
                "check",
                # The thresholds themselves, so every verdict can be re-read as judged.
                settings={
                    "profile": profile.name,
                    "profile_version": profile.version,
                    "thresholds": profile.to_dict(),
                },
                statistics={
                    "checks": len(checks),
                    "failed": sum(not c.passed for c in checks),
                    "verdict": verdict_,
                    **judged,
                    "seconds": round(time.perf_counter() - started, 4),
                },
            )
        )
        run_id = run_id_of(raw_hash_of([f.sha256 for f in loaded.raw_files]))
        params = [
            {
                "name": p.name,
                "value": p.value,
                "std": p.std,
                "unit": p.unit,
                "temperature_c": m.environment.temperature_c,
            }
            for p in sorted(cal.parameters.values(), key=lambda p: p.name)
        ]
        check_dicts = _check_dicts(checks)
        protocol_name = f"{serial}_result.txt"
        protocol_text = render_protocol(
            device_model=m.unit.model,
            serial=serial,
            started_at=m.run.started,
            run_id=run_id,
            procedure=m.run.procedure,
            profile=f"{profile.name} v{profile.version}",
            gravity=cal.gravity,
            operator=m.run.operator,
            parameters=params,
            checks=check_dicts,
            verdict=verdict_,
        )
        result: ArchiveResult = archive_run(
            archive,
            RunIn(
                serial=serial,
                device_model=m.unit.model,
                manufacturer=m.unit.manufacturer,
                specification=m.unit.specification,
                started_at=m.run.started,
                operator=m.run.operator,
                procedure=m.run.procedure,
                site=m.site.model_dump(mode="json"),
                gravity=cal.gravity,
                environment=m.environment.model_dump(mode="json"),
                equipment=[e.model_dump(mode="json") for e in m.equipment],
                manifest_text=loaded.manifest_text,
                tolerance_profile=profile.name,
                raw_files=[
                    RawFileIn(f.path, f.name, f.sha256, f.size, f.format) for f in loaded.raw_files
                ],
                settings=settings,
                software_version=SOFTWARE_VERSION,
                source_revision=source_revision(),
                steps=[s.to_dict() for s in steps],
                calibration=cal.to_dict(),
                parameters=params,
                checks=check_dicts,
                verdict=verdict_,
                profile_name=profile.name,
                profile_version=profile.version,
                samples=samples_table(loaded.segments),
            ),
            extra_files={protocol_name: protocol_text.encode()},
            pending=pending,
        )
    except Exception as exc:
        if reraise is not None and reraise(exc):
            raise
        return _failed(where, serial, exc)
    finally:
        pending.close()
    status = "duplicate" if result.status == "duplicate" else "ok"
    protocol_path = result.files.get(protocol_name)
    return run_outcome(
        source=where,
        serial=serial,
        status=status,
        run_id=result.run_id,
        cal=cal,
        checks=checks,
        protocol=None if protocol_path is None else str(protocol_path),
        verdict_=verdict_,
        message=result.message,
    )


def _failed(where: str, serial: str, exc: Exception) -> dict[str, Any]:
    """The failed outcome of a run: bad input is reported, a bug must not stop the batch."""
    if isinstance(exc, IngestError | ValueError | OSError):
        log.warning("run %s failed: %s", where, exc)
        return run_outcome(source=where, serial=serial, status="failed", error=str(exc))
    log.error("run %s failed with an internal error", where, exc_info=exc)
    return run_outcome(
        source=where,
        serial=serial,
        status="failed",
        error=f"internal error ({type(exc).__name__}): {exc}",
    )
