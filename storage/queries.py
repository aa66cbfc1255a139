"""Questions asked of the archive, answered as dicts and pandas DataFrames.

Every untrusted input (serial, run id, parameter name, date) is a bound
parameter of a SQLAlchemy statement, never part of a SQL string.

"Valid" calibration, as used by `latest_calibration` and `parameter_history`:
the current revision of a run (``superseded_by IS NULL``) whose verdict is
"pass". Of several such runs the one that started last wins. Supersession is
taken as it is now, not as it was at `as_of` (the archive answers "which run
started before D holds the calibration we trust today").
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

import pandas as pd
from sqlalchemy import Row, select
from sqlalchemy.orm import Session

from storage.db import Archive
from storage.schema import (
    CalibrationRow,
    CheckResultRow,
    Device,
    Equipment,
    ParameterRow,
    ProcessingStep,
    RawFile,
    Run,
    RunEquipment,
)

PASS = "pass"


def _dict(row: Row) -> dict[str, Any]:
    return dict(row._mapping)


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
        stmt = stmt.where(CalibrationRow.superseded_by.is_(None))
    else:
        stmt = stmt.where(CalibrationRow.revision == revision)
    cal = s.execute(stmt).scalar_one_or_none()
    if cal is None:
        raise LookupError(f"run has no calibration revision {revision}")
    return cal


def _cal_dict(s: Session, cal: CalibrationRow) -> dict[str, Any]:
    params = s.execute(
        select(
            ParameterRow.name,
            ParameterRow.value,
            ParameterRow.std,
            ParameterRow.unit,
            ParameterRow.temperature_c,
        )
        .where(ParameterRow.calibration_id == cal.id)
        .order_by(ParameterRow.name, ParameterRow.temperature_c)
    ).all()
    checks = s.execute(
        select(
            CheckResultRow.name,
            CheckResultRow.value,
            CheckResultRow.limit,
            CheckResultRow.passed,
            CheckResultRow.detail,
        )
        .where(CheckResultRow.calibration_id == cal.id)
        .order_by(CheckResultRow.id)
    ).all()
    steps = s.execute(
        select(
            ProcessingStep.seq,
            ProcessingStep.name,
            ProcessingStep.settings,
            ProcessingStep.statistics,
            ProcessingStep.software_version,
            ProcessingStep.source_revision,
        )
        .where(ProcessingStep.calibration_id == cal.id)
        .order_by(ProcessingStep.seq)
    ).all()
    return {
        "calibration_id": cal.id,
        "revision": cal.revision,
        "created_at": cal.created_at,
        "settings_hash": cal.settings_hash,
        "settings": cal.settings,
        "software_version": cal.software_version,
        "source_revision": cal.source_revision,
        "verdict": cal.verdict,
        "profile_name": cal.profile_name,
        "profile_version": cal.profile_version,
        "superseded_by": cal.superseded_by,
        "parameters": [_dict(p) for p in params],
        "checks": [_dict(c) for c in checks],
        "steps": [_dict(s) for s in steps],
        "document": cal.document,
    }


def _device_dict(dev: Device) -> dict[str, Any]:
    return {
        "serial": dev.serial,
        "model": dev.model,
        "manufacturer": dev.manufacturer,
        "specification": dev.specification,
    }


def run_summary(archive: Archive, run_id: str) -> dict[str, Any]:
    """Everything about one run and its current calibration revision.

    Returns
    -------
    dict with the run's fields, ``device``, ``equipment`` (with the due dates
    valid at run time), ``raw_files``, ``revisions`` (count) and
    ``calibration`` (current revision: parameters, checks, steps, document).
    Raises LookupError if there is no such run.
    """
    with Session(archive.engine()) as s:
        run, dev = _run_row(s, run_id)
        raw = s.execute(
            select(RawFile.name, RawFile.sha256, RawFile.size, RawFile.format, RawFile.stored_path)
            .where(RawFile.run_id == run.id)
            .order_by(RawFile.name)
        ).all()
        equipment = s.execute(
            select(
                Equipment.kind,
                Equipment.model,
                Equipment.serial,
                Equipment.accuracy_class,
                RunEquipment.calibration_due,
                RunEquipment.calibrated_on,
            )
            .join(RunEquipment, RunEquipment.equipment_id == Equipment.id)
            .where(RunEquipment.run_id == run.id)
            .order_by(Equipment.kind, Equipment.serial)
        ).all()
        revisions = s.execute(
            select(CalibrationRow.revision).where(CalibrationRow.run_id == run.id)
        ).all()
        cal = _cal_dict(s, _calibration(s, run.id, None))
    return {
        "run_id": run.run_id,
        "started_at": run.started_at,
        "operator": run.operator,
        "procedure": run.procedure,
        "site": run.site,
        "gravity": run.gravity,
        "environment": run.environment,
        "tolerance_profile": run.tolerance_profile,
        "raw_hash": run.raw_hash,
        "run_dir": run.run_dir,
        "samples_path": run.samples_path,
        "manifest_text": run.manifest_text,
        "created_at": run.created_at,
        "device": _device_dict(dev),
        "equipment": [_dict(e) for e in equipment],
        "raw_files": [_dict(r) for r in raw],
        "revisions": len(revisions),
        "calibration": cal,
    }


def history(archive: Archive, serial: str) -> pd.DataFrame:
    """One row per calibration revision of a unit, oldest run first.

    Columns: run_id, started_at, procedure, revision, verdict, superseded,
    software_version, created_at.
    """
    stmt = (
        select(
            Run.run_id,
            Run.started_at,
            Run.procedure,
            CalibrationRow.revision,
            CalibrationRow.verdict,
            CalibrationRow.superseded_by.is_not(None).label("superseded"),
            CalibrationRow.software_version,
            CalibrationRow.created_at,
        )
        .join(Device, Device.id == Run.device_id)
        .join(CalibrationRow, CalibrationRow.run_id == Run.id)
        .where(Device.serial == serial)
        .order_by(Run.started_at, Run.id, CalibrationRow.revision)
    )
    columns = [
        "run_id",
        "started_at",
        "procedure",
        "revision",
        "verdict",
        "superseded",
        "software_version",
        "created_at",
    ]
    with Session(archive.engine()) as s:
        df = pd.DataFrame(s.execute(stmt).all(), columns=columns)
    return df.astype({"superseded": bool})


def parameter_history(
    archive: Archive, serial: str, name: str, *, include_superseded: bool = False
) -> pd.DataFrame:
    """Values of one parameter of a unit over its runs, oldest first.

    Only current revisions unless `include_superseded`. Columns: run_id,
    started_at, revision, verdict, value, std, unit, temperature_c.
    """
    stmt = (
        select(
            Run.run_id,
            Run.started_at,
            CalibrationRow.revision,
            CalibrationRow.verdict,
            ParameterRow.value,
            ParameterRow.std,
            ParameterRow.unit,
            ParameterRow.temperature_c,
        )
        .join(Device, Device.id == Run.device_id)
        .join(CalibrationRow, CalibrationRow.run_id == Run.id)
        .join(ParameterRow, ParameterRow.calibration_id == CalibrationRow.id)
        .where(Device.serial == serial, ParameterRow.name == name)
        .order_by(Run.started_at, Run.id, CalibrationRow.revision, ParameterRow.temperature_c)
    )
    if not include_superseded:
        stmt = stmt.where(CalibrationRow.superseded_by.is_(None))
    columns = [
        "run_id",
        "started_at",
        "revision",
        "verdict",
        "value",
        "std",
        "unit",
        "temperature_c",
    ]
    with Session(archive.engine()) as s:
        return pd.DataFrame(s.execute(stmt).all(), columns=columns)


def latest_calibration(
    archive: Archive, serial: str, as_of: datetime | None = None
) -> dict[str, Any] | None:
    """The latest valid calibration of a unit from a run started at or before `as_of`.

    Valid: current revision (not superseded) with verdict "pass" (module
    docstring). `as_of` must be time zone aware; None means now.

    Returns
    -------
    None if there is none, else a dict: run_id, started_at, serial and the
    calibration fields as in `run_summary` (parameters, checks, steps, document).
    """
    if as_of is not None and as_of.utcoffset() is None:
        raise ValueError(f"as_of: expected a time-zone-aware datetime, got {as_of!r}")
    stmt = (
        select(Run.run_id, Run.started_at, CalibrationRow)
        .join(Device, Device.id == Run.device_id)
        .join(CalibrationRow, CalibrationRow.run_id == Run.id)
        .where(
            Device.serial == serial,
            CalibrationRow.superseded_by.is_(None),
            CalibrationRow.verdict == PASS,
        )
        .order_by(Run.started_at.desc(), Run.id.desc())
        .limit(1)
    )
    if as_of is not None:
        stmt = stmt.where(Run.started_at <= as_of)
    with Session(archive.engine()) as s:
        row = s.execute(stmt).one_or_none()
        if row is None:
            return None
        return {
            "run_id": row.run_id,
            "started_at": row.started_at,
            "serial": serial,
            **_cal_dict(s, row.CalibrationRow),
        }


def export_calibration(
    archive: Archive, run_id: str, revision: int | None = None
) -> dict[str, Any]:
    """The calibration JSON document of a run with the unit and run metadata.

    Parameters
    ----------
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
        "unit": {"serial": dev.serial, "model": dev.model, "manufacturer": dev.manufacturer},
        "run": {
            "run_id": run.run_id,
            "started_at": run.started_at.isoformat(),
            "procedure": run.procedure,
            "gravity": run.gravity,
            "raw_hash": run.raw_hash,
        },
        "revision": cal.revision,
        "superseded": cal.superseded_by is not None,
        "software_version": cal.software_version,
        "source_revision": cal.source_revision,
        "settings_hash": cal.settings_hash,
        "verdict": cal.verdict,
        "profile": {"name": cal.profile_name, "version": cal.profile_version},
        "calibration": cal.document,
    }
