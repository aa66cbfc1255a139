"""Archive one processed run: files first, then one database transaction.

Identity is by content. A run is identified by ``raw_hash``, the SHA-256 over
the sorted SHA-256s of its raw files, and its ``run_id`` is derived from it,
so the same bytes always land in the same run. A processing of the run is a
calibration identified by ``settings_hash`` (settings, procedure, tolerance
profile) and the software version:

- unknown raw_hash                      -> new run, revision 1          ("ok")
- known raw_hash, known settings + software -> nothing written          ("duplicate")
- known raw_hash, new settings or software  -> revision n+1, supersedes n ("revised")
- a run judged again against the unit's earlier runs (`rejudge_run`) -> revision n+1
  with the same parameters, document and steps, its own checks and verdict ("revised");
  its settings hash also covers the runs it was judged against (`JUDGED_AGAINST`)

Order of writes: raw objects (content-addressed, harmless if orphaned), the
samples Parquet file and the extra files (protocol...) into the run folder,
all made durable (fsync, rename, fsync of their folders: `rawstore.PendingFiles`),
then all rows in one transaction. If the transaction fails, the files this
attempt created in the run folder are removed again. Concurrent archiving of
the same run is resolved by the database's unique constraints: the loser gets
an IntegrityError, looks again and reports "duplicate".

Why one module of ~870 lines: the write path (validation of the input, the plan, the
files, the rows, the retry when a concurrent writer wins) is the story of one
transaction and its invariants, read best top to bottom in one place.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from datetime import UTC, date, datetime
from pathlib import Path
from typing import Any, Literal

import pyarrow as pa
from sqlalchemy import Engine, func, insert, select, text
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from calib_core.calibration import CheckResult, Parameter, StepRecord
from storage import rawstore, schema, seal, store_identity, unit_latest
from storage.current import CURRENT, LATEST_RUN_FIRST
from storage.db import Archive
from storage.naming import check_safe_name
from storage.schema import Base
from storage.settings_hash import JUDGED_AGAINST, REJUDGE_STEP, settings_hash
from storage.settings_hash import canonical_json as _canonical_json

Status = Literal["ok", "duplicate", "revised"]
_MAX_ATTEMPTS = 3


class ArchiveError(RuntimeError):
    """The run could not be archived; nothing of it is in the database."""


class StaleCheckError(ArchiveError):
    """A run of the serial under another description was archived after this run's
    passed ``device:description`` check was made: the run must be checked again (the
    batch retries it, `pipelines.run_task.is_transient`)."""


# The check that compares a run's unit description with the serial's earlier runs
# (pipelines.process.device_check); a pass must still hold when the run is committed.
DESCRIPTION_CHECK = "device:description"
# Class of the per-unit advisory locks (two-key form: apart from the chain's one-key lock).
PG_UNIT_LOCK = 0x756E6974  # "unit"


@dataclass
class RawFileIn:
    """A raw input file as read by the ingest step."""

    path: Path  # where the bytes are now
    name: str  # original file name, kept in the archive
    sha256: str  # of the bytes, 64 lowercase hex digits
    size: int  # bytes
    format: str  # "mpu6000-txt", "csv", "mat", "mcap", "manifest"...


@dataclass
class RunIn:
    """Everything the archive keeps about one processed run (SI units): plain data, and the
    parameters, checks and steps as calib_core objects, from which the archive writes its
    rows and the sealed calibration document."""

    serial: str
    device_model: str
    manufacturer: str
    specification: str | None
    started_at: datetime  # time zone aware
    operator: str | None
    procedure: str
    site: dict[str, Any]
    gravity: float  # m/s^2 used by the solver
    environment: dict[str, Any]
    equipment: list[dict[str, Any]]  # kind, serial, model, accuracy_class, calibration_due...
    manifest_text: str | None
    tolerance_profile: str | None
    raw_files: list[RawFileIn]
    settings: dict[str, Any]
    software_version: str
    source_revision: str | None
    steps: list[StepRecord]  # in order; the rows of processing_steps
    calibration: dict[str, Any]  # Calibration.to_dict(); its "parameters" come from `parameters`
    parameters: list[Parameter]  # the parameters rows and the document's, in this order
    checks: list[CheckResult]  # the check_results rows
    verdict: str  # "pass", "needs review" or "fail"
    profile_name: str | None
    profile_version: str | None
    samples: pa.Table | rawstore.SamplesFile | None = None  # a SamplesFile: written already
    # The temperature the parameters belong to (deg C; None: not recorded), kept on
    # every parameter row (the run's lab temperature).
    parameter_temperature_c: float | None = None


@dataclass
class ArchiveResult:
    """What `archive_run` did. `files` maps each extra file name to where it was written."""

    status: Status
    run_id: str
    revision: int
    calibration_id: int
    run_dir: Path
    message: str
    files: dict[str, Path] = field(default_factory=dict)


# --- parameters: one form for rows and document -------------------------------


def calibration_document(run: RunIn) -> dict[str, Any]:
    """The stored calibration document: ``run.calibration`` with its parameters from
    ``run.parameters``.

    The archive writes both the ``parameters`` rows and the parameters of the stored
    calibration document from the same `Parameter` objects, so the two cannot disagree
    when written (`storage.verify` reports any later disagreement).
    """
    return {**run.calibration, "parameters": {p.name: p.to_dict() for p in run.parameters}}


# --- identities -------------------------------------------------------------


def raw_hash_of(sha256s: list[str]) -> str:
    """SHA-256 over the sorted file hashes, one per line: order of listing does not matter."""
    return hashlib.sha256("\n".join(sorted(sha256s)).encode()).hexdigest()


def run_id_of(raw_hash: str) -> str:
    """The run id derived from a raw hash ("R" + 12 hex digits = 48 bits)."""
    return "R" + raw_hash[:12]


def settings_hash_of(run: RunIn) -> str:
    """SHA-256 of the canonical JSON of what decides the result besides the raw bytes."""
    return settings_hash(run.settings, run.procedure, run.profile_name, run.profile_version)


# --- validation (before anything touches the disk) ---------------------------


def _as_date(value: Any, where: str) -> date | None:
    if value is None or (isinstance(value, date) and not isinstance(value, datetime)):
        return value
    if isinstance(value, datetime):
        return value.date()
    if isinstance(value, str):
        try:
            return date.fromisoformat(value)
        except ValueError:
            pass
    raise ValueError(f"{where}: expected a date (YYYY-MM-DD), got {value!r}")


def _number(value: Any, where: str, *, optional: bool) -> float | None:
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _validate(run: RunIn, extra_files: dict[str, bytes]) -> None:
    check_safe_name(run.serial, "serial")
    for name in extra_files:
        check_safe_name(name, "extra file name")
    if not isinstance(run.started_at, datetime) or run.started_at.utcoffset() is None:
        raise ValueError(f"started_at: expected a time-zone-aware datetime, got {run.started_at!r}")
    if not run.raw_files:
        raise ValueError(f"run of {run.serial}: no raw files")
    names = [f.name for f in run.raw_files]
    if len(set(names)) != len(names):
        raise ValueError(f"raw_files: file names repeat: {sorted(names)}")
    for f in run.raw_files:
        rawstore.object_path(Path("."), f.sha256)  # raises on a malformed hash
        if not isinstance(f.size, int) or f.size < 0:
            raise ValueError(f"raw file {f.name}: size {f.size!r} is not a byte count")
    for key in ("device_model", "manufacturer", "procedure", "software_version", "verdict"):
        if not isinstance(getattr(run, key), str) or not getattr(run, key):
            raise ValueError(f"{key}: expected a non-empty string, got {getattr(run, key)!r}")
    _number(run.gravity, "gravity", optional=False)
    for i, eq in enumerate(run.equipment):
        for key in ("kind", "serial"):
            if not isinstance(eq.get(key), str) or not eq.get(key):
                raise ValueError(f"equipment[{i}].{key}: expected a non-empty string")
        for key in ("calibration_due", "calibrated_on"):
            _as_date(eq.get(key), f"equipment[{i}].{key}")
    _number(run.parameter_temperature_c, "parameter_temperature_c", optional=True)
    for what, items, kind in (
        ("parameters", run.parameters, Parameter),
        ("steps", run.steps, StepRecord),
        ("checks", run.checks, CheckResult),
    ):
        for i, item in enumerate(items):
            if not isinstance(item, kind):
                raise TypeError(
                    f"{what}[{i}]: expected a {kind.__name__}, got {type(item).__name__}"
                )
            if not isinstance(item.name, str) or not item.name:
                raise ValueError(f"{what}[{i}].name: expected a non-empty string")
    for i, p in enumerate(run.parameters):
        _number(p.value, f"parameters[{i}] ({p.name}).value", optional=False)
        _number(p.std, f"parameters[{i}] ({p.name}).std", optional=True)
    for i, c in enumerate(run.checks):
        _number(c.value, f"checks[{i}] ({c.name}).value", optional=True)
        _number(c.limit, f"checks[{i}] ({c.name}).limit", optional=True)
        if not isinstance(c.passed, bool):
            raise ValueError(f"checks[{i}].passed: expected true or false, got {c.passed!r}")
    for where, value in [
        ("site", run.site),
        ("environment", run.environment),
        ("calibration", run.calibration),
        ("steps", [st.to_dict() for st in run.steps]),
    ]:
        _canonical_json(value, where)
    if run.samples is not None and not isinstance(run.samples, pa.Table | rawstore.SamplesFile):
        raise TypeError(
            f"samples: expected a pyarrow.Table or a SamplesFile, got {type(run.samples).__name__}"
        )


# --- planning ----------------------------------------------------------------


@dataclass(frozen=True)
class _Plan:
    run_pk: int | None  # None: a new run
    revision: int
    previous_id: int | None  # the revision this one supersedes
    duplicate_of: tuple[int, int] | None = None  # (calibration id, revision)
    run_dir: str | None = None  # of an existing run, relative to the root


def _plan(session: Session, run: RunIn, raw_hash: str, settings_hash: str) -> _Plan:
    """What archiving `run` means given what the database holds now."""
    row = session.execute(
        select(schema.Run.id, schema.Run.run_id, schema.Run.run_dir, schema.Device.serial)
        .join(schema.Device, schema.Device.id == schema.Run.device_id)
        .where(schema.Run.raw_hash == raw_hash)
    ).one_or_none()
    if row is None:
        return _Plan(run_pk=None, revision=1, previous_id=None)
    if row.serial != run.serial:
        raise ArchiveError(
            f"these raw files are already archived as run {row.run_id} of serial {row.serial!r}, "
            f"not {run.serial!r}: check the manifest"
        )
    same = session.execute(
        select(schema.CalibrationRow.id, schema.CalibrationRow.revision).where(
            schema.CalibrationRow.run_id == row.id,
            schema.CalibrationRow.settings_hash == settings_hash,
            schema.CalibrationRow.software_version == run.software_version,
        )
    ).one_or_none()
    last = session.execute(
        select(func.max(schema.CalibrationRow.revision)).where(
            schema.CalibrationRow.run_id == row.id
        )
    ).scalar_one()
    current = session.execute(
        select(schema.CalibrationRow.id).where(
            schema.CalibrationRow.run_id == row.id, schema.CalibrationRow.superseded_by.is_(None)
        )
    ).scalar_one_or_none()
    return _Plan(
        run_pk=row.id,
        revision=(last or 0) + 1,
        previous_id=current,
        duplicate_of=None if same is None else (same.id, same.revision),
        run_dir=row.run_dir,
    )


class _PlanChangedError(Exception):
    """Another writer committed between planning and the transaction: plan again."""


# --- writing -------------------------------------------------------------------


def archive_run(
    archive: Archive,
    run: RunIn,
    extra_files: dict[str, bytes] | None = None,
    *,
    pending: rawstore.PendingFiles | None = None,
    reason: str | None = None,
) -> ArchiveResult:
    """Archive a processed run (idempotent; see the module docstring).

    Parameters
    ----------
    archive : where to write; its schema must be current (`Archive.upgrade`).
    run : the run, its processing and results.
    extra_files : file name -> bytes written into the run folder (revision 1)
        or its ``revision-<n>`` subfolder, e.g. the test protocol.
    pending : where the run's files are queued and committed; raw files the
        caller staged there at ingest (`rawstore.PendingFiles.stage_raw`) are
        stored without another read. The caller closes it. None: one of its own.
    reason : why, for the audit trail; a revision without one records what
        changed (settings, software version).

    Returns
    -------
    ArchiveResult; ``status`` is "ok", "revised" or "duplicate".

    Raises
    ------
    ValueError for invalid input (before anything is written), ArchiveError
    when the transaction fails (nothing of the run is then in the database).
    """
    extra_files = dict(extra_files or {})
    _validate(run, extra_files)
    seal.check_reason(reason)
    raw_hash = raw_hash_of([f.sha256 for f in run.raw_files])
    run_id = run_id_of(raw_hash)
    settings_hash = settings_hash_of(run)
    root = archive.root
    new_run_dir = rawstore.run_dir(root, run.serial, run.started_at.astimezone(UTC), run_id)
    # SQLite: take the write lock at BEGIN so a concurrent writer waits instead of
    # failing halfway; PostgreSQL ignores the option.
    engine = archive.engine().execution_options(sqlite_begin="IMMEDIATE")

    created: list[Path] = []  # files/folders this call created, removed again on failure
    plan: _Plan | None = None
    last_error: Exception | None = None
    own = pending is None
    store_identity.check(archive)  # PostgreSQL: the database's own file store, no other
    pending = rawstore.PendingFiles() if pending is None else pending
    try:
        for attempt in range(_MAX_ATTEMPTS):
            with Session(engine) as session:
                new_plan = _plan(session, run, raw_hash, settings_hash)
            if new_plan.duplicate_of is not None:
                return _duplicate(root, run, run_id, new_plan)
            if last_error is not None and new_plan == plan and attempt > 1:
                break  # the database state did not change: the error is in this run's data
            plan = new_plan
            rdir = new_run_dir if plan.run_dir is None else root / plan.run_dir
            written = _write_files(root, run, run_id, rdir, plan, extra_files, created, pending)
            try:
                cal_id = _write_rows(
                    engine,
                    run,
                    (raw_hash, run_id, settings_hash),
                    root,
                    rdir,
                    plan,
                    written,
                    reason,
                )
            except _PlanChangedError:
                continue
            except IntegrityError as exc:
                last_error = exc
                continue
            return _result(run, run_id, rdir, plan, cal_id, written.files)
        raise ArchiveError(
            f"run {run_id} of {run.serial}: the database refused the rows: {_reason(last_error)}"
        ) from last_error
    except BaseException:
        _cleanup(created)
        raise
    finally:
        if own:
            pending.close()


def _reason(exc: Exception | None) -> str:
    orig = getattr(exc, "orig", None)
    return (
        str(orig or exc).strip().splitlines()[0] if exc else "concurrent writers kept changing it"
    )


def _duplicate(root: Path, run: RunIn, run_id: str, plan: _Plan) -> ArchiveResult:
    cal_id, revision = plan.duplicate_of  # type: ignore[misc]
    return ArchiveResult(
        status="duplicate",
        run_id=run_id,
        revision=revision,
        calibration_id=cal_id,
        run_dir=root / plan.run_dir,  # type: ignore[operator]
        message=(
            f"already archived: run {run_id} (revision {revision}) holds these raw files "
            f"of {run.serial}, processed with the same settings and software {run.software_version}"
        ),
    )


def _result(
    run: RunIn, run_id: str, rdir: Path, plan: _Plan, cal_id: int, files: dict[str, Path]
) -> ArchiveResult:
    if plan.run_pk is None:
        status, message = "ok", f"archived run {run_id} of {run.serial}"
    else:
        status = "revised"
        message = (
            f"run {run_id} of {run.serial} processed again: revision {plan.revision} "
            f"supersedes revision {plan.revision - 1}"
        )
    return ArchiveResult(status, run_id, plan.revision, cal_id, rdir, message, files)


@dataclass
class _Written:
    files: dict[str, Path]  # extra file name -> path
    sha256s: dict[str, str]  # path relative to the root -> sha256, of the extra files
    samples: tuple[str, str] | None  # (path relative to the root, sha256) of a new samples file


def _write_files(
    root: Path,
    run: RunIn,
    run_id: str,
    rdir: Path,
    plan: _Plan,
    extra_files: dict[str, bytes],
    created: list[Path],
    pending: rawstore.PendingFiles,
) -> _Written:
    """Raw objects, samples (new runs only) and extra files, durable on return.

    All are queued in `pending` and committed together (`rawstore.PendingFiles`).
    """
    for f in run.raw_files:
        rawstore.store_raw(root, Path(f.path), f.sha256, pending)
    samples = None
    if plan.run_pk is None and run.samples is not None:
        day = run.started_at.astimezone(UTC)
        path = rawstore.samples_path(root, run.serial, day, run_id)
        _note_new(path, created)
        if isinstance(run.samples, rawstore.SamplesFile):  # a streamed record's, written
            pending.adopt(run.samples.path, path)
            sha = run.samples.sha256
        else:
            path, sha = rawstore.write_samples(pending, root, run.serial, day, run_id, run.samples)
        samples = (path.relative_to(root).as_posix(), sha)
    # Later revisions get their own folder: an archived file is never overwritten.
    target = rdir if plan.revision == 1 else rdir / f"revision-{plan.revision}"
    _note_new(target, created)
    files, sha256s = {}, {}
    for name, data in extra_files.items():
        pending.write_bytes(target / name, data)
        files[name] = target / name
        sha256s[(target / name).relative_to(root).as_posix()] = hashlib.sha256(data).hexdigest()
    pending.commit()
    return _Written(files, sha256s, samples)


def _note_new(path: Path, created: list[Path]) -> None:
    # Only the path itself, never a parent: a parent may be shared with another run
    # being archived at the same time. Empty parents left behind are harmless.
    if not path.exists() and path not in created:
        created.append(path)


def _cleanup(created: list[Path]) -> None:
    for p in reversed(created):
        if p.is_dir():
            rawstore.remove_tree(p)
        else:
            p.unlink(missing_ok=True)


def _write_rows(
    engine: Engine,
    run: RunIn,
    ids: tuple[str, str, str],
    root: Path,
    rdir: Path,
    plan: _Plan,
    written: _Written,
    reason: str | None,
) -> int:
    """All rows of the run and its seal in one transaction; return the new calibration's id.

    `ids` is (raw hash, run id, settings hash).
    """
    raw_hash, run_id, settings_hash = ids
    with Session(engine) as s, s.begin():
        if _plan(s, run, raw_hash, settings_hash) != plan:
            raise _PlanChangedError
        run_pk = plan.run_pk
        if run_pk is None:
            rel_dir = rdir.relative_to(root).as_posix()
            run_pk = _insert_run(s, run, raw_hash, run_id, rel_dir, written.samples)
        cal = schema.CalibrationRow(
            run_id=run_pk,
            revision=plan.revision,
            settings_hash=settings_hash,
            settings=run.settings,
            software_version=run.software_version,
            source_revision=run.source_revision,
            document=calibration_document(run),
            verdict=run.verdict,
            profile_name=run.profile_name,
            profile_version=run.profile_version,
        )
        s.add(cal)
        s.flush()
        if plan.previous_id is not None:
            s.get(schema.CalibrationRow, plan.previous_id).superseded_by = cal.id
        _insert_children(s, run, run_pk, cal.id)
        s.flush()
        device_id = s.scalar(select(schema.Run.device_id).where(schema.Run.id == run_pk))
        unit_latest.refresh(s.connection(), device_id)  # the fleet's picks, never stale
        if plan.previous_id is not None and reason is None:
            reason = _revision_reason(s, plan.previous_id, settings_hash, run.software_version)
        action = "archived" if plan.run_pk is None else "revised"
        seal.seal_calibration(s.connection(), cal.id, action, files=written.sha256s, reason=reason)
        return cal.id


# --- judged again ----------------------------------------------------------------


@dataclass
class Rejudgement:
    """A run's current revision judged again against the unit's earlier runs.

    run_id : the run.
    calibration_id : the revision judged again; it must still be the current one.
    earlier : run ids of the unit's runs (same procedure) made before it, most recent first,
        as the new checks saw them; they must still be the archive's.
    checks : every check of the new revision.
    check_statistics : the statistics of its ``check`` step.
    verdict : the new verdict.
    step : the step record of the judgement, appended to the revision's steps.
    reason : why, into the audit trail.
    """

    run_id: str
    calibration_id: int
    earlier: list[str]
    checks: list[CheckResult]
    check_statistics: dict[str, Any]
    verdict: str
    step: StepRecord
    reason: str


def rejudge_run(archive: Archive, judged: Rejudgement) -> ArchiveResult | None:
    """A new revision of a run with the same parameters, document and steps, judged again.

    Its settings are the revision's; its ``rejudge`` step records the runs it was judged
    against (`JUDGED_AGAINST`: ``judged.earlier``), and its settings hash covers them
    besides the settings (`settings_hash`), so a reader recomputes it from the sealed
    rows (`storage.verify`). Sealed as "revised" with the reason.

    Returns
    -------
    ArchiveResult ("revised"); None when the archive changed since the checks were made
    (another revision of the run, another earlier run): judge again.
    """
    seal.check_reason(judged.reason)
    engine = archive.engine().execution_options(sqlite_begin="IMMEDIATE")
    try:
        with Session(engine) as s, s.begin():
            prev = s.get(schema.CalibrationRow, judged.calibration_id)
            run = s.get(schema.Run, prev.run_id) if prev is not None else None
            if run is None or run.run_id != judged.run_id or prev.superseded_by is not None:
                return None
            if _earlier_runs(s, run) != judged.earlier:
                return None
            cal = _judged_again(s, prev, run.procedure, judged)
            unit_latest.refresh(s.connection(), run.device_id)
            seal.seal_calibration(s.connection(), cal.id, "revised", reason=judged.reason)
            result = ArchiveResult(
                "revised",
                run.run_id,
                cal.revision,
                cal.id,
                archive.root / run.run_dir,
                f"run {run.run_id} judged again: revision {cal.revision} supersedes "
                f"revision {prev.revision} ({judged.reason})",
            )
    except IntegrityError:  # a concurrent revision of the same run won
        return None
    return result


def _earlier_runs(s: Session, run: schema.Run) -> list[str]:
    """Run ids of the unit's runs by the same procedure made before `run`, with a current
    revision, most recent first (`storage.queries.repeatability_candidates`' order)."""
    return list(
        s.scalars(
            select(schema.Run.run_id)
            .join(schema.CalibrationRow, schema.CalibrationRow.run_id == schema.Run.id)
            .where(
                schema.Run.device_id == run.device_id,
                schema.Run.procedure == run.procedure,
                schema.Run.started_at < run.started_at,
                CURRENT,
            )
            .order_by(*LATEST_RUN_FIRST)
        )
    )


def _judged_again(
    s: Session, prev: schema.CalibrationRow, procedure: str, judged: Rejudgement
) -> schema.CalibrationRow:
    """The rows of the new revision: `prev`'s, with the checks and verdict of `judged`."""
    revision = 1 + s.scalar(
        select(func.max(schema.CalibrationRow.revision)).where(
            schema.CalibrationRow.run_id == prev.run_id
        )
    )
    cal = schema.CalibrationRow(
        run_id=prev.run_id,
        revision=revision,
        settings_hash=settings_hash(
            prev.settings, procedure, prev.profile_name, prev.profile_version, judged.earlier
        ),
        settings=prev.settings,
        software_version=prev.software_version,
        source_revision=prev.source_revision,
        document=prev.document,
        verdict=judged.verdict,
        profile_name=prev.profile_name,
        profile_version=prev.profile_version,
    )
    s.add(cal)
    s.flush()
    prev.superseded_by = cal.id
    steps = (
        s.execute(
            select(schema.ProcessingStep)
            .where(schema.ProcessingStep.calibration_id == prev.id)
            .order_by(schema.ProcessingStep.seq)
        )
        .scalars()
        .all()
    )
    rows = [
        {
            "run_id": prev.run_id,
            "calibration_id": cal.id,
            "seq": i,
            "name": st.name,
            "settings": st.settings,
            "statistics": judged.check_statistics if st.name == "check" else st.statistics,
            "software_version": st.software_version,
            "source_revision": st.source_revision,
        }
        for i, st in enumerate(steps)
    ]
    rows.append(
        {
            "run_id": prev.run_id,
            "calibration_id": cal.id,
            "seq": len(rows),
            "name": REJUDGE_STEP,
            "settings": {**judged.step.settings, JUDGED_AGAINST: judged.earlier},
            "statistics": judged.step.statistics,
            "software_version": judged.step.software_version,
            "source_revision": prev.source_revision,
        }
    )
    _insert_many(s, schema.ProcessingStep, rows)
    params = s.execute(
        select(
            schema.ParameterRow.name,
            schema.ParameterRow.value,
            schema.ParameterRow.std,
            schema.ParameterRow.unit,
            schema.ParameterRow.temperature_c,
        )
        .where(schema.ParameterRow.calibration_id == prev.id)
        .order_by(schema.ParameterRow.id)
    ).all()
    _insert_many(s, schema.ParameterRow, [{"calibration_id": cal.id, **p._mapping} for p in params])
    _insert_many(
        s,
        schema.CheckResultRow,
        [
            {
                "calibration_id": cal.id,
                "name": c.name,
                "value": c.value,
                "limit": c.limit,
                "passed": c.passed,
                "detail": c.detail,
                "profile_name": prev.profile_name,
                "profile_version": prev.profile_version,
            }
            for c in judged.checks
        ],
    )
    s.flush()
    return cal


def _revision_reason(s: Session, previous_id: int, settings_hash: str, software: str) -> str:
    """What changed since the revision a new one supersedes, when no reason was given."""
    prev = s.get(schema.CalibrationRow, previous_id)
    changed = []
    if prev.settings_hash != settings_hash:
        changed.append(f"settings {prev.settings_hash[:12]} -> {settings_hash[:12]}")
    if prev.software_version != software:
        changed.append(f"software {prev.software_version} -> {software}")
    return "processed again (no reason given): " + ", ".join(changed)


def _insert_children(s: Session, run: RunIn, run_pk: int, cal_id: int) -> None:
    """The step, parameter and check rows of a new calibration revision."""
    steps = [
        {
            "run_id": run_pk,
            "calibration_id": cal_id,
            "seq": i,
            "name": st.name,
            "settings": st.settings,
            "statistics": st.statistics,
            "software_version": st.software_version,
            "source_revision": run.source_revision,
        }
        for i, st in enumerate(run.steps)
    ]
    _insert_many(s, schema.ProcessingStep, steps)
    rows = [
        {
            "calibration_id": cal_id,
            "name": p.name,
            "value": p.value,
            "std": p.std,
            "unit": p.unit,
            "temperature_c": run.parameter_temperature_c,
        }
        for p in run.parameters
    ]
    _insert_many(s, schema.ParameterRow, rows)
    checks = [
        {
            "calibration_id": cal_id,
            "name": c.name,
            "value": c.value,
            "limit": c.limit,
            "passed": c.passed,
            "detail": c.detail,
            "profile_name": run.profile_name,
            "profile_version": run.profile_version,
        }
        for c in run.checks
    ]
    _insert_many(s, schema.CheckResultRow, checks)


def _insert_run(
    s: Session,
    run: RunIn,
    raw_hash: str,
    run_id: str,
    rel_dir: str,
    samples: tuple[str, str] | None,
) -> int:
    if s.bind.dialect.name == "postgresql":
        # New runs of one unit are committed one at a time (SQLite writers queue at BEGIN
        # IMMEDIATE), so the description guard sees every earlier one. An advisory lock,
        # as the writer role may not lock rows (SELECT ... FOR UPDATE needs UPDATE).
        s.execute(
            text("SELECT pg_advisory_xact_lock(:k, hashtext(:serial))"),
            {"k": PG_UNIT_LOCK, "serial": run.serial},
        )
    device = s.scalars(
        select(schema.Device).where(schema.Device.serial == run.serial)
    ).one_or_none()
    if device is not None:
        _guard_description(s, run, device.id, run_id)
    if device is None:
        device = schema.Device(
            serial=run.serial,
            model=run.device_model,
            manufacturer=run.manufacturer,
            specification=run.specification,
        )
        s.add(device)
        s.flush()
    row = schema.Run(
        run_id=run_id,
        device_id=device.id,
        started_at=run.started_at,
        operator=run.operator,
        procedure=run.procedure,
        site=run.site,
        gravity=run.gravity,
        environment=run.environment,
        manifest_text=run.manifest_text,
        raw_hash=raw_hash,
        model=run.device_model,  # the run's own description, whatever the device row says
        manufacturer=run.manufacturer,
        specification=run.specification,
        tolerance_profile=run.tolerance_profile,
        run_dir=rel_dir,
        samples_path=None if samples is None else samples[0],
        samples_sha256=None if samples is None else samples[1],
    )
    s.add(row)
    s.flush()
    for i, eq in enumerate(run.equipment):
        s.add(
            schema.RunEquipment(
                run_id=row.id,
                equipment_id=_equipment_id(s, eq),
                calibration_due=_as_date(eq.get("calibration_due"), f"equipment[{i}]"),
                calibrated_on=_as_date(eq.get("calibrated_on"), f"equipment[{i}]"),
            )
        )
    _insert_many(
        s,
        schema.RawFileRow,
        [
            {
                "run_id": row.id,
                "name": f.name,
                "sha256": f.sha256,
                "size": f.size,
                "format": f.format,
                "stored_path": rawstore.object_path(Path("."), f.sha256).as_posix(),
            }
            for f in run.raw_files
        ],
    )
    return row.id


def _guard_description(s: Session, run: RunIn, device_pk: int, run_id: str) -> None:
    """Refuse a run whose passed `DESCRIPTION_CHECK` no longer holds: a run of the same
    serial with another model or manufacturer was committed since (concurrent runs of
    one unit in a batch). Runs without that check are not judged here."""
    if not any(c.name == DESCRIPTION_CHECK and c.passed for c in run.checks):
        return
    other = s.execute(
        select(schema.Run.run_id, schema.Run.model, schema.Run.manufacturer)
        .where(
            schema.Run.device_id == device_pk,
            (schema.Run.model != run.device_model) | (schema.Run.manufacturer != run.manufacturer),
        )
        .limit(1)
    ).first()
    if other is not None:
        raise StaleCheckError(
            f"run {run_id} of {run.serial}: run {other.run_id}, archived while this run was "
            f"checked, describes the unit as model {other.model!r} by {other.manufacturer!r}, "
            f"this run as {run.device_model!r} by {run.manufacturer!r}: its "
            f"{DESCRIPTION_CHECK} check is out of date; process the run again"
        )


def _insert_many(s: Session, model: type[Base], rows: list[dict[str, Any]]) -> None:
    """INSERT the rows in one executemany, on the session's connection (Core).

    The tens of step, parameter and check rows of a run need no ORM objects,
    whose bookkeeping cost more than the SQL; the ORM's bulk insert of the same
    rows, the same statement and defaults, still cost more than Core.
    """
    if rows:  # an empty parameter list would insert one row of defaults
        s.connection().execute(insert(model.__table__), rows)


def _equipment_id(s: Session, eq: dict[str, Any]) -> int:
    found = s.scalars(
        select(schema.Equipment.id).where(
            schema.Equipment.kind == eq["kind"], schema.Equipment.serial == eq["serial"]
        )
    ).one_or_none()
    if found is not None:
        return found
    row = schema.Equipment(
        kind=eq["kind"],
        serial=eq["serial"],
        model=eq.get("model"),
        accuracy_class=eq.get("accuracy_class"),
        calibration_due=_as_date(eq.get("calibration_due"), "equipment.calibration_due"),
        calibrated_on=_as_date(eq.get("calibrated_on"), "equipment.calibrated_on"),
    )
    s.add(row)
    s.flush()
    return row.id
