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

import math
from datetime import UTC, date, datetime, time
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
from sqlalchemy import Row, bindparam, func, select
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, aliased

from calib_core import params
from storage.db import Archive
from storage.naming import check_safe_name
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


HISTORY_COLUMNS = ["run_id", "started_at", "revision", "verdict", "value", "std", "unit",
                   "temperature_c"]  # fmt: skip


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
    with Session(archive.engine()) as s:
        return pd.DataFrame(s.execute(stmt).all(), columns=HISTORY_COLUMNS)


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


# --- issue 9: traceability, equipment validity, units, fleet -------------------------
#
# The functions below validate their filters (a clear ValueError naming the
# filter) before any SQL runs, and bind every value. Dates given as `date` mean
# whole UTC days: `as_of`/`date_to` include the whole day, `date_from` starts at
# its midnight.

VERDICTS = ("pass", "fail", "needs review")  # calib_core.verification.overall_verdict
EQUIPMENT_SERIAL_LEN = 200


def check_serial(serial: str) -> str:
    """A unit serial as the archive stores it (storage.naming rules), else ValueError."""
    return check_safe_name(serial, "serial")


def check_parameter(name: str) -> str:
    """A canonical parameter name (calib_core.params), else ValueError naming it."""
    if not isinstance(name, str):
        raise ValueError(f"parameter: expected a canonical name like 'acc.bias.x', got {name!r}")
    return params.validate(name)


def check_verdict(verdict: str) -> str:
    if verdict not in VERDICTS:
        raise ValueError(f"verdict: expected one of {', '.join(VERDICTS)}, got {verdict!r}")
    return verdict


def check_text(value: str, what: str, max_len: int = 200) -> str:
    """A free-text filter (model, equipment serial): non-empty printable, bounded length."""
    if not isinstance(value, str) or not value or len(value) > max_len or not value.isprintable():
        raise ValueError(f"{what}: expected 1-{max_len} printable characters, got {value!r}")
    return value


def as_instant(
    value: date | datetime | str | None, what: str, *, end_of_day: bool
) -> datetime | None:
    """A time-zone-aware UTC instant from a date, an aware datetime or ISO 8601 text.

    A bare date (``2024-05-01``) means the start of that UTC day, or with
    `end_of_day` its last microsecond, so ``--to 2024-05-01`` includes the day.
    """
    if value is None:
        return None
    if isinstance(value, str):
        text_ = value.strip()
        try:
            value = (
                date.fromisoformat(text_)
                if len(text_) == 10
                else datetime.fromisoformat(text_.replace("Z", "+00:00"))
            )
        except ValueError:
            raise ValueError(
                f"{what}: expected a date YYYY-MM-DD or a date-time with a zone "
                f"(2024-05-01T08:30:00+00:00), got {value!r}"
            ) from None
    if isinstance(value, datetime):
        if value.utcoffset() is None:
            raise ValueError(f"{what}: {value.isoformat()} has no time zone (add +00:00 or Z)")
        return value.astimezone(UTC)
    if isinstance(value, date):
        t = datetime.combine(value, time.max if end_of_day else time.min, tzinfo=UTC)
        return t
    raise ValueError(f"{what}: expected a date or datetime, got {type(value).__name__}")


def _finite(value: float | None, what: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{what}: expected a finite number, got {value!r}")
    return float(value)


def _run_day(dialect: str):  # noqa: ANN202 - a SQL expression
    """The UTC calendar day a run started, as a SQL date on either back end."""
    if dialect == "postgresql":
        return func.date(func.timezone("UTC", Run.started_at))
    return func.date(Run.started_at)  # SQLite keeps naive UTC text


def _frame(rows: list[Row | tuple], columns: list[str]) -> pd.DataFrame:
    return pd.DataFrame.from_records([tuple(r) for r in rows], columns=columns)


LATEST_COLUMNS = [
    "serial",
    "run_id",
    "started_at",
    "revision",
    "calibration_id",
    "software_version",
    "name",
    "value",
    "std",
    "unit",
    "temperature_c",
]


# Statements built once: building a select costs more than running it on an index.
_FOREVER = datetime(9999, 12, 31, tzinfo=UTC)
_LATEST_PICK = (
    select(CalibrationRow.id)
    .join(Run, Run.id == CalibrationRow.run_id)
    .join(Device, Device.id == Run.device_id)
    .where(
        Device.serial == bindparam("serial"),
        CalibrationRow.superseded_by.is_(None),
        CalibrationRow.verdict == PASS,
        Run.started_at <= bindparam("at", type_=Run.started_at.type),
    )
    .order_by(Run.started_at.desc(), Run.id.desc())
    .limit(1)
    .scalar_subquery()
)
# One statement, one round trip: the pick runs once (an uncorrelated subquery).
_LATEST = (
    select(Run.run_id, Run.started_at, CalibrationRow.revision, CalibrationRow.id,
           CalibrationRow.software_version, ParameterRow.name, ParameterRow.value,
           ParameterRow.std, ParameterRow.unit, ParameterRow.temperature_c)
    .select_from(ParameterRow)
    .join(CalibrationRow, CalibrationRow.id == ParameterRow.calibration_id)
    .join(Run, Run.id == CalibrationRow.run_id)
    .where(ParameterRow.calibration_id == _LATEST_PICK)
    .order_by(ParameterRow.name, ParameterRow.temperature_c)
)  # fmt: skip


def latest_valid(
    archive: Archive, serial: str, as_of: date | datetime | str | None = None
) -> pd.DataFrame:
    """Parameters of the latest valid calibration of a unit as of a date.

    Valid as in `latest_calibration` (current revision, verdict "pass"); the
    run must have started at or before `as_of` (a date includes that whole
    UTC day; None: now).

    Returns
    -------
    DataFrame with LATEST_COLUMNS, one row per parameter value; empty if the
    unit has no valid calibration by then.
    """
    check_serial(serial)
    at = as_instant(as_of, "as_of", end_of_day=True) or _FOREVER
    with archive.engine().connect() as conn:
        rows = conn.execute(_LATEST, {"serial": serial, "at": at}).all()
    return _frame([(serial, *r) for r in rows], LATEST_COLUMNS)


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
    chosen = (
        CalibrationRow.superseded_by.is_(None)
        if current
        else CalibrationRow.revision == bindparam("rev")
    )
    return (
        select(
            Run.id.label("run_pk"), Run.run_id, Run.started_at, Run.operator, Run.procedure,
            Run.site, Run.gravity, Run.environment, Run.tolerance_profile, Run.raw_hash,
            Run.run_dir, Run.samples_path, Run.samples_sha256, Run.manifest_text, Run.created_at,
            Device.serial, Device.model, Device.manufacturer, Device.specification,
            CalibrationRow.id.label("cal_id"), CalibrationRow.revision,
            CalibrationRow.superseded_by, CalibrationRow.created_at.label("cal_created_at"),
            CalibrationRow.settings_hash, CalibrationRow.settings,
            CalibrationRow.software_version, CalibrationRow.source_revision,
            CalibrationRow.verdict, CalibrationRow.profile_name, CalibrationRow.profile_version,
            _NEWER.revision.label("superseding_revision"),
            ParameterRow.id.label("param_id"), ParameterRow.value, ParameterRow.std,
            ParameterRow.unit, ParameterRow.temperature_c,
        )
        .join(Device, Device.id == Run.device_id)
        .outerjoin(CalibrationRow, (CalibrationRow.run_id == Run.id) & chosen)
        .outerjoin(_NEWER, _NEWER.id == CalibrationRow.superseded_by)
        .outerjoin(
            ParameterRow,
            (ParameterRow.calibration_id == CalibrationRow.id)
            & (ParameterRow.name == bindparam("name")),
        )
        .where(Run.run_id == bindparam("run_id"))
        .order_by(ParameterRow.temperature_c)
    )  # fmt: skip


_LIN_HEAD = {True: _lineage_head(True), False: _lineage_head(False)}
_LIN_RAW = (
    select(RawFile.name, RawFile.sha256, RawFile.size, RawFile.format, RawFile.stored_path)
    .where(RawFile.run_id == bindparam("run"))
    .order_by(RawFile.name)
)
_LIN_STEPS = (
    select(ProcessingStep.seq, ProcessingStep.name, ProcessingStep.settings,
           ProcessingStep.statistics, ProcessingStep.software_version,
           ProcessingStep.source_revision)
    .where(ProcessingStep.calibration_id == bindparam("cal"))
    .order_by(ProcessingStep.seq)
)  # fmt: skip
_LIN_EQUIPMENT = (
    select(Equipment.kind, Equipment.serial, Equipment.model, Equipment.accuracy_class,
           RunEquipment.calibrated_on, RunEquipment.calibration_due)
    .join(RunEquipment, RunEquipment.equipment_id == Equipment.id)
    .where(RunEquipment.run_id == bindparam("run"))
    .order_by(Equipment.kind, Equipment.serial)
)  # fmt: skip


def lineage(
    archive: Archive, run_id: str, name: str, revision: int | None = None
) -> dict[str, Any]:
    """Where one archived parameter value comes from.

    Parameters
    ----------
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
    if revision is not None and (isinstance(revision, bool) or not isinstance(revision, int)
                                 or revision < 1):  # fmt: skip
        raise ValueError(f"revision: expected a whole number >= 1, got {revision!r}")
    with archive.engine().connect() as conn:
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
        raw = conn.execute(_LIN_RAW, {"run": head.run_pk}).all()
        steps = conn.execute(_LIN_STEPS, {"cal": head.cal_id}).all()
        equipment = conn.execute(_LIN_EQUIPMENT, {"run": head.run_pk}).all()
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
            "run_id": head.run_id,
            "started_at": started,
            "operator": head.operator,
            "procedure": head.procedure,
            "site": head.site,
            "gravity": head.gravity,
            "environment": head.environment,
            "tolerance_profile": head.tolerance_profile,
            "raw_hash": head.raw_hash,
            "run_dir": head.run_dir,
            "samples_path": head.samples_path,
            "samples_sha256": head.samples_sha256,
            "manifest_text": head.manifest_text,
            "archived_at": head.created_at,
        },
        "device": {
            "serial": head.serial,
            "model": head.model,
            "manufacturer": head.manufacturer,
            "specification": head.specification,
        },
        "calibration": {
            "calibration_id": head.cal_id,
            "revision": head.revision,
            "current": head.superseded_by is None,
            "superseded_by_revision": head.superseding_revision,
            "created_at": head.cal_created_at,
            "settings_hash": head.settings_hash,
            "settings": head.settings,
            "software_version": head.software_version,
            "source_revision": head.source_revision,
            "verdict": head.verdict,
            "profile_name": head.profile_name,
            "profile_version": head.profile_version,
        },
        "raw_files": [_dict(r) for r in raw],
        "steps": [_dict(s) for s in steps],
        "equipment": [{**_dict(e), **_validity(started, e.calibration_due)} for e in equipment],
    }


LAPSED_COLUMNS = [
    "equipment_kind",
    "equipment_serial",
    "run_id",
    "serial",
    "started_at",
    "operator",
    "calibration_due",
    "days_overdue",
]


def lapsed_runs(archive: Archive, equipment_serial: str, kind: str | None = None) -> pd.DataFrame:
    """Runs made on a piece of equipment while its own calibration had lapsed.

    Lapsed: the run started (UTC day) after the equipment's calibration due
    date as recorded with that run (`run_equipment`), i.e. the due date is the
    last valid day. Runs without a recorded due date are not listed (unknown).

    Parameters
    ----------
    equipment_serial : the equipment's serial (all kinds with this serial
        unless `kind` is given).
    kind : "rate_table", "centrifuge", "chamber", "daq"...

    Returns
    -------
    DataFrame with LAPSED_COLUMNS, oldest run first; days_overdue >= 1.
    """
    check_text(equipment_serial, "equipment serial", EQUIPMENT_SERIAL_LEN)
    day = _run_day(make_url(archive.url).get_backend_name())
    stmt = (
        select(Equipment.kind, Equipment.serial, Run.run_id, Device.serial, Run.started_at,
               Run.operator, RunEquipment.calibration_due)
        .join(RunEquipment, RunEquipment.equipment_id == Equipment.id)
        .join(Run, Run.id == RunEquipment.run_id)
        .join(Device, Device.id == Run.device_id)
        .where(
            Equipment.serial == equipment_serial,
            RunEquipment.calibration_due.is_not(None),
            day > RunEquipment.calibration_due,
        )
        .order_by(Run.started_at, Run.id)
    )  # fmt: skip
    if kind is not None:
        stmt = stmt.where(Equipment.kind == check_text(kind, "equipment kind", 100))
    with archive.engine().connect() as conn:
        rows = conn.execute(stmt).all()
    df = _frame(rows, LAPSED_COLUMNS[:-1])
    df["days_overdue"] = [
        (t.astimezone(UTC).date() - due).days
        for t, due in zip(df["started_at"], df["calibration_due"], strict=True)
    ]
    return df.astype({"days_overdue": "int64"})


UNIT_COLUMNS = [
    "serial",
    "model",
    "manufacturer",
    "run_id",
    "started_at",
    "procedure",
    "operator",
    "revision",
    "verdict",
    "env_temperature_c",
]


def units(
    archive: Archive,
    *,
    model: str | None = None,
    date_from: date | datetime | str | None = None,
    date_to: date | datetime | str | None = None,
    verdict: str | None = None,
    env_temp_min: float | None = None,
    env_temp_max: float | None = None,
) -> pd.DataFrame:
    """Calibrated units: one row per run (its current revision) matching every filter.

    Parameters
    ----------
    model : device model, exact.
    date_from, date_to : run start, inclusive (dates are whole UTC days).
    verdict : "pass" or "fail" of the current revision.
    env_temp_min, env_temp_max : lab temperature of the run's environment, deg C,
        inclusive; runs without a recorded temperature are left out when either is given.

    Returns
    -------
    DataFrame with UNIT_COLUMNS, by start time.
    """
    t0 = as_instant(date_from, "date_from", end_of_day=False)
    t1 = as_instant(date_to, "date_to", end_of_day=True)
    if t0 is not None and t1 is not None and t0 > t1:
        raise ValueError(f"date range: from {t0.isoformat()} is after to {t1.isoformat()}")
    lo = _finite(env_temp_min, "env_temp_min")
    hi = _finite(env_temp_max, "env_temp_max")
    if lo is not None and hi is not None and lo > hi:
        raise ValueError(f"temperature range: min {lo} is above max {hi}")
    temp = Run.environment["temperature_c"].as_float()
    stmt = (
        select(Device.serial, Device.model, Device.manufacturer, Run.run_id, Run.started_at,
               Run.procedure, Run.operator, CalibrationRow.revision, CalibrationRow.verdict,
               temp)
        .join(Device, Device.id == Run.device_id)
        .join(CalibrationRow, CalibrationRow.run_id == Run.id)
        .where(CalibrationRow.superseded_by.is_(None))
        .order_by(Run.started_at, Run.id)
    )  # fmt: skip
    if model is not None:
        stmt = stmt.where(Device.model == check_text(model, "model"))
    if t0 is not None:
        stmt = stmt.where(Run.started_at >= t0)
    if t1 is not None:
        stmt = stmt.where(Run.started_at <= t1)
    if verdict is not None:
        stmt = stmt.where(CalibrationRow.verdict == check_verdict(verdict))
    if lo is not None:
        stmt = stmt.where(temp >= lo)
    if hi is not None:
        stmt = stmt.where(temp <= hi)
    with archive.engine().connect() as conn:
        return _frame(conn.execute(stmt).all(), UNIT_COLUMNS)


def serial_parameter_history(
    archive: Archive, serial: str, name: str, *, include_superseded: bool = False
) -> pd.DataFrame:
    """`parameter_history` with validated inputs (CLI `calib query history`)."""
    return parameter_history(
        archive, check_serial(serial), check_parameter(name), include_superseded=include_superseded
    )


# Per unit of the model, its latest valid calibration picked by a correlated subquery
# on ix_runs_device_id_started_at (a few index steps per unit), then the parameter by
# ix_parameters_calibration_id_name: the cost grows with the units, not the 5M rows.
_FLEET_DEVICE = aliased(Device)
_FLEET_PICK = (
    select(CalibrationRow.id)
    .join(Run, Run.id == CalibrationRow.run_id)
    .where(
        Run.device_id == _FLEET_DEVICE.id,
        CalibrationRow.superseded_by.is_(None),
        CalibrationRow.verdict == PASS,
        Run.started_at <= bindparam("at", type_=Run.started_at.type),
    )
    .order_by(Run.started_at.desc(), Run.id.desc())
    .limit(1)
    .correlate(_FLEET_DEVICE)
    .scalar_subquery()
)
_FLEET = (
    select(_FLEET_DEVICE.serial, Run.run_id, Run.started_at, ParameterRow.value,
           ParameterRow.std, ParameterRow.unit, ParameterRow.temperature_c)
    .select_from(_FLEET_DEVICE)
    .join(CalibrationRow, CalibrationRow.id == _FLEET_PICK)
    .join(Run, Run.id == CalibrationRow.run_id)
    .join(
        ParameterRow,
        (ParameterRow.calibration_id == CalibrationRow.id)
        & (ParameterRow.name == bindparam("name")),
    )
    .where(_FLEET_DEVICE.model == bindparam("model"))
    .order_by(_FLEET_DEVICE.serial, ParameterRow.temperature_c)
)  # fmt: skip


FLEET_COLUMNS = ["serial", "run_id", "started_at", "value", "std", "unit", "temperature_c"]


def fleet(
    archive: Archive, model: str, name: str, as_of: date | datetime | str | None = None
) -> pd.DataFrame:
    """Fleet distribution of a parameter: its value in each unit's latest valid calibration.

    One row per unit of `model` that has a valid calibration (current revision,
    verdict "pass") from a run started at or before `as_of` (None: now), with
    that calibration's value(s) of `name` (several rows for a unit when the value
    is temperature-dependent).

    Returns
    -------
    DataFrame with FLEET_COLUMNS, by serial.
    """
    check_text(model, "model")
    check_parameter(name)
    at = as_instant(as_of, "as_of", end_of_day=True) or _FOREVER
    with archive.engine().connect() as conn:
        rows = conn.execute(_FLEET, {"model": model, "name": name, "at": at}).all()
    return _frame(rows, FLEET_COLUMNS)


def run_samples(archive: Archive, run_id: str) -> pa.Table:
    """The archived samples of one run (segment, t, acc_*, gyr_*, temp; SI units).

    Raises LookupError if there is no such run or it has no samples file.
    """
    with Session(archive.engine()) as s:
        run, _ = _run_row(s, run_id)
        rel = run.samples_path
    if not rel:
        raise LookupError(f"run {run_id!r} has no archived samples")
    path = archive.root / rel
    if not path.is_file():
        raise LookupError(f"run {run_id!r}: samples file {path} is missing")
    return pq.read_table(path)


def repeatability_candidates(
    archive: Archive, serial: str, procedure: str, *, exclude_run_id: str | None = None
) -> list[dict[str, Any]]:
    """Current calibrations of one unit by one procedure, most recent run first.

    Returns
    -------
    list of dicts: run_id, started_at, environment, verdict, parameters
    (canonical name -> (value, std), SI; parameters at one temperature only).
    """
    stmt = (
        select(
            Run.run_id, Run.started_at, Run.environment, CalibrationRow.id, CalibrationRow.verdict
        )
        .join(Device, Device.id == Run.device_id)
        .join(CalibrationRow, CalibrationRow.run_id == Run.id)
        .where(
            Device.serial == serial,
            Run.procedure == procedure,
            CalibrationRow.superseded_by.is_(None),
        )
        .order_by(Run.started_at.desc(), Run.id.desc())
    )
    if exclude_run_id is not None:
        stmt = stmt.where(Run.run_id != exclude_run_id)
    out = []
    with Session(archive.engine()) as s:
        for row in s.execute(stmt).all():
            values = s.execute(
                select(ParameterRow.name, ParameterRow.value, ParameterRow.std).where(
                    ParameterRow.calibration_id == row.id
                )
            ).all()
            out.append(
                {
                    "run_id": row.run_id,
                    "started_at": row.started_at,
                    "environment": row.environment,
                    "verdict": row.verdict,
                    "parameters": {v.name: (v.value, v.std) for v in values},
                }
            )
    return out
