"""Read-only questions of the archive browser about fleets and equipment (`calib serve`).

A device model's units with their latest run and latest valid calibration, one
parameter's values over them, equipment with its due dates and the runs made while
its calibration had lapsed. Inputs are validated and bound as in storage.browse.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import ARRAY, Integer, any_, bindparam, func, select

from storage.db import Archive
from storage.queries import check_parameter, check_text
from storage.schema import CalibrationRow, Device, Equipment, ParameterRow, Run, RunEquipment


def models(archive: Archive) -> list[dict[str, Any]]:
    """Device models with their number of units, by model."""
    stmt = (
        select(Device.model, func.count().label("units"))
        .group_by(Device.model)
        .order_by(Device.model)
    )
    with archive.engine().connect() as conn:
        return [dict(r._mapping) for r in conn.execute(stmt).all()]


_IN_CHUNK = 5000  # bound parameters per IN list (SQLite allows 32766, PostgreSQL 65535)


def _among(archive: Archive, column, n: int):  # noqa: ANN001, ANN202
    """(column IN :ids, ids per statement): an expanding IN list on SQLite, one array
    parameter on PostgreSQL (6k separate parameters cost it ~0.1 s of planning)."""
    if archive.is_sqlite:
        return column.in_(bindparam("ids", expanding=True)), _IN_CHUNK
    return column == any_(bindparam("ids", type_=ARRAY(Integer))), max(n, 1)


@dataclass
class Fleet:
    """The units of a device model (storage.browse.model_fleet).

    units : one dict per unit, by serial: serial, runs (count), and of its latest run
        run_id, started_at, verdict, profile_name (current revision).
    valid : calibration id -> (serial, run_id, started_at) of each unit's latest valid
        calibration (current revision, verdict pass), as in storage.queries.fleet.
    """

    units: list[dict[str, Any]]
    valid: dict[int, tuple[str, str, datetime]]


def model_fleet(archive: Archive, model: str) -> Fleet:
    """Every unit of `model` with its latest run and its latest valid calibration.

    One grouped pass over the model's runs (the newest start per unit, on
    ix_runs_device_id_started_at) and one seek per unit for that run; only for units
    whose latest run did not pass, a second grouped pass over their valid runs. 6k
    units / 60k runs in ~0.2 s on SQLite, where fetching every run took ~0.6 s. Of runs
    of one unit with the same start the later archived one counts, as in
    storage.queries.fleet.
    """
    check_text(model, "model")
    current = (CalibrationRow.run_id == Run.id) & CalibrationRow.superseded_by.is_(None)
    newest = (
        select(Run.device_id, func.max(Run.started_at).label("t"), func.count().label("n"))
        .join(Device, Device.id == Run.device_id)
        .where(Device.model == model)
        .group_by(Run.device_id)
        .subquery()
    )
    latest = (
        select(Device.id, Device.serial, newest.c.n, Run.run_id, Run.started_at,
               CalibrationRow.id, CalibrationRow.verdict, CalibrationRow.profile_name)
        .select_from(newest)
        .join(Device, Device.id == newest.c.device_id)
        .join(Run, (Run.device_id == newest.c.device_id) & (Run.started_at == newest.c.t))
        .outerjoin(CalibrationRow, current)
        .order_by(Device.serial, Run.id)
    )  # fmt: skip
    units: dict[str, dict[str, Any]] = {}
    valid: dict[str, tuple[int, str, datetime]] = {}
    with archive.engine().connect() as conn:
        for dev_id, serial, n, run_id, started, cal_id, verdict, profile in conn.execute(latest):
            units[serial] = {"serial": serial, "runs": n, "run_id": run_id,
                             "started_at": started, "verdict": verdict,
                             "profile_name": profile, "_id": dev_id}  # fmt: skip
            if verdict == "pass":
                valid[serial] = (cal_id, run_id, started)  # the later run id wins a tie
            else:
                valid.pop(serial, None)
        rest = [u["_id"] for s, u in units.items() if s not in valid]
        among, chunk = _among(archive, Run.device_id, len(rest))
        for i in range(0, len(rest), chunk):
            for cal_id, serial, run_id, started in conn.execute(
                _older_valid(current, among), {"ids": rest[i:i + chunk]}
            ):
                valid[serial] = (cal_id, run_id, started)
    for u in units.values():
        del u["_id"]
    return Fleet(list(units.values()),
                 {cal: (serial, run_id, t) for serial, (cal, run_id, t) in valid.items()})


def _older_valid(current, among):  # noqa: ANN001, ANN202 - conditions in, a select out
    """Latest valid calibration of the units with ids :ids, by serial and run id."""
    passed = current & (CalibrationRow.verdict == "pass")
    newest_valid = (
        select(Run.device_id, func.max(Run.started_at).label("t"))
        .join(CalibrationRow, passed)
        .where(among)
        .group_by(Run.device_id)
        .subquery()
    )
    return (
        select(CalibrationRow.id, Device.serial, Run.run_id, Run.started_at)
        .select_from(newest_valid)
        .join(Device, Device.id == newest_valid.c.device_id)
        .join(Run, (Run.device_id == newest_valid.c.device_id)
              & (Run.started_at == newest_valid.c.t))
        .join(CalibrationRow, passed)
        .order_by(Device.serial, Run.id)
    )  # fmt: skip




def fleet_values(archive: Archive, fleet: Fleet, name: str) -> list[dict[str, Any]]:
    """Values of parameter `name` in each unit's latest valid calibration, by serial.

    Dicts: serial, run_id, started_at, value, std, unit, temperature_c (SI), the rows
    of storage.queries.fleet.
    """
    check_parameter(name)
    ids = list(fleet.valid)
    among, chunk = _among(archive, ParameterRow.calibration_id, len(ids))
    stmt = select(ParameterRow.calibration_id, ParameterRow.value, ParameterRow.std,
                  ParameterRow.unit, ParameterRow.temperature_c).where(
        ParameterRow.name == name, among)  # fmt: skip
    out = []
    with archive.engine().connect() as conn:
        for i in range(0, len(ids), chunk):
            for cal_id, value, std, unit, temp in conn.execute(stmt, {"ids": ids[i:i + chunk]}):
                serial, run_id, started = fleet.valid[cal_id]
                out.append({"serial": serial, "run_id": run_id, "started_at": started,
                            "value": value, "std": std, "unit": unit, "temperature_c": temp})
    out.sort(key=lambda r: (r["serial"], r["temperature_c"] is None, r["temperature_c"] or 0.0))
    return out


def equipment_list(archive: Archive) -> list[dict[str, Any]]:
    """Every piece of equipment: kind, serial, model, accuracy_class, the latest due date
    recorded with any of its runs (``calibration_due``), the run count and the first and
    last run's start."""
    stmt = (
        select(Equipment.kind, Equipment.serial, Equipment.model, Equipment.accuracy_class,
               func.max(RunEquipment.calibration_due).label("calibration_due"),
               func.count(RunEquipment.id).label("runs"))
        .outerjoin(RunEquipment, RunEquipment.equipment_id == Equipment.id)
        .group_by(Equipment.id, Equipment.kind, Equipment.serial, Equipment.model,
                  Equipment.accuracy_class)
        .order_by(Equipment.kind, Equipment.serial)
    )  # fmt: skip
    with archive.engine().connect() as conn:
        return [dict(r._mapping) for r in conn.execute(stmt).all()]


def equipment_item(archive: Archive, kind: str, serial: str) -> dict[str, Any]:
    """One piece of equipment with its due-date history: the distinct (calibrated_on,
    calibration_due) pairs recorded with its runs, each with its run count and span."""
    check_text(kind, "equipment kind", 100)
    check_text(serial, "equipment serial")
    head = select(Equipment.id, Equipment.kind, Equipment.serial, Equipment.model,
                  Equipment.accuracy_class).where(Equipment.kind == kind,
                                                  Equipment.serial == serial)  # fmt: skip
    with archive.engine().connect() as conn:
        row = conn.execute(head).one_or_none()
        if row is None:
            raise LookupError(f"no equipment {kind} {serial!r} in the archive")
        periods = conn.execute(
            select(RunEquipment.calibrated_on, RunEquipment.calibration_due,
                   func.count().label("runs"), func.min(Run.started_at).label("first_run"),
                   func.max(Run.started_at).label("last_run"))
            .join(Run, Run.id == RunEquipment.run_id)
            .where(RunEquipment.equipment_id == row.id)
            .group_by(RunEquipment.calibrated_on, RunEquipment.calibration_due)
            .order_by(func.min(Run.started_at))
        ).all()  # fmt: skip
    item = dict(row._mapping)
    del item["id"]
    item["periods"] = [dict(p._mapping) for p in periods]
    return item


def lapsed_page(
    archive: Archive, kind: str, serial: str, limit: int = 500
) -> tuple[list[dict[str, Any]], int]:
    """Runs made on one piece of equipment while its calibration had lapsed: the first
    `limit` (oldest first) and how many there are, as storage.queries.lapsed_runs decides
    (the run's UTC start day after the due date recorded with that run).

    Dicts: run_id, serial, started_at, operator, calibration_due, days_overdue.
    """
    check_text(kind, "equipment kind", 100)
    check_text(serial, "equipment serial")
    if archive.is_sqlite:
        day = func.date(Run.started_at)  # SQLite keeps naive UTC text
    else:
        day = func.date(func.timezone("UTC", Run.started_at))
    where = (Equipment.kind == kind, Equipment.serial == serial,
             RunEquipment.calibration_due.is_not(None), day > RunEquipment.calibration_due)
    base = (select(Run.run_id, Device.serial, Run.started_at, Run.operator,
                   RunEquipment.calibration_due)
            .select_from(Equipment)
            .join(RunEquipment, RunEquipment.equipment_id == Equipment.id)
            .join(Run, Run.id == RunEquipment.run_id)
            .join(Device, Device.id == Run.device_id)
            .where(*where))  # fmt: skip
    counted = (select(func.count()).select_from(Equipment)
               .join(RunEquipment, RunEquipment.equipment_id == Equipment.id)
               .join(Run, Run.id == RunEquipment.run_id).where(*where))  # fmt: skip
    with archive.engine().connect() as conn:
        total = conn.execute(counted).scalar_one()
        rows = conn.execute(base.order_by(Run.started_at, Run.id).limit(limit)).all()
    out = [dict(r._mapping) for r in rows]
    for r in out:
        r["days_overdue"] = (r["started_at"].astimezone(UTC).date() - r["calibration_due"]).days
    return out, total
