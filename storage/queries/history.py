"""Queries of the archive about units over time: latest (valid) calibration, units,
fleets and their history (a unit's revisions: `storage.queries.unit_history`).

"Current" and "valid" calibration, and which is a unit's latest: the one rule of
storage.current (a current revision with verdict "pass"; of several such runs the one
that started last wins; supersession taken as it is now, also at `as_of`).
"""

from __future__ import annotations

from datetime import date, datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import bindparam, select
from sqlalchemy.orm import Session, aliased

from storage.current import CURRENT, LATEST_FIRST, VALID, latest_valid_pick
from storage.db import Archive
from storage.queries._common import (
    _FOREVER,
    NAMED_PARAMETER,
    PARAMETER_VALUE,
    _finite,
    _frame,
    as_instant,
    check_parameter,
    check_serial,
    check_text,
    check_verdict,
    reading,
    select_run_calibrations,
    where_model_and_start,
)
from storage.schema import (
    CalibrationRow,
    Device,
    ParameterRow,
    Run,
)

if TYPE_CHECKING:
    import pandas as pd  # imported where a frame is made (slow to import)
    from sqlalchemy import Row

    from storage.queries.records import DatedRevision


HISTORY_COLUMNS = [
    "run_id",
    "started_at",
    "revision",
    "verdict",
    "value",
    "std",
    "unit",
    "temperature_c",
]


def _parameter_over_runs(  # noqa: ANN202 - a select
    name: str | list[str], include_superseded: bool, *lead: Any
):
    """Rows of parameter `name` (or of each of several names) over runs (`lead` columns,
    then device serial first), oldest run first; the callers add which devices."""
    one = isinstance(name, str)
    stmt = (
        select_run_calibrations(
            *lead,
            Device.serial,
            Run.run_id,
            Run.started_at,
            CalibrationRow.revision,
            CalibrationRow.verdict,
            *PARAMETER_VALUE,
        )
        .join(ParameterRow, ParameterRow.calibration_id == CalibrationRow.id)
        .where(ParameterRow.name == name if one else ParameterRow.name.in_(name))
        .order_by(Run.started_at, Run.id, CalibrationRow.revision, ParameterRow.temperature_c)
    )
    if not one:  # rows of one run, revision and temperature: by name
        stmt = stmt.order_by(ParameterRow.name)
    if not include_superseded:
        stmt = stmt.where(CURRENT)
    return stmt


def parameter_history(
    archive: Archive, serial: str, name: str, *, include_superseded: bool = False
) -> pd.DataFrame:
    """Values of one parameter of a unit over its runs, oldest first (inputs validated).

    Parameters
    ----------
    archive : the archive.
    serial : the unit.
    name : canonical parameter name, e.g. ``gyr.bias.x``.
    include_superseded : also the revisions replaced by a reprocessing.

    Returns
    -------
    DataFrame with HISTORY_COLUMNS: run_id, started_at, revision, verdict,
    value, std, unit (SI), temperature_c.
    """
    import pandas as pd

    stmt = _parameter_over_runs(check_parameter(name), include_superseded)
    stmt = stmt.where(Device.serial == check_serial(serial))
    with reading(archive) as conn:
        rows = [r[1:] for r in conn.execute(stmt)]
    return pd.DataFrame(rows, columns=HISTORY_COLUMNS)


# The CLI's name of the same question (`calib query history`).
serial_parameter_history = parameter_history


def fleet_history(archive: Archive, model: str, name: str) -> pd.DataFrame:
    """One parameter over every unit of a device model (current revisions), oldest first.

    Columns: serial, then HISTORY_COLUMNS.
    """
    import pandas as pd

    stmt = _parameter_over_runs(check_parameter(name), include_superseded=False)
    stmt = stmt.where(Device.model == check_text(model, "model"))
    with reading(archive) as conn:
        return pd.DataFrame(conn.execute(stmt).all(), columns=["serial", *HISTORY_COLUMNS])


FLEET_HISTORY_COLUMNS = ["name", "serial", *HISTORY_COLUMNS]


def fleet_histories(archive: Archive, model: str, names: list[str]) -> list[Row]:
    """Several parameters over every unit of a device model (current revisions) in one
    question, without pandas (a unit's recalibration interval: pipelines.recall).

    Returns
    -------
    Rows with the attributes of FLEET_HISTORY_COLUMNS (name, serial, then those of
    `fleet_history`), oldest run first; one parameter's rows in the order of
    `fleet_history` of that parameter.
    """
    if not names:
        return []
    wanted = sorted({check_parameter(n) for n in names})
    stmt = _parameter_over_runs(wanted, False, ParameterRow.name.label("name"))
    stmt = stmt.where(Device.model == check_text(model, "model"))
    with reading(archive) as conn:
        return list(conn.execute(stmt).all())


def latest_calibration(
    archive: Archive, serial: str, as_of: datetime | None = None
) -> DatedRevision | None:
    """The latest valid calibration of a unit from a run started at or before `as_of`.

    Valid: current revision (not superseded) with verdict "pass" (module
    docstring).

    Parameters
    ----------
    archive : the archive.
    serial : the unit.
    as_of : time-zone-aware date and time; None for now.

    Returns
    -------
    None if there is none, else a DatedRevision (storage.queries.records): run_id,
    started_at, serial and the revision (parameters, checks, steps, document).
    """
    if as_of is not None and as_of.utcoffset() is None:
        raise ValueError(f"as_of: expected a time-zone-aware datetime, got {as_of!r}")
    stmt = (
        select_run_calibrations(Run.run_id, Run.started_at, CalibrationRow)
        .where(Device.serial == serial, VALID)
        .order_by(*LATEST_FIRST)
        .limit(1)
    )
    if as_of is not None:
        stmt = stmt.where(Run.started_at <= as_of)
    from storage.queries.runs import revision_record  # here: `calib history` needs no run questions

    with Session(archive.engine()) as s:
        row = s.execute(stmt).one_or_none()
        if row is None:
            return None
        head = {"run_id": row.run_id, "started_at": row.started_at, "serial": serial}
        return revision_record(s, row.CalibrationRow, **head)


def latest_run(archive: Archive, serial: str) -> dict[str, Any] | None:
    """A unit's latest run with its current revision, of any verdict (storage.current:
    latest by run start, the later archived among equal starts).

    Returns
    -------
    None if the unit has no run, else a dict: run_id, started_at, procedure, revision,
    verdict.
    """
    check_serial(serial)
    stmt = (
        select_run_calibrations(
            Run.run_id, Run.started_at, Run.procedure, CalibrationRow.revision,
            CalibrationRow.verdict,
        )
        .where(Device.serial == serial, CURRENT)
        .order_by(*LATEST_FIRST)
        .limit(1)
    )  # fmt: skip
    with reading(archive) as conn:
        row = conn.execute(stmt).one_or_none()
    return None if row is None else dict(row._mapping)


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
_LATEST_PICK = (
    latest_valid_pick(Run.started_at <= bindparam("at", type_=Run.started_at.type))
    .join(Device, Device.id == Run.device_id)
    .where(Device.serial == bindparam("serial"))
    .scalar_subquery()
)
# One statement, one round trip: the pick runs once (an uncorrelated subquery).
_LATEST = (
    select(Run.run_id, Run.started_at, CalibrationRow.revision, CalibrationRow.id,
           CalibrationRow.software_version, ParameterRow.name, *PARAMETER_VALUE)
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
    with reading(archive) as conn:
        rows = conn.execute(_LATEST, {"serial": serial, "at": at}).all()
    return _frame([(serial, *r) for r in rows], LATEST_COLUMNS)


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
    frame: bool = True,
) -> pd.DataFrame | list[tuple]:
    """Calibrated units: one row per run (its current revision) matching every filter.

    Each row's model and manufacturer are the run's own (what its manifest said);
    `model` filters by the unit's registered model (the one its serial was first
    archived under), so a unit stays in one fleet even when a run misnames it (that
    run fails its ``device:description`` check).

    Parameters
    ----------
    archive : the archive.
    model : the units' registered device model, exact.
    date_from, date_to : run start, inclusive (dates are whole UTC days).
    verdict : "pass" or "fail" of the current revision.
    env_temp_min, env_temp_max : lab temperature of the run's environment, deg C,
        inclusive; runs without a recorded temperature are left out when either is given.
    frame : False for the rows as tuples (no pandas: pipelines.recall).

    Returns
    -------
    DataFrame with UNIT_COLUMNS (tuples of them when not `frame`), by start time.
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
        select_run_calibrations(
            Device.serial,
            Run.model,
            Run.manufacturer,
            Run.run_id,
            Run.started_at,
            Run.procedure,
            Run.operator,
            CalibrationRow.revision,
            CalibrationRow.verdict,
            temp,
        )
        .where(CURRENT)
        .order_by(Run.started_at, Run.id)
    )
    stmt = where_model_and_start(stmt, model, t0, t1)
    if verdict is not None:
        stmt = stmt.where(CalibrationRow.verdict == check_verdict(verdict))
    if lo is not None:
        stmt = stmt.where(temp >= lo)
    if hi is not None:
        stmt = stmt.where(temp <= hi)
    with reading(archive) as conn:
        rows = [tuple(r) for r in conn.execute(stmt).all()]
    return _frame(rows, UNIT_COLUMNS) if frame else rows


# Per unit of the model, its latest valid calibration picked by a correlated subquery
# on ix_runs_device_id_started_at_id (a few index steps per unit), then the parameter by
# ix_parameters_calibration_id_name: the cost grows with the units, not the 5M rows.
FLEET_DEVICE = aliased(Device)
FLEET_PICK = (
    latest_valid_pick(
        Run.device_id == FLEET_DEVICE.id,
        Run.started_at <= bindparam("at", type_=Run.started_at.type),
    )
    .correlate(FLEET_DEVICE)
    .scalar_subquery()
)
_FLEET = (
    select(FLEET_DEVICE.serial, Run.run_id, Run.started_at, *PARAMETER_VALUE)
    .select_from(FLEET_DEVICE)
    .join(CalibrationRow, CalibrationRow.id == FLEET_PICK)
    .join(Run, Run.id == CalibrationRow.run_id)
    .join(ParameterRow, NAMED_PARAMETER)
    .where(FLEET_DEVICE.model == bindparam("model"))
    .order_by(FLEET_DEVICE.serial, ParameterRow.temperature_c)
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

    Parameters
    ----------
    archive : the archive.
    model : device model, exact.
    name : canonical parameter name.
    as_of : date or time of validity; None for now.

    Returns
    -------
    DataFrame with FLEET_COLUMNS, by serial.
    """
    check_text(model, "model")
    check_parameter(name)
    at = as_instant(as_of, "as_of", end_of_day=True) or _FOREVER
    with reading(archive) as conn:
        rows = conn.execute(_FLEET, {"model": model, "name": name, "at": at}).all()
    return _frame(rows, FLEET_COLUMNS)
