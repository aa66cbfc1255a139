"""Read-only questions of the archive browser about fleets and equipment (`calib serve`).

A device model's units by their latest run and one parameter's values over their latest
valid calibrations (as storage.queries.fleet), equipment with its due dates and the runs
made while its calibration had lapsed. Inputs are validated and bound as in storage.browse.
"""

from __future__ import annotations

import functools
from collections import Counter
from dataclasses import dataclass
from datetime import UTC
from typing import Any

from sqlalchemy import Integer, Select, bindparam, func, or_, select
from sqlalchemy.orm import aliased

from storage import unit_latest
from storage.db import Archive
from storage.queries import check_parameter, check_text
from storage.queries._common import PASS
from storage.schema import (
    CalibrationRow,
    Device,
    Equipment,
    Run,
    RunEquipment,
    UnitLatest,
    UnitLatestValue,
)

REFERENCE_C = unit_latest.REFERENCE_C  # of temperature-dependent values, the one nearest


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


@functools.cache
def _fleet_statements() -> tuple[Select, Select]:
    """(verdict and profile counts, failing units) of a fleet, with bound :model and
    :n (failing units listed); built once (building a select costs more than
    running it). Each unit's latest run, its current revision and the unit's latest
    valid calibration, with the latest run's verdict and profile, are its row of
    unit_latest (storage.unit_latest, kept by the archive's writes): one key lookup per
    unit instead of a walk of its runs."""
    units = (select().select_from(Device)
             .join(UnitLatest, UnitLatest.device_id == Device.id)  # units with a run
             .where(Device.model == bindparam("model")))  # fmt: skip
    grouped = units.add_columns(UnitLatest.verdict, UnitLatest.profile_name,
                                func.count()).group_by(UnitLatest.verdict,
                                                       UnitLatest.profile_name)  # fmt: skip
    other = aliased(Run)
    runs = (select(func.count()).select_from(other).where(other.device_id == Device.id)
            .correlate(Device).scalar_subquery())  # fmt: skip
    failing = (
        units.add_columns(Device.serial, Run.run_id, Run.started_at, UnitLatest.verdict,
                          runs.label("runs"))
        .join(Run, Run.id == UnitLatest.run_id)
        .where(or_(UnitLatest.verdict.is_(None), UnitLatest.verdict != PASS))
        .order_by(Device.serial).limit(bindparam("n", type_=Integer))
    )  # fmt: skip
    return grouped, failing


def fleet_units(archive: Archive, model: str, failing_max: int = FAILING_MAX) -> FleetUnits:
    """Every unit of `model` by its latest run: verdict and profile counts, failing units.

    Each unit's latest run (the later archived of runs with the same start, as in
    storage.queries.fleet) and its current revision's verdict and profile are the unit's
    row of unit_latest;
    the counts are grouped in the database, so no per-unit row reaches Python but the
    listed failing ones.
    """
    check_text(model, "model")
    grouped, failing = _fleet_statements()
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


_FLEET_VALUES = (
    select(UnitLatestValue.serial, UnitLatestValue.calibration_id, UnitLatestValue.value,
           UnitLatestValue.temperature_c)
    .join(UnitLatest, unit_latest.LIVE)
    .where(UnitLatestValue.model == bindparam("model"), UnitLatestValue.name == bindparam("name"))
    .order_by(UnitLatestValue.serial)
)  # fmt: skip


def fleet_values(archive: Archive, model: str, name: str) -> list[dict[str, Any]]:
    """Per unit of `model`, parameter `name` in its latest valid calibration: the value
    nearest REFERENCE_C when temperature-dependent (the lower of two as near), by serial.

    The units and calibrations of storage.queries.fleet (its pick, FLEET_PICK, as of
    now), one value each, as unit_latest_values keeps them (storage.unit_latest): one
    range of its key, in serial order, each row checked against its unit's latest
    valid calibration (unit_latest.LIVE); `fleet_lineage` adds the run of the few rows a
    page lists. Dicts: serial, calibration_id, value (SI), temperature_c.
    """
    check_text(model, "model")
    check_parameter(name)
    with archive.engine().connect() as conn:  # fetched at once (per-row fetches cost more)
        rows = conn.execute(_FLEET_VALUES, {"model": model, "name": name}).all()
    return [{"serial": s, "calibration_id": c, "value": v, "temperature_c": t}
            for s, c, v, t in rows]  # fmt: skip


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
    stmt = (select(Run.run_id, Device.serial, Run.started_at, Run.operator,
                   RunEquipment.calibration_due, func.count().over().label("total"))
            .select_from(Equipment)
            .join(RunEquipment, RunEquipment.equipment_id == Equipment.id)
            .join(Run, Run.id == RunEquipment.run_id)
            .join(Device, Device.id == Run.device_id)
            .where(*where)
            .order_by(Run.started_at, Run.id).limit(limit))  # fmt: skip
    with archive.engine().connect() as conn:  # counted in the same pass (before the LIMIT)
        rows = conn.execute(stmt).all()
    total = rows[0].total if rows else 0
    out = [dict(r._mapping) for r in rows]
    for r in out:
        del r["total"]
        r["days_overdue"] = (r["started_at"].astimezone(UTC).date() - r["calibration_due"]).days
    return out, total
