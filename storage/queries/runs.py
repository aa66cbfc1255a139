"""Queries of the archive about one run: summary, export, lineage of a value, samples,
the runs a new one is compared with for repeatability and how a revision was judged.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from datetime import UTC, date, datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import Row, bindparam, func, select
from sqlalchemy.orm import Session, aliased

from storage.current import CURRENT, LATEST_RUN_FIRST, is_current
from storage.db import Archive
from storage.naming import check_safe_name
from storage.queries._common import (
    IN_CHUNK,
    NAMED_PARAMETER,
    PARAMETER_VALUE,
    _dict,
    check_parameter,
    check_text,
    parameter_values,
    reading,
    select_run_calibrations,
)
from storage.queries.records import (
    ArchivedFile,
    DatedRevision,
    EquipmentUse,
    ParameterValue,
    Revision,
    RunSummary,
    Step,
    Unit,
)
from storage.schema import (
    CalibrationRow,
    CheckResultRow,
    Device,
    Equipment,
    ParameterRow,
    ProcessingStep,
    RawFileRow,
    Run,
    RunEquipment,
)
from storage.validation import validations

if TYPE_CHECKING:  # pyarrow (with numpy) is loaded by run_samples only: read-only commands
    import pyarrow as pa  # that never read samples start without it

MIN_RUN_ID_PREFIX = 4  # characters, as git's shortest abbreviation


def full_run_id(archive: Archive, given: str) -> str:
    """The archived run id that `given` names: the id itself or a unique prefix (as git).

    Raises LookupError naming what was given: no run, or a prefix several runs share
    (listing up to five of them); ValueError for a prefix shorter than MIN_RUN_ID_PREFIX
    or with characters a run id never has.
    """
    text = check_text(given, "run id", 100)
    if not re.fullmatch(r"[A-Za-z0-9]+", text):
        raise ValueError(f"run id {given!r}: letters and digits only")
    with reading(archive) as conn:
        if conn.execute(select(Run.id).where(Run.run_id == text)).first() is not None:
            return text
        if len(text) < MIN_RUN_ID_PREFIX:
            raise ValueError(
                f"run id {given!r}: give at least {MIN_RUN_ID_PREFIX} characters of it"
            )
        # A bound LIKE pattern: the text is letters and digits only (checked above).
        found = (
            conn.execute(
                select(Run.run_id).where(Run.run_id.like(text + "%")).order_by(Run.run_id).limit(6)
            )
            .scalars()
            .all()
        )
    if not found:
        raise LookupError(f"no run {given!r} in the archive")
    if len(found) > 1:
        shown = ", ".join(found[:5]) + (", ..." if len(found) > 5 else "")
        raise LookupError(f"run id prefix {given!r} is ambiguous: {shown}")
    return found[0]


def _run_row(s: Session, run_id: str) -> Row:
    row = s.execute(
        select(Run, Device).join(Device, Device.id == Run.device_id).where(Run.run_id == run_id)
    ).one_or_none()
    if row is None:
        raise LookupError(f"no run {run_id!r} in the archive")
    return row


def _calibration(s: Session, run_pk: int, revision: int | None) -> CalibrationRow:
    stmt = select(CalibrationRow).where(CalibrationRow.run_id == run_pk)
    if revision is None:
        stmt = stmt.where(CURRENT)
    else:
        stmt = stmt.where(CalibrationRow.revision == revision)
    cal = s.execute(stmt).scalar_one_or_none()
    if cal is None:
        raise LookupError(f"run has no calibration revision {revision}")
    return cal


_PROVENANCE = ("settings_hash", "settings", "software_version", "source_revision", "verdict",
               "profile_name", "profile_version")  # fmt: skip


def _provenance(cal: Any) -> dict[str, Any]:
    """What produced and judged a calibration revision, from its row (or a row with the
    same attribute names)."""
    return {k: getattr(cal, k) for k in _PROVENANCE}


# A revision's checks in the order written, its steps in order (calibration id ``cal``).
CHECK_COLUMNS = (CheckResultRow.name, CheckResultRow.value, CheckResultRow.limit,
                 CheckResultRow.passed, CheckResultRow.detail)  # fmt: skip
_CHECKS_OF = (
    select(*CHECK_COLUMNS)
    .where(CheckResultRow.calibration_id == bindparam("cal"))
    .order_by(CheckResultRow.id)
)
_STEPS_OF = (
    select(ProcessingStep.seq, ProcessingStep.name, ProcessingStep.settings,
           ProcessingStep.statistics, ProcessingStep.software_version,
           ProcessingStep.source_revision)
    .where(ProcessingStep.calibration_id == bindparam("cal"))
    .order_by(ProcessingStep.seq)
)  # fmt: skip


def revision_record(s: Session, cal: CalibrationRow, **run: Any) -> Revision:
    """The revision `cal` with its parameters, checks and steps; given its `run` (run_id,
    started_at, serial), a DatedRevision."""
    from calib_core.calibration import CheckResult  # numpy: not for `calib audit`

    params = s.execute(
        select(ParameterRow.name, *PARAMETER_VALUE)
        .where(ParameterRow.calibration_id == cal.id)
        .order_by(ParameterRow.name, ParameterRow.temperature_c)
    ).all()
    return (DatedRevision if run else Revision)(
        **run,
        calibration_id=cal.id,
        revision=cal.revision,
        created_at=cal.created_at,
        **_provenance(cal),
        superseded_by=cal.superseded_by,
        parameters=[ParameterValue(*p) for p in params],
        checks=[CheckResult(*c) for c in s.execute(_CHECKS_OF, {"cal": cal.id})],
        steps=[Step(*row) for row in s.execute(_STEPS_OF, {"cal": cal.id})],
        document=cal.document,
    )


# A run's raw files (bound parameter "run": the run's primary key), by name.
_RAW_FILES = (
    select(RawFileRow.name, RawFileRow.sha256, RawFileRow.size, RawFileRow.format,
           RawFileRow.stored_path)
    .where(RawFileRow.run_id == bindparam("run"))
    .order_by(RawFileRow.name)
)  # fmt: skip
_EQUIPMENT_USED = (
    select(Equipment.kind, Equipment.model, Equipment.serial, Equipment.accuracy_class,
           RunEquipment.calibration_due, RunEquipment.calibrated_on)
    .join(RunEquipment, RunEquipment.equipment_id == Equipment.id)
    .where(RunEquipment.run_id == bindparam("run"))
    .order_by(Equipment.kind, Equipment.serial)
)  # fmt: skip


# The columns of a run that its summary gives as they are (RunSummary's first fields).
_RUN_COLUMNS = ("run_id", "started_at", "operator", "procedure", "site", "gravity",
                "environment", "tolerance_profile", "raw_hash", "run_dir", "samples_path",
                "manifest_text", "created_at")  # fmt: skip


def run_summary(archive: Archive, run_id: str) -> RunSummary:
    """Everything about one run and its current calibration revision.

    Parameters
    ----------
    archive : the archive.
    run_id : the full run id (`full_run_id` resolves a prefix).

    Returns
    -------
    RunSummary (storage.queries.records): the run's fields, ``device``, ``equipment``
    (with the due dates valid at run time), ``raw_files``, ``revisions`` (count),
    ``calibration`` (current revision: parameters, checks, steps, document) and
    ``validations`` (the current revision's validation records, storage.validation).
    Raises LookupError if there is no such run.
    """
    with Session(archive.engine()) as s:
        run, dev = _run_row(s, run_id)
        raw = s.execute(_RAW_FILES, {"run": run.id}).all()
        equipment = s.execute(_EQUIPMENT_USED, {"run": run.id}).all()
        revisions = s.scalar(select(func.count()).where(CalibrationRow.run_id == run.id))
        cal = revision_record(s, _calibration(s, run.id, None))
    return RunSummary(
        **{k: getattr(run, k) for k in _RUN_COLUMNS},
        device=Unit(dev.serial, run.model, run.manufacturer, run.specification),
        equipment=[EquipmentUse(*e) for e in equipment],
        raw_files=[ArchivedFile(*r) for r in raw],
        revisions=revisions,
        calibration=cal,
        validations=validations(archive, run.run_id, cal.revision),
    )


def export_calibration(
    archive: Archive, run_id: str, revision: int | None = None
) -> dict[str, Any]:
    """The calibration JSON document of a run with the unit and run metadata.

    Parameters
    ----------
    archive : the archive.
    run_id : the full run id.
    revision : None for the current revision.

    Returns
    -------
    JSON-ready dict: ``unit`` (serial, model, manufacturer), ``run`` (run_id,
    started_at ISO 8601 UTC, procedure, gravity, raw_hash), ``revision``,
    ``software_version``, ``settings_hash``, ``verdict``, ``profile`` and
    ``calibration`` (the `Calibration.to_dict()` document as archived).
    """
    with Session(archive.engine()) as s:
        run, dev = _run_row(s, run_id)
        cal = _calibration(s, run.id, revision)
    return {
        "unit": {"serial": dev.serial, "model": run.model, "manufacturer": run.manufacturer},
        "run": {
            "run_id": run.run_id,
            "started_at": run.started_at.isoformat(),
            "procedure": run.procedure,
            "gravity": run.gravity,
            "raw_hash": run.raw_hash,
        },
        "revision": cal.revision,
        "superseded": not is_current(cal.superseded_by),
        "software_version": cal.software_version,
        "source_revision": cal.source_revision,
        "settings_hash": cal.settings_hash,
        "verdict": cal.verdict,
        "profile": {"name": cal.profile_name, "version": cal.profile_version},
        "calibration": cal.document,
    }


def _validity(started_at: datetime, due: date | None) -> dict[str, Any]:
    """Was equipment within its calibration at a run? (The due date is its last valid UTC day.)"""
    if due is None:
        return {"valid_at_run": None, "days_overdue": None}
    overdue = (started_at.astimezone(UTC).date() - due).days
    return {"valid_at_run": overdue <= 0, "days_overdue": max(overdue, 0)}


_NEWER = aliased(CalibrationRow)


def _lineage_head(current: bool):  # noqa: ANN202 - a select
    """Run, device, the chosen revision and the parameter's values, one row per value.

    Outer joins: the run may lack the revision, the revision the parameter.
    """
    chosen = CURRENT if current else CalibrationRow.revision == bindparam("rev")
    return (
        select(
            Run.id.label("run_pk"),
            *(getattr(Run, k) for k in _RUN_COLUMNS),
            Run.samples_sha256,
            Device.serial,
            Run.model,
            Run.manufacturer,
            Run.specification,
            CalibrationRow.id.label("cal_id"),
            CalibrationRow.revision,
            CalibrationRow.superseded_by,
            CalibrationRow.created_at.label("cal_created_at"),
            *(getattr(CalibrationRow, k) for k in _PROVENANCE),
            _NEWER.revision.label("superseding_revision"),
            ParameterRow.id.label("param_id"),
            *PARAMETER_VALUE,
        )
        .join(Device, Device.id == Run.device_id)
        .outerjoin(CalibrationRow, (CalibrationRow.run_id == Run.id) & chosen)
        .outerjoin(_NEWER, _NEWER.id == CalibrationRow.superseded_by)
        .outerjoin(ParameterRow, NAMED_PARAMETER)
        .where(Run.run_id == bindparam("run_id"))
        .order_by(ParameterRow.temperature_c)
    )


_LIN_HEAD = {True: _lineage_head(True), False: _lineage_head(False)}
# A lineage's equipment fields, in its order.
_LIN_EQUIPMENT = ("kind", "serial", "model", "accuracy_class", "calibrated_on", "calibration_due")


def lineage(
    archive: Archive, run_id: str, name: str, revision: int | None = None
) -> dict[str, Any]:
    """Where one archived parameter value comes from.

    Parameters
    ----------
    archive : the archive.
    run_id : the run ("R" + 12 hex digits).
    name : canonical parameter name.
    revision : calibration revision; None for the current one.

    Returns
    -------
    dict (JSON-ready apart from dates): ``parameter`` (name and its values:
    value, std, unit, temperature_c; several when temperature-dependent),
    ``run`` (started_at, operator, procedure, site, gravity in m/s^2,
    environment, tolerance profile, raw hash, manifest as submitted, samples
    file and hash), ``device``, ``calibration`` (revision, current or
    superseded, settings and settings hash, software version and source
    revision, verdict, profile name and version), ``raw_files`` (name, sha256,
    size, format, stored path), ``steps`` (in order, with settings, statistics,
    software version, source revision) and ``equipment`` (with the calibration
    due date as it was at the run, ``valid_at_run`` and ``days_overdue``).

    Raises
    ------
    LookupError when the run, revision or parameter is not archived.
    """
    check_safe_name(run_id, "run id")
    check_parameter(name)
    if revision is not None and (
        isinstance(revision, bool) or not isinstance(revision, int) or revision < 1
    ):
        raise ValueError(f"revision: expected a whole number >= 1, got {revision!r}")
    with reading(archive) as conn:
        found = conn.execute(
            _LIN_HEAD[revision is None], {"run_id": run_id, "rev": revision or 0, "name": name}
        ).all()
        if not found:
            raise LookupError(f"no run {run_id!r} in the archive")
        head = found[0]
        if head.cal_id is None:
            what = "current revision" if revision is None else f"revision {revision}"
            raise LookupError(f"run {run_id} has no calibration {what}")
        if head.param_id is None:
            raise LookupError(f"run {run_id} revision {head.revision} has no parameter {name!r}")
        raw = conn.execute(_RAW_FILES, {"run": head.run_pk}).all()
        steps = conn.execute(_STEPS_OF, {"cal": head.cal_id}).all()
        equipment = conn.execute(_EQUIPMENT_USED, {"run": head.run_pk}).all()
    started = head.started_at
    return {
        "parameter": {
            "name": name,
            "values": [
                {"value": v.value, "std": v.std, "unit": v.unit, "temperature_c": v.temperature_c}
                for v in found
            ],
        },
        "run": {
            **{k: getattr(head, k) for k in _RUN_COLUMNS[:-2]},  # as the summary's, and:
            "samples_sha256": head.samples_sha256,
            "manifest_text": head.manifest_text,
            "archived_at": head.created_at,
        },
        "device": Unit(head.serial, head.model, head.manufacturer, head.specification).to_dict(),
        "calibration": {
            "calibration_id": head.cal_id,
            "revision": head.revision,
            "current": is_current(head.superseded_by),
            "superseded_by_revision": head.superseding_revision,
            "created_at": head.cal_created_at,
            **_provenance(head),
        },
        "raw_files": [_dict(r) for r in raw],
        "steps": [_dict(s) for s in steps],
        "equipment": [
            {**{k: getattr(e, k) for k in _LIN_EQUIPMENT}, **_validity(started, e.calibration_due)}
            for e in equipment
        ],
    }


def run_samples(archive: Archive, run_id: str) -> pa.Table:
    """The archived samples of one run (SI units).

    Parameters
    ----------
    archive : the archive.
    run_id : the full run id.

    Returns
    -------
    pyarrow Table with columns segment, t (s), acc_x..z (m/s^2), gyr_x..z
    (rad/s), temp (deg C); ``.to_pandas()`` gives a DataFrame.

    Raises
    ------
    LookupError if there is no such run or it has no samples file.
    """
    with Session(archive.engine()) as s:
        run, _ = _run_row(s, run_id)
        rel = run.samples_path
    if not rel:
        raise LookupError(f"run {run_id!r} has no archived samples")
    path = archive.root / rel
    if not path.is_file():
        raise LookupError(f"run {run_id!r}: samples file {path} is missing")
    import pyarrow.parquet as pq

    with pq.ParquetFile(path) as samples:  # not read_table: its dataset layer loads pandas
        return samples.read()


def device_description(archive: Archive, serial: str) -> dict[str, Any] | None:
    """The registered description of a serial (model, manufacturer, specification: as
    its first archived run gave it), or None."""
    with Session(archive.engine()) as s:
        dev = s.scalars(select(Device).where(Device.serial == serial)).one_or_none()
        if dev is None:
            return None
        return {
            "model": dev.model,
            "manufacturer": dev.manufacturer,
            "specification": dev.specification,
        }


def earlier_descriptions(archive: Archive, serial: str, run_id: str) -> list[dict[str, Any]]:
    """How the runs of a serial archived before `run_id` describe the unit.

    Before: all of the serial's runs if `run_id` is not archived yet, else those
    archived earlier (a lower row id), so a reprocessed run is compared as when it
    was first archived, whatever came later.

    Returns
    -------
    One dict per distinct (model, manufacturer), for the latest run by run time that
    gave it (`storage.current.LATEST_RUN_FIRST`), whatever the order they were archived
    in, latest first: run_id, started_at, model, manufacturer, specification.
    Empty for the serial's first run.
    """
    with reading(archive) as conn:
        own = conn.execute(select(Run.id).where(Run.run_id == run_id)).scalar_one_or_none()
        stmt = (
            select(Run.run_id, Run.started_at, Run.model, Run.manufacturer, Run.specification)
            .join(Device, Device.id == Run.device_id)
            .where(Device.serial == serial)
            .order_by(*LATEST_RUN_FIRST)
        )
        if own is not None:
            stmt = stmt.where(Run.id < own)
        out: dict[tuple[str, str], dict[str, Any]] = {}
        for row in conn.execute(stmt):
            out.setdefault((row.model, row.manufacturer), _dict(row))
    return list(out.values())


def repeatability_candidates(
    archive: Archive,
    serial: str,
    procedure: str,
    *,
    before: datetime | None = None,
    exclude_run_id: str | None = None,
    only: Sequence[str] | None = None,
    before_calibration: int | None = None,
) -> list[dict[str, Any]]:
    """Current calibrations of one unit by one procedure, most recent run first
    (storage.current.LATEST_RUN_FIRST).

    Parameters
    ----------
    before : only runs started before this instant (the runs a run started then is
        judged against); None for all.
    exclude_run_id : a run left out.
    only : only these run ids (the group an archived revision records).
    before_calibration : a calibration id: each run's latest revision written before it
        (the archive as that revision saw it) instead of its current one.

    Returns
    -------
    list of dicts: run_id, started_at, environment, calibration_id, verdict, parameters
    (canonical name -> (value, std), SI; parameters at one temperature only).
    """
    stmt = (
        select_run_calibrations(
            Run.run_id,
            Run.started_at,
            Run.environment,
            CalibrationRow.id.label("calibration_id"),
            CalibrationRow.verdict,
        )
        .where(Device.serial == serial, Run.procedure == procedure, _then(before_calibration))
        .order_by(*LATEST_RUN_FIRST)
    )
    if only is not None:
        stmt = stmt.where(Run.run_id.in_(list(only)))
    if before is not None:
        stmt = stmt.where(Run.started_at < before)
    if exclude_run_id is not None:
        stmt = stmt.where(Run.run_id != exclude_run_id)
    with Session(archive.engine()) as s:
        rows = s.execute(stmt).all()
        values = parameter_values(s, [r.calibration_id for r in rows])
    return [{**_dict(row), "parameters": values[row.calibration_id]} for row in rows]


def calibration_revision(archive: Archive, run_id: str, revision: int) -> DatedRevision | None:
    """One revision of a run with its run and unit; None when there is no such revision."""
    with Session(archive.engine()) as s:
        row = s.execute(
            select(Run.run_id, Run.started_at, Device.serial, CalibrationRow)
            .join(Device, Device.id == Run.device_id)
            .join(CalibrationRow, CalibrationRow.run_id == Run.id)
            .where(Run.run_id == run_id, CalibrationRow.revision == revision)
        ).one_or_none()
        if row is None:
            return None
        head = {"run_id": row.run_id, "started_at": row.started_at, "serial": row.serial}
        return revision_record(s, row.CalibrationRow, **head)


def _then(before_calibration: int | None) -> Any:
    """Each run's current revision, or its latest written before `before_calibration`."""
    if before_calibration is None:
        return CURRENT
    older = aliased(CalibrationRow)
    latest = (
        select(func.max(older.id))
        .where(older.run_id == Run.id, older.id < before_calibration)
        .scalar_subquery()
    )
    return CalibrationRow.id == latest


def judgement(archive: Archive, calibration_id: int) -> dict[str, Any]:
    """The checks of one calibration revision as archived, and its ``check`` step.

    Returns
    -------
    dict: ``checks`` (CheckResult, in the order written) and ``check_step`` (settings,
    statistics; None for a revision without that step).
    """
    from calib_core.calibration import CheckResult

    with Session(archive.engine()) as s:
        checks = s.execute(_CHECKS_OF, {"cal": calibration_id}).all()
        step = s.execute(
            select(ProcessingStep.settings, ProcessingStep.statistics).where(
                ProcessingStep.calibration_id == calibration_id, ProcessingStep.name == "check"
            )
        ).first()
    return {
        "checks": [CheckResult(*c) for c in checks],
        "check_step": None if step is None else _dict(step),
    }


def current_judgements(archive: Archive, run_ids: list[str]) -> dict[str, dict[str, Any]]:
    """Verdict and checks of the current revision of each of `run_ids` (those archived).

    Returns
    -------
    run id -> {"verdict": str, "checks": [CheckResult, ...]}.
    """
    from calib_core.calibration import CheckResult

    out: dict[str, dict[str, Any]] = {}
    with Session(archive.engine()) as s:
        for start in range(0, len(run_ids), IN_CHUNK):
            rows = s.execute(
                select(Run.run_id, CalibrationRow.verdict, *CHECK_COLUMNS)
                .join(CalibrationRow, CalibrationRow.run_id == Run.id)
                .outerjoin(CheckResultRow, CheckResultRow.calibration_id == CalibrationRow.id)
                .where(Run.run_id.in_(run_ids[start : start + IN_CHUNK]), CURRENT)
                .order_by(Run.run_id, CheckResultRow.id)
            ).all()
            for r in rows:
                judged = out.setdefault(r.run_id, {"verdict": r.verdict, "checks": []})
                if r.name is not None:
                    judged["checks"].append(
                        CheckResult(r.name, r.value, r.limit, r.passed, r.detail)
                    )
    return out
