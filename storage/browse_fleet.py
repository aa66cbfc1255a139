"""Read-only questions of the archive browser about fleets and equipment (`calib serve`).

A device model's units by their latest run and one parameter's values over their latest
valid calibrations (as storage.queries.fleet), equipment with its due dates and the runs
made while its calibration had lapsed. Inputs are validated and bound as in storage.browse.
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from dataclasses import dataclass
from datetime import UTC
from typing import Any

from sqlalchemy import Integer, Select, bindparam, func, or_, select, true
from sqlalchemy.orm import aliased

from storage.db import Archive
from storage.queries import check_parameter, check_text
from storage.queries._common import _FOREVER, PASS
from storage.queries.history import FLEET_DEVICE, FLEET_PICK
from storage.schema import CalibrationRow, Device, Equipment, ParameterRow, Run, RunEquipment

REFERENCE_C = 20.0  # of temperature-dependent values, the one nearest this (deg C)


def models(archive: Archive) -> list[dict[str, Any]]:
    """Device models with their number of units, by model."""
    stmt = (
        select(Device.model, func.count().label("units"))
        .group_by(Device.model)
        .order_by(Device.model)
    )
    with archive.engine().connect() as conn:
        return [dict(r._mapping) for r in conn.execute(stmt).all()]


FAILING_MAX = 200


@dataclass
class FleetUnits:
    """The units of a device model as their latest runs leave them (`fleet_units`).

    units : number of units of the model.
    latest : verdict of each unit's latest run (current revision; None: no calibration)
        -> number of units.
    profiles : tolerance profile name of those calibrations -> number of units.
    failing : the first `FAILING_MAX` units, by serial, whose latest run did not pass:
        serial, run_id, started_at, verdict, runs (the unit's run count).
    """

    units: int
    latest: dict[str | None, int]
    profiles: dict[str, int]
    failing: list[dict[str, Any]]

    @property
    def n_failing(self) -> int:
        return sum(n for v, n in self.latest.items() if v != PASS)


def _per_unit(sqlite: bool, dev, pick: Select):  # noqa: ANN001, ANN202
    """The units of model :model (`dev`, an aliased Device) with the one id `pick` selects
    for each (a LIMIT 1 select correlated to `dev`): a subquery of (serial, device_id,
    pick). Where `pick` finds nothing it is NULL (SQLite) or the unit is left out
    (PostgreSQL).

    SQLite evaluates a correlated scalar subquery once per unit here; PostgreSQL plans
    the same scalar subquery in a join condition as a hash join over every row of the
    picked table (0.9 s for 6k units), so there it is a LATERAL join (one index walk per
    unit, as on SQLite).
    """
    model = dev.model == bindparam("model")
    if sqlite:
        one = pick.correlate(dev).scalar_subquery()
        stmt = select(dev.serial, dev.id.label("device_id"), one.label("pick")).where(model)
    else:
        one = pick.correlate(dev).lateral("one")
        stmt = (select(dev.serial, dev.id.label("device_id"), one.c[0].label("pick"))
                .select_from(dev).join(one, true()).where(model))  # fmt: skip
    return stmt.subquery("per_unit")


@functools.cache
def _fleet_statements(sqlite: bool) -> tuple[Select, Select, Select]:
    """(verdict and profile counts, failing units, values) of a fleet, with bound :model,
    :n (failing units listed), :name and :at; built once per back end (building a select
    costs more than running it, and a fresh alias would miss the compiled cache)."""
    dev = aliased(Device)
    latest_run = (select(Run.id).where(Run.device_id == dev.id)
                  .order_by(Run.started_at.desc(), Run.id.desc()).limit(1))  # fmt: skip
    units = _per_unit(sqlite, dev, latest_run)
    current = (CalibrationRow.run_id == units.c.pick) & CalibrationRow.superseded_by.is_(None)
    base = (select().select_from(units).outerjoin(CalibrationRow, current)
            .where(units.c.pick.is_not(None)))  # a unit without runs has no latest run
    grouped = base.add_columns(CalibrationRow.verdict, CalibrationRow.profile_name,
                               func.count()).group_by(CalibrationRow.verdict,
                                                      CalibrationRow.profile_name)  # fmt: skip
    other = aliased(Run)
    runs = (select(func.count()).select_from(other).where(other.device_id == units.c.device_id)
            .correlate(units).scalar_subquery())  # fmt: skip
    failing = (
        base.add_columns(units.c.serial, Run.run_id, Run.started_at, CalibrationRow.verdict,
                         runs.label("runs"))
        .join(Run, Run.id == units.c.pick)
        .where(or_(CalibrationRow.verdict.is_(None), CalibrationRow.verdict != PASS))
        .order_by(units.c.serial).limit(bindparam("n", type_=Integer))
    )  # fmt: skip
    valid = _per_unit(sqlite, FLEET_DEVICE, FLEET_PICK.element)
    values = (
        select(valid.c.serial, ParameterRow.calibration_id, ParameterRow.value,
               ParameterRow.temperature_c)
        .join(ParameterRow, (ParameterRow.calibration_id == valid.c.pick)
              & (ParameterRow.name == bindparam("name")))
    )  # fmt: skip
    return grouped, failing, values


def fleet_units(archive: Archive, model: str, failing_max: int = FAILING_MAX) -> FleetUnits:
    """Every unit of `model` by its latest run: verdict and profile counts, failing units.

    Each unit's latest run is one backward step on ix_runs_device_id_started_at_id (the
    later archived of runs with the same start, as in storage.queries.fleet), its current
    revision one step on ix_calibrations_current; the counts are grouped in the
    database, so no per-unit row reaches Python but the listed failing ones.
    """
    check_text(model, "model")
    grouped, failing, _ = _fleet_statements(archive.is_sqlite)
    latest: Counter[str | None] = Counter()
    profiles: Counter[str] = Counter()
    with archive.engine().connect() as conn:
        for verdict, profile, n in conn.execute(grouped, {"model": model}):
            latest[verdict] += n
            if profile:
                profiles[profile] += n
        rows = (conn.execute(failing, {"model": model, "n": failing_max}).all()
                if latest.keys() - {PASS} else [])  # fmt: skip
    return FleetUnits(sum(latest.values()), dict(latest), dict(profiles),
                      [dict(r._mapping) for r in rows])


def fleet_values(archive: Archive, model: str, name: str) -> list[dict[str, Any]]:
    """Per unit of `model`, parameter `name` in its latest valid calibration: the value
    nearest REFERENCE_C when temperature-dependent (the lower of two as near), by serial.

    The units and calibrations of storage.queries.fleet (its pick, FLEET_PICK), read
    lean: serial, calibration id, value and temperature per row, 6k units without a date
    to convert each; `fleet_lineage` adds the run of the few rows a page lists.
    Dicts: serial, calibration_id, value (SI), temperature_c.
    """
    check_text(model, "model")
    check_parameter(name)
    values = _fleet_statements(archive.is_sqlite)[2]
    best: dict[str, tuple[tuple[float, float], tuple]] = {}
    with archive.engine().connect() as conn:
        for row in conn.execute(values, {"model": model, "name": name, "at": _FOREVER}):
            t = row[3]
            key = (0.0, 0.0) if t is None or math.isnan(t) else (abs(t - REFERENCE_C), t)
            old = best.get(row[0])
            if old is None or key < old[0]:
                best[row[0]] = (key, row)
    keys = ("serial", "calibration_id", "value", "temperature_c")
    return [dict(zip(keys, best[s][1], strict=True)) for s in sorted(best)]


def fleet_lineage(archive: Archive, rows: list[dict[str, Any]]) -> None:
    """Add run_id and started_at of its calibration to each of `rows` (fleet_values)."""
    ids = sorted({r["calibration_id"] for r in rows})
    stmt = (select(CalibrationRow.id, Run.run_id, Run.started_at)
            .join(Run, Run.id == CalibrationRow.run_id)
            .where(CalibrationRow.id.in_(ids)))  # fmt: skip
    with archive.engine().connect() as conn:
        runs = {cal: (run_id, t) for cal, run_id, t in conn.execute(stmt)} if ids else {}
    for r in rows:
        r["run_id"], r["started_at"] = runs[r["calibration_id"]]


def equipment_list(archive: Archive) -> list[dict[str, Any]]:
    """Every piece of equipment: kind, serial, model, accuracy_class, the latest due date
    recorded with any of its runs (``calibration_due``) and the run count.

    Both per piece from ix_run_equipment_equipment_id_calibration_due alone (its last
    entry; its entries counted), not by grouping the run_equipment rows."""
    due = (select(func.max(RunEquipment.calibration_due))
           .where(RunEquipment.equipment_id == Equipment.id).scalar_subquery())  # fmt: skip
    runs = (select(func.count()).select_from(RunEquipment)
            .where(RunEquipment.equipment_id == Equipment.id).scalar_subquery())  # fmt: skip
    stmt = (
        select(Equipment.kind, Equipment.serial, Equipment.model, Equipment.accuracy_class,
               due.label("calibration_due"), runs.label("runs"))
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
