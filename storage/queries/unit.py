"""Queries of the archive about one unit as the archive browser shows it: its device
row, every parameter value of its current revisions, its current thermal model; and the
revisions of one of its runs.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import bindparam, select

from storage.current import CURRENT, current
from storage.db import Archive
from storage.naming import check_safe_name
from storage.queries._common import check_serial, reading
from storage.schema import CalibrationRow, Device, ParameterRow, Run, ThermalModelRow

_NEWER = CalibrationRow.__table__.alias("newer")


def revisions(archive: Archive, run_id: str) -> list[dict[str, Any]]:
    """Every calibration revision of a run, oldest first (LookupError if no such run).

    Dicts: revision, created_at, verdict, software_version, source_revision,
    settings_hash, profile_name, profile_version, superseded_by_revision.
    """
    check_safe_name(run_id, "run id")
    stmt = (
        select(
            CalibrationRow.revision,
            CalibrationRow.created_at,
            CalibrationRow.verdict,
            CalibrationRow.software_version,
            CalibrationRow.source_revision,
            CalibrationRow.settings_hash,
            CalibrationRow.profile_name,
            CalibrationRow.profile_version,
            _NEWER.c.revision.label("superseded_by_revision"),
        )
        .join(Run, Run.id == CalibrationRow.run_id)
        .outerjoin(_NEWER, _NEWER.c.id == CalibrationRow.superseded_by)
        .where(Run.run_id == run_id)
        .order_by(CalibrationRow.revision)
    )
    with reading(archive) as conn:
        rows = conn.execute(stmt).all()
    if not rows:
        raise LookupError(f"no run {run_id!r} in the archive")
    return [dict(r._mapping) for r in rows]


def device(archive: Archive, serial: str) -> dict[str, Any]:
    """A unit's device row: serial, model, manufacturer, specification (LookupError if none)."""
    check_serial(serial)
    stmt = select(
        Device.serial, Device.model, Device.manufacturer, Device.specification, Device.created_at
    ).where(Device.serial == serial)
    with reading(archive) as conn:
        row = conn.execute(stmt).one_or_none()
    if row is None:
        raise LookupError(f"no unit with serial {serial!r} in the archive")
    return dict(row._mapping)


# Built once (a select costs more to build than to run on its index), bound per unit.
_UNIT_PARAMETERS = (
    select(Run.run_id, Run.started_at,
           Run.environment["temperature_c"].as_float().label("env_temperature_c"),
           CalibrationRow.revision, CalibrationRow.verdict,
           CalibrationRow.profile_name, ParameterRow.name, ParameterRow.value,
           ParameterRow.std, ParameterRow.unit, ParameterRow.temperature_c)
    .join(Device, Device.id == Run.device_id)
    .join(CalibrationRow, (CalibrationRow.run_id == Run.id)
          & CURRENT)
    .join(ParameterRow, ParameterRow.calibration_id == CalibrationRow.id)
    .where(Device.serial == bindparam("serial"))
    .order_by(Run.started_at, Run.id, ParameterRow.name, ParameterRow.temperature_c)
)  # fmt: skip


def unit_parameters(archive: Archive, serial: str) -> list[dict[str, Any]]:
    """Every parameter value of a unit's current revisions, by run start then name.

    Dicts: run_id, started_at, env_temperature_c (the run's lab temperature),
    revision, verdict, profile_name, name, value, std, unit, temperature_c (SI).
    One query for the unit's whole history.
    """
    check_serial(serial)
    with reading(archive) as conn:
        return [dict(r._mapping) for r in conn.execute(_UNIT_PARAMETERS, {"serial": serial})]


_THERMAL_MODEL = (
    select(ThermalModelRow.id, ThermalModelRow.created_at, ThermalModelRow.t_ref,
           ThermalModelRow.t_min, ThermalModelRow.t_max, ThermalModelRow.document,
           ThermalModelRow.calibration_ids)
    .join(Device, Device.id == ThermalModelRow.device_id)
    .where(Device.serial == bindparam("serial"), current(ThermalModelRow))
    .order_by(ThermalModelRow.id.desc())
    .limit(1)
)  # fmt: skip


def thermal_model(archive: Archive, serial: str) -> dict[str, Any] | None:
    """The current thermal model of a unit (id, created_at, t_ref, t_min, t_max, document)."""
    check_serial(serial)
    with reading(archive) as conn:
        row = conn.execute(_THERMAL_MODEL, {"serial": serial}).one_or_none()
    return None if row is None else dict(row._mapping)
