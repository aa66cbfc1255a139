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

The write path (the plan, the files, the rows, the retry when a concurrent writer wins)
is the story of one transaction and its invariants, read top to bottom here; what the
run is and its validation are in storage.run_input, a run judged again in
storage.rejudgement, the revision's child rows in storage.revision_rows.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, field
from datetime import UTC
from pathlib import Path
from typing import Literal

from sqlalchemy import Engine, func, select, text
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from storage import rawstore, schema, seal, store_identity, unit_latest
from storage.current import CURRENT
from storage.db import Archive
from storage.revision_rows import add_revision, check_rows, insert_many, step_row
from storage.run_input import (
    EquipmentIn,
    RunIn,
    calibration_document,
    raw_hash_of,
    run_id_of,
    run_row,
    settings_hash_of,
    validate,
)

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
        select(schema.CalibrationRow.id).where(schema.CalibrationRow.run_id == row.id, CURRENT)
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
    validate(run, extra_files)
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
        previous = None
        if plan.previous_id is not None:
            previous = s.get(schema.CalibrationRow, plan.previous_id)
        cal = add_revision(
            s,
            previous,
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
    steps = [step_row(run_pk, cal_id, i, st, run.source_revision) for i, st in enumerate(run.steps)]
    insert_many(s, schema.ProcessingStep, steps)
    rows = [
        {"calibration_id": cal_id, **p.to_row(run.parameter_temperature_c)} for p in run.parameters
    ]
    insert_many(s, schema.ParameterRow, rows)
    checks = check_rows(cal_id, run.checks, run.profile_name, run.profile_version)
    insert_many(s, schema.CheckResultRow, checks)


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
        **run_row(run),
        raw_hash=raw_hash,
        model=run.device_model,  # the run's own description, whatever the device row says
        manufacturer=run.manufacturer,
        specification=run.specification,
        run_dir=rel_dir,
        samples_path=None if samples is None else samples[0],
        samples_sha256=None if samples is None else samples[1],
    )
    s.add(row)
    s.flush()
    for eq in run.equipment:
        s.add(
            schema.RunEquipment(
                run_id=row.id,
                equipment_id=_equipment_id(s, eq),
                calibration_due=eq.calibration_due,
                calibrated_on=eq.calibrated_on,
            )
        )
    insert_many(
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


def _equipment_id(s: Session, eq: EquipmentIn) -> int:
    found = s.scalars(
        select(schema.Equipment.id).where(
            schema.Equipment.kind == eq.kind, schema.Equipment.serial == eq.serial
        )
    ).one_or_none()
    if found is not None:
        return found
    row = schema.Equipment(**asdict(eq))  # its fields are the table's columns
    s.add(row)
    s.flush()
    return row.id
