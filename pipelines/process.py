"""One lab run from its files to the archive: ingest, preprocess, solve, check, archive.

Each stage is a plain function; `process_run` strings them together and turns
any error into a failed outcome (nothing archived) so a batch goes on. The
Prefect flows in `pipelines.flows` wrap `process_run` and nothing else.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
import pyarrow as pa

from calib_core import procedures, verification
from calib_core.calibration import Calibration, CheckResult, Parameter, StepRecord
from calib_core.checks import check_calibration, overall_verdict
from calib_core.condition_rules import NOT_JUDGED
from calib_core.conditions import check_conditions, counts_against_verdict
from calib_core.preprocess.chain import preprocess, replaced_checks
from calib_core.preprocess.motion import static_labels
from calib_core.recording import Recording
from calib_core.solvers.rate_table import plateau_window
from calib_core.stillness import StatedLimits, measured_noise, stillness_problems
from calib_core.tolerances import ToleranceProfile
from calib_core.uncertainty import Budget
from pipelines import shared_reference
from pipelines.as_found import as_found_step, earlier_calibration
from pipelines.ingest import LoadedRun, RunSource, load_run
from pipelines.ingest.data_format import format_dict
from pipelines.ingest.errors import IngestError, naming_the_run
from pipelines.ingest.manifest import RunManifest
from pipelines.issuing import issue_certificate, with_note
from pipelines.lab import lab_precheck
from pipelines.process_streamed import (
    as_found_solver,
    conditions_segments,
    load_streamed,
    solve_streamed_run,
    stream_plan,
)
from pipelines.provenance import SOFTWARE_VERSION, source_revision
from pipelines.rejudge import check_entry, group_of, rejudge_from
from pipelines.reports.display import record_notes
from pipelines.reports.protocol import render_protocol
from pipelines.tolerances import load_profile
from pipelines.uncertainty import uncertainty_step
from storage import queries, rawstore, write_failures
from storage.archive import ArchiveResult, archive_run
from storage.db import Archive
from storage.run_input import RawFileIn, RunIn, raw_hash_of, run_id_of

log = logging.getLogger("calib.process")


def samples_table(segments: dict[str, Recording]) -> pa.Table:
    """All segments' samples as one Arrow table (segment, t, acc_*, gyr_*, temp), SI units.

    Each numeric column is a chunked array, one chunk per segment, rather than one
    concatenated array: the same table (`pa.Table.equals`) and the same Parquet
    bytes (Arrow's writer pages a column the same whatever its chunks), for a
    third of the copying.

    Built from the arrays' buffers: ``pa.array`` imports pandas (pyarrow asks whether
    every input is a pandas object) and the cast of a dictionary column imports
    ``pyarrow.compute``, together a large part of what one run may take.
    """
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
    numeric = {k: _chunked(v) for k, v in cols.items()}
    return pa.table(
        {"segment": _label_column({k: len(rec) for k, rec in segments.items()}), **numeric}
    )


def _chunked(chunks: list[np.ndarray]) -> pa.ChunkedArray:
    """The chunks as one column, of the type `np.concatenate` would give them."""
    kind = np.result_type(*chunks)
    return pa.chunked_array(
        [_numeric_column(np.asarray(c, kind)) for c in chunks], pa.from_numpy_dtype(kind)
    )


def _label_column(counts: dict[str, int]) -> pa.Array:
    """Each label repeated its count of times, as an Arrow string array.

    One bytes join and one offsets array (a string per sample built in Python costs
    more than all the numeric columns together); the same values, so the same Parquet.
    """
    labels = [label.encode() for label in counts]
    sizes = np.repeat([len(b) for b in labels], list(counts.values()))
    offsets = np.zeros(len(sizes) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    if offsets[-1] > np.iinfo(np.int32).max:  # beyond a string array's 32-bit offsets
        return pa.array(np.repeat(list(counts), list(counts.values())), pa.string())
    data = b"".join(b * n for b, n in zip(labels, counts.values(), strict=True))
    return pa.StringArray.from_buffers(
        len(sizes), pa.py_buffer(offsets.astype(np.int32)), pa.py_buffer(data)
    )


def _numeric_column(values: np.ndarray) -> pa.Array:
    """A numeric NumPy column as an Arrow array over the same memory (NaN stays a value,
    as ``pa.array`` keeps it), without ``pa.array``'s import of pandas."""
    values = np.ascontiguousarray(values)
    if values.dtype.kind not in "iuf" or not values.dtype.isnative:
        return pa.array(values)
    kind = pa.from_numpy_dtype(values.dtype)
    return pa.Array.from_buffers(kind, len(values), [None, pa.py_buffer(values)])


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
        "checks": [check_entry(c) for c in (checks or [])],
        "protocol": protocol,
        "verdict": verdict_,
        "source": source,
        "message": message,
    }


def ingest_step(loaded: LoadedRun, seconds: float) -> StepRecord:
    """The step record of ingest: format settings, files, samples per segment, wall time
    (and, for a record streamed in chunks, its memory limit, bytes; the sensors' firmware ids
    per segment when the log records them, ``devices``)."""
    rec = loaded.streamed
    samples = {k: len(r) for k, r in loaded.segments.items()}
    more: dict[str, Any] = {}
    devices = {k: r.devices for k, r in loaded.segments.items() if r.devices}
    if devices:  # the sensors' firmware ids (pipelines.autopilot reads them for exports)
        more["devices"] = devices
    if rec is not None:
        samples = {rec.label: rec.n}
        more = {"streamed": {"memory_limit": rec.memory_limit, "bytes": rec.result.size}}
    return StepRecord(
        "ingest",
        settings={"format": format_dict(loaded.manifest.format)},
        statistics={
            "files": len(loaded.raw_files),
            "samples": samples,
            "seconds": round(seconds, 4),
            **more,
        },
    )


def solve_loaded(
    loaded: LoadedRun, procedure: str | None = None, settings: dict[str, Any] | None = None
) -> tuple[Calibration, list[StepRecord], dict[str, Any], dict[str, Budget], dict[str, Recording]]:
    """Preprocess and solve a loaded run; returns the calibration, step records, settings,
    the GUM budget of each parameter (step "uncertainty") and the preprocessed fit segments.

    `procedure` and `settings` replace the manifest's procedure and update its
    settings (see `calibrate`). Verification segments stay out of the fit
    (docs/reports.md); they are checked after. A record streamed in chunks is solved from
    its samples' Parquet (`pipelines.process_streamed`; no fit segments in memory).
    """
    if loaded.streamed is not None:
        return solve_streamed_run(loaded, procedure, settings)
    m = loaded.manifest
    settings = {**m.run.settings, **(settings or {})}
    started = time.perf_counter()
    segments, steps = preprocess(loaded.segments, settings, gravity=m.gravity())
    # Wall time of the whole preprocessing chain, on its last step (batch benchmark).
    steps[-1].statistics["preprocess_seconds"] = round(time.perf_counter() - started, 4)
    cal, record = procedures.solve_step(
        segments,
        {**settings, "procedure": procedure or m.run.procedure, "gravity": m.gravity()},
        held_out=loaded.verification_labels,
    )
    cal.info.setdefault("solver_checks", []).extend(replaced_checks(steps))
    fit = {k: v for k, v in segments.items() if k not in loaded.verification_labels}
    budgets, budget_step = uncertainty_step(cal, fit, settings, m)
    return cal, [*steps, record, budget_step], settings, budgets, fit


def calibrate(
    run: LoadedRun, procedure: str | None = None, settings: dict[str, Any] | None = None
) -> Calibration:
    """Calibrate a run read with `read_run`: preprocess its segments, then solve.

    Nothing is archived (`process_run` does the whole pipeline into an archive).

    Parameters
    ----------
    run : the run in memory (`pipelines.read_run`).
    procedure : the procedure to solve (a key of `calib_core.procedures.PROCEDURES`,
        e.g. "six_position", "six_position_integral", "multi_position"); None for
        the manifest's (an MPU-6000 folder: "six_position_integral").
    settings : preprocessing and procedure settings that replace the manifest's
        of the same name (docs/manifest.md, docs/procedures.md).

    Returns
    -------
    Calibration: every parameter with its standard uncertainty (SI units),
    residuals per segment, warnings and solver facts (`info`).

    Raises
    ------
    ValueError when the segments do not fit the procedure (missing labels, a
    parameter beyond physical bounds), with the reason.
    """
    return solve_loaded(run, procedure, settings)[0]


def judge(
    run: LoadedRun,
    cal: Calibration,
    archive: Archive | None = None,
    budgets: dict[str, Budget] | None = None,
) -> list[CheckResult]:
    """Every check of a run calibrated with `calibrate`: the set the archive's views of
    the run (`calib show`, the report, the web) count once `process_run` archives it.

    Parameters
    ----------
    run : the run in memory (`pipelines.read_run`).
    cal : its calibration (`calibrate`).
    archive : the archive whose earlier runs of the serial the repeatability and
        ``device:description`` checks are judged against; None: no repeatability, and
        ``device:description`` is listed as "not judged: needs the archive" (status
        "not judged", never counted against the verdict).
    budgets : name -> GUM budget; None judges each parameter with U = 0 and says so.

    Returns
    -------
    CheckResult list: `calib_core.check_calibration`'s, then the lab conditions,
    verification points, repeatability, the record's findings and ``device:description``.
    """
    return check_run(run, cal, archive, "", budgets).checks


def verify_run(
    loaded: LoadedRun,
    cal: Calibration,
    profile: ToleranceProfile,
    archive: Archive | None,
    run_id: str,
    budgets: dict[str, Budget] | None,
    as_judged: AsJudged | None,
) -> tuple[list[CheckResult], dict[str, Any]]:
    """Held-out verification points, repeatability against the archive, residual diagnosis.

    Repeatability is judged against the current calibrations of the unit's runs by
    the same procedure made before this one (by run time) under the same conditions
    (`comparable_runs`), never against later runs (with `as_judged`: the group an
    archived revision records, their values as of it). When an earlier run is archived
    after later ones, `pipelines.rejudge` judges those again (new revisions);
    `calib repeatability SERIAL` judges a whole group on demand. With `budgets`, runs
    on the same reference share their Type B in the scatter rule (pipelines.shared_reference).

    Returns
    -------
    (checks "verify:..." and "repeat:...", statistics for the check step:
    diagnosis, repeatability_group, verification_points).
    """
    m = loaded.manifest
    factor = m.format.acc_reference_factor()  # acc_unit, or acc_scale_unit for counts
    given = {s.label: s.reference_acc for s in m.segments}
    window = plateau_window(m.run.settings)
    refs = [
        verification.rate_reference(loaded.segments[label], **window)
        if "table_rate" in loaded.segments[label].reference
        else verification.reference_point(
            label,
            cal.gravity,
            None if given.get(label) is None else np.asarray(given[label]) * factor,
        )
        for label in sorted(loaded.verification_labels)
    ]
    checks = verification.verify_points(cal, loaded.segments, refs, profile)
    current = verification.RunValues(
        run_id,
        m.environment.temperature_c,
        {n: (p.value, p.std) for n, p in cal.parameters.items()},
    )
    as_then = {} if as_judged is None else {
        "only": as_judged.group, "before_calibration": as_judged.before_calibration
    }  # fmt: skip
    earlier = (
        []  # no archive: no earlier runs to repeat (`judge`)
        if archive is None
        else queries.repeatability_candidates(
            archive,
            m.unit.serial,
            m.run.procedure,
            before=m.run.started,
            exclude_run_id=run_id,
            **as_then,
        )
    )
    mine = None
    if budgets:
        rid = shared_reference.reference_id([e.as_dict() for e in m.equipment], m.site.as_dict())
        mine = {n: (rid, shared_reference.split_budget(b.to_dict())[1]) for n, b in budgets.items()}
    group = group_of(current, earlier, profile, archive if budgets else None, mine)
    checks += verification.repeatability(group, profile)
    return checks, {
        "diagnosis": verification.diagnose_residuals(cal, profile).to_dict(),
        "repeatability_group": [r.run_id for r in group],
        "verification_points": [r.label for r in refs],
    }


SAME_DESCRIPTION = "no other description of this serial archived"


def device_check(m: RunManifest, earlier: list[dict[str, Any]] | None) -> CheckResult:
    """``device:description``: the unit's model and manufacturer against the serial's
    earlier runs (`storage.queries.earlier_descriptions`); None when judged without an
    archive: "not judged: needs the archive" (never counted against the verdict).

    A serial archived before under another model or manufacturer is a relabelled
    or swapped unit, or a typo: the check fails (verdict "needs review") and names
    each other description with the latest run that gave it. Every run keeps its
    own description in the archive.
    """
    if earlier is None:
        detail = f"{NOT_JUDGED}: needs the archive (the serial's earlier runs)"
        return CheckResult("device:description", None, None, False, detail)
    said = (m.unit.model, m.unit.manufacturer)
    other = [e for e in earlier if (e["model"], e["manufacturer"]) != said]
    if not other:  # one wording whatever was archived first: the same in any batch order
        return CheckResult("device:description", None, None, True, SAME_DESCRIPTION)
    before = "; and as ".join(
        f"model {e['model']!r} by {e['manufacturer']!r} (run {e['run_id']}, started "
        f"{e['started_at']:%Y-%m-%d})"
        for e in other
    )
    return CheckResult(
        "device:description",
        None,
        None,
        False,
        f"serial {m.unit.serial} is archived as {before}; this run says model {said[0]!r} by "
        f"{said[1]!r}: a relabelled or swapped unit, or a typo in run.toml? Review before use",
    )


def run_conditions(
    loaded: LoadedRun, cal: Calibration, profile: ToleranceProfile
) -> list[CheckResult]:
    """The lab conditions and acquisition rules of the run (calib_core.conditions), from
    what the manifest records, the lab's equipment pre-check (lab.toml) and the segments
    as acquired."""
    m = loaded.manifest
    precheck, equipment_limits = lab_precheck()  # a profile's own limit wins
    return check_conditions(
        conditions_segments(loaded),
        {**m.recorded_conditions(), **precheck},
        procedure=m.run.procedure,
        settings=m.run.settings,
        gravity=cal.gravity,
        gravity_source=m.site.source(),
        overrides={**equipment_limits, **profile.conditions},
    )


def still_checks(loaded: LoadedRun, gravity: float, profile: ToleranceProfile) -> list[CheckResult]:
    """The static segments of the run's procedure judged still by absolute criteria
    (`calib_core.stillness`): a fit segment that is not is refused (ValueError naming its
    file, the segment and what was measured); a held-out one gives the finding
    ``record:still:<label>`` (the fit can do without it). A run segmented automatically
    (``run.settings.segmentation``) declares continuous recordings, not static segments:
    its statics are those the segmentation found at rest by its own detector."""
    proc = procedures.BY_NAME.get(loaded.manifest.run.procedure)
    if proc is None or "segmentation" in loaded.manifest.run.settings:
        return []
    stated = StatedLimits.of(profile)
    labels = static_labels(proc.static_segments, loaded.segments)
    measured = measured_noise([loaded.segments[label] for label in labels])
    out = []
    for label in labels:
        rec = loaded.segments[label]
        problems = stillness_problems(rec, gravity, stated, measured)
        if not problems:
            continue
        what = f"static segment '{label}' ({rec.source}) moved: {'; '.join(problems)}"
        if label not in loaded.verification_labels:
            raise ValueError(f"{what}; repeat it with the unit at rest")
        out.append(CheckResult(f"record:still:{label}", None, None, False, what))
    return out


@dataclass
class Judged:
    """What the check stage found: checks, verdict, the profile and its step record."""

    checks: list[CheckResult]
    verdict: str
    profile: ToleranceProfile
    step: StepRecord


def check_run(
    loaded: LoadedRun,
    cal: Calibration,
    archive: Archive | None,
    run_id: str,
    budgets: dict[str, Budget] | None = None,
    as_judged: AsJudged | None = None,
) -> Judged:
    """Tolerances (judged by the profile's decision rule with each parameter's expanded
    uncertainty from `budgets`) and residual limits of the run's profile, verification,
    repeatability."""
    started = time.perf_counter()
    if as_judged is not None and as_judged.profile is not None:
        profile = as_judged.profile
    else:
        profile = load_profile(loaded.manifest.run.tolerance_profile)
    checks = check_calibration(cal, profile, budgets)
    checks += run_conditions(loaded, cal, profile)
    more_checks, judged = verify_run(loaded, cal, profile, archive, run_id, budgets, as_judged)
    checks += more_checks
    checks += [CheckResult(**f) for f in loaded.findings]  # the readers' (record:cut:...)
    checks += still_checks(loaded, cal.gravity, profile)
    serial = loaded.manifest.unit.serial
    earlier = None if archive is None else queries.earlier_descriptions(archive, serial, run_id)
    checks.append(device_check(loaded.manifest, earlier))
    verdict_ = overall_verdict(checks)
    step = StepRecord(
        "check",
        # The thresholds themselves, so every verdict can be re-read as judged.
        settings={
            "profile": profile.name,
            "profile_version": profile.version,
            "thresholds": profile.to_dict(),
            "decision_rule": profile.decision_rule.statement(),
        },
        statistics={
            "checks": len(checks),
            "failed": sum(counts_against_verdict(c) for c in checks),
            "verdict": verdict_,
            **judged,
            "seconds": round(time.perf_counter() - started, 4),
        },
    )
    return Judged(checks, verdict_, profile, step)


def archived_parameters(cal: Calibration) -> list[Parameter]:
    """The calibration's parameters in the order the archive keeps them (by name)."""
    return sorted(cal.parameters.values(), key=lambda p: p.name)


def _run_identity(m: RunManifest) -> dict[str, Any]:
    """The unit and the run as the protocol and the archive name them (keyword arguments)."""
    return {
        "serial": m.unit.serial,
        "device_model": m.unit.model,
        "started_at": m.run.started,
        "operator": m.run.operator,
        "procedure": m.run.procedure,
    }


def protocol_of(
    loaded: LoadedRun,
    cal: Calibration,
    judged: Judged,
    run_id: str,
    budgets: dict[str, Budget] | None = None,
) -> str:
    """The test protocol text (MPU-6000 layout) of the run, with the uncertainty budgets."""
    return render_protocol(
        **_run_identity(loaded.manifest),
        run_id=run_id,
        profile=f"{judged.profile.name} v{judged.profile.version}",
        gravity=cal.gravity,
        parameters=archived_parameters(cal),
        checks=judged.checks,
        verdict=judged.verdict,
        budgets={n: b.to_dict() for n, b in (budgets or {}).items()},
        decision_rule=judged.profile.decision_rule.statement(),
        names=judged.profile.protocol_names,
        notes=record_notes(judged.checks, cal.warnings),
    )


def run_record(
    loaded: LoadedRun,
    cal: Calibration,
    steps: list[StepRecord],
    settings: dict[str, Any],
    judged: Judged,
) -> RunIn:
    """Everything the archive keeps of the run, from the manifest and the results."""
    m = loaded.manifest
    return RunIn(
        **_run_identity(m),
        manufacturer=m.unit.manufacturer,
        specification=m.unit.specification,
        site=m.site,
        gravity=cal.gravity,
        environment=m.environment,
        equipment=m.equipment,
        manifest_text=loaded.manifest_text,
        tolerance_profile=judged.profile.name,
        raw_files=[RawFileIn(f.path, f.name, f.sha256, f.size, f.format) for f in loaded.raw_files],
        settings=settings,
        software_version=SOFTWARE_VERSION,
        source_revision=source_revision(),
        steps=[*steps, judged.step],
        calibration=cal.to_dict(),
        parameters=archived_parameters(cal),
        checks=list(judged.checks),
        verdict=judged.verdict,
        profile_name=judged.profile.name,
        profile_version=judged.profile.version,
        samples=samples_table(loaded.segments)
        if loaded.streamed is None
        else loaded.streamed.samples,
        parameter_temperature_c=m.environment.temperature_c,
    )


@dataclass(frozen=True)
class AsJudged:
    """The archive as an archived revision saw it when it was judged (`pipelines.recompute`
    solves and judges the revision again against it, not against the archive of now).

    before_calibration : calibration id of the revision: each run of its group counts with
        the values of the revision that was its latest before this one.
    group : run ids of the repeatability group its ``check`` step records.
    as_found : (run id, revision) of the earlier calibration its ``as_found`` step used;
        None: the revision has no such step.
    profile : the tolerance profile as its ``check`` step archived it (thresholds), not as
        the profile file says now; None: the file's (a revision judged before thresholds
        were archived).
    """

    before_calibration: int
    group: tuple[str, ...]
    as_found: tuple[str, int] | None
    profile: ToleranceProfile | None = None


@dataclass
class Derived:
    """A run processed up to everything the archive keeps of it (`derive_run`)."""

    run: RunIn
    extra_files: dict[str, bytes]
    protocol_name: str
    cal: Calibration
    judged: Judged


def load_source(
    source: RunSource,
    archive: Archive,
    pending: rawstore.PendingFiles,
    *,
    reason: str | None = None,
    correct: Callable[[LoadedRun], tuple[LoadedRun, StepRecord]] | None = None,
) -> tuple[LoadedRun, list[StepRecord]]:
    """The run loaded (its raw files staged towards the store in `pending`), its reference
    corrected by `correct`, and its first steps (reprocess, ingest, reference_correction)."""
    started = time.perf_counter()
    # A static-bias record larger than its memory limit is streamed, not read (unless
    # its settings or a reference correction need it in memory).
    plan = stream_plan(source) if correct is None else None
    if plan is None:
        loaded = load_run(source, hash_file=partial(pending.stage_raw, archive.root))
    else:
        loaded = load_streamed(plan, archive.root, pending)
    steps = [ingest_step(loaded, time.perf_counter() - started)]
    if reason is not None:
        steps.insert(0, StepRecord("reprocess", settings={"reason": reason}))
    if correct is not None:
        loaded, corrected = correct(loaded)
        steps.append(corrected)
    return loaded, steps


def derive_run(
    loaded: LoadedRun,
    steps: list[StepRecord],
    archive: Archive,
    as_judged: AsJudged | None = None,
) -> Derived:
    """Solve and judge a loaded run (`load_source`): the record `archive_run` archives and
    its protocol. `as_judged`: judged against the archive as an archived revision saw it
    (`pipelines.recompute`); None: as the archive is now (`process_run`)."""
    serial = loaded.manifest.unit.serial
    cal, solve_steps, settings, budgets, fit = solve_loaded(loaded)
    corrected = next((s for s in steps if s.name == "reference_correction"), None)
    if corrected is not None:
        settings = {**settings, "reference_correction": corrected.settings}
    run_id = run_id_of(raw_hash_of([f.sha256 for f in loaded.raw_files]))
    judged = check_run(loaded, cal, archive, run_id, budgets, as_judged)
    if as_judged is None:
        earlier = earlier_calibration(archive, serial, loaded.manifest.run.started)
    elif as_judged.as_found is None:
        earlier = None
    else:
        earlier = queries.calibration_revision(archive, *as_judged.as_found)
    if earlier is not None:  # the unit comes back: as found beside as left
        found = None if loaded.streamed is None else as_found_solver(loaded, cal, settings)
        solve_steps.append(
            as_found_step(earlier, cal, fit, settings, budgets, judged.profile, found)
        )
    protocol_name = f"{serial}_result.txt"
    return Derived(
        run_record(loaded, cal, steps + solve_steps, settings, judged),
        {protocol_name: protocol_of(loaded, cal, judged, run_id, budgets).encode()},
        protocol_name,
        cal,
        judged,
    )


def process_run(
    source: RunSource,
    archive: Archive,
    *,
    reraise: Callable[[BaseException], bool] | None = None,
    reason: str | None = None,
    correct: Callable[[LoadedRun], tuple[LoadedRun, StepRecord]] | None = None,
) -> dict[str, Any]:
    """Ingest, preprocess, solve, check and archive one run. Never raises for bad input.

    Parameters
    ----------
    source : the run on disk.
    archive : where it goes.
    reraise : errors for which ``reraise(exc)`` is true are raised instead of
        becoming a failed outcome, so a caller can retry them (the batch flow
        does, for transient errors: a locked database, a vanished network share).
    reason : why an archived run is processed again (`pipelines.reprocess`): kept as
        the settings of a first step ``reprocess`` of the new revision. It is not
        part of the settings hash, so it never makes a duplicate a new revision.
    correct : the loaded run with its reference corrected, and the step saying how
        (`pipelines.impact`); the step's settings join the run's settings as
        ``reference_correction``, so the corrected solve is a revision of its own.

    Returns
    -------
    dict, the run's entry of the `calib process --json` document (docs/cli.md):
    ``status`` ("ok", "duplicate" or "failed"), ``run_id``, ``serial``,
    ``verdict``, ``checks``, ``protocol`` and ``error`` (the reason of a failed run).
    """
    where = str(source.folder)
    serial = source.serial or ""
    # The raw files are copied towards the archive's object store as they are hashed
    # at ingest, and archive_run commits those copies: each file is read and hashed
    # once. Whatever is not archived (a failed run, a duplicate) is deleted on close.
    pending = rawstore.PendingFiles()
    try:
        loaded, steps = load_source(source, archive, pending, reason=reason, correct=correct)
        serial = loaded.manifest.unit.serial
        derived = derive_run(loaded, steps, archive)
        cal, protocol_name = derived.cal, derived.protocol_name
        result: ArchiveResult = archive_run(
            archive,
            derived.run,
            extra_files=derived.extra_files,
            pending=pending,
            reason=reason,  # into the audit trail's event of the revision
        )
        checks, verdict_, message = derived.judged.checks, derived.judged.verdict, result.message
        # The unit's later runs, and this one, judged again by run time where an earlier
        # run came later (also for a duplicate: processing a run again completes that).
        again = rejudge_from(archive, serial, loaded.manifest.run.procedure, result.run_id)
        if (own := again.get(result.run_id)) is not None:
            checks, verdict_ = own["checks"], own["verdict"]
            message += f"; judged again by run time as revision {own['revision']}"
        for other, new in again.items():
            if other != result.run_id:
                message += f"; run {other} judged again: {new['verdict']}"
    except Exception as exc:
        if reraise is not None and reraise(exc):
            raise
        return _failed(where, serial, exc, archive.url)
    finally:
        pending.close()
    if result.status != "duplicate" and (why := issue_certificate(archive, result.run_id)):
        message = with_note(message, result.run_id, why)
    protocol_path = result.files.get(protocol_name)
    return run_outcome(
        source=where,
        serial=serial,
        status="duplicate" if result.status == "duplicate" else "ok",
        run_id=result.run_id,
        cal=cal,
        checks=checks,
        protocol=None if protocol_path is None else str(protocol_path),
        verdict_=verdict_,
        message=message,
    )


def _failed(where: str, serial: str, exc: Exception, database_url: str) -> dict[str, Any]:
    """The failed outcome of a run: bad input is reported, a bug must not stop the batch.

    A full disk, a read-only archive or a missing permission is said as such,
    with the file or database and what to do (`storage.write_failures`).
    """
    if (problem := write_failures.describe(exc, database_url)) is not None:
        log.warning("run %s failed: %s", where, problem)
        return run_outcome(source=where, serial=serial, status="failed", error=problem)
    if isinstance(exc, IngestError | ValueError | OSError):
        log.warning("run %s failed: %s", where, exc)
        error = naming_the_run(exc, where)
        return run_outcome(source=where, serial=serial, status="failed", error=error)
    log.error("run %s failed with an internal error", where, exc_info=exc)
    return run_outcome(
        source=where,
        serial=serial,
        status="failed",
        error=f"internal error ({type(exc).__name__}): {exc}",
    )
