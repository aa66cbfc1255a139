"""Queries of the archive about a device model's fleet as the archive browser shows it:
models, a model's units by their latest run, one parameter's values over their latest
valid calibrations (the derived tables of storage.unit_latest, by the one rule of
storage.current, as `fleet` and `latest_valid` pick them).
"""

from __future__ import annotations

import functools
from collections import Counter
from dataclasses import dataclass
from typing import Any

from sqlalchemy import Integer, Select, bindparam, func, or_, select
from sqlalchemy.orm import aliased

from storage import unit_latest
from storage.current import PASS
from storage.db import Archive
from storage.queries._common import check_parameter, check_text, reading
from storage.schema import CalibrationRow, Device, Run, UnitLatest, UnitLatestValue

REFERENCE_C = unit_latest.REFERENCE_C  # of temperature-dependent values, the one nearest


def models(archive: Archive) -> list[dict[str, Any]]:
    """Device models with their number of units, by model."""
    stmt = (
        select(Device.model, func.count().label("units"))
        .group_by(Device.model)
        .order_by(Device.model)
    )
    with reading(archive) as conn:
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
    units = (
        select()
        .select_from(Device)
        .join(UnitLatest, UnitLatest.device_id == Device.id)  # units with a run
        .where(Device.model == bindparam("model"))
    )
    grouped = units.add_columns(UnitLatest.verdict, UnitLatest.profile_name, func.count()).group_by(
        UnitLatest.verdict, UnitLatest.profile_name
    )
    other = aliased(Run)
    runs = (
        select(func.count())
        .select_from(other)
        .where(other.device_id == Device.id)
        .correlate(Device)
        .scalar_subquery()
    )
    failing = (
        units.add_columns(
            Device.serial, Run.run_id, Run.started_at, UnitLatest.verdict, runs.label("runs")
        )
        .join(Run, Run.id == UnitLatest.run_id)
        .where(or_(UnitLatest.verdict.is_(None), UnitLatest.verdict != PASS))
        .order_by(Device.serial)
        .limit(bindparam("n", type_=Integer))
    )
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
    with reading(archive) as conn:
        for verdict, profile, n in conn.execute(grouped, {"model": model}):
            latest[verdict] += n
            if profile:
                profiles[profile] += n
        rows = (
            conn.execute(failing, {"model": model, "n": failing_max}).all()
            if latest.keys() - {PASS}
            else []
        )
    return FleetUnits(
        sum(latest.values()), dict(latest), dict(profiles), [dict(r._mapping) for r in rows]
    )


@functools.cache
def _latest_valid_runs() -> Select:
    """Each unit of the bound :model with a valid calibration: its latest valid one's run
    (unit_latest's pick, by the rule of storage.current), by serial."""
    return (
        select(Device.serial, Run.run_id, Run.started_at)
        .select_from(Device)
        .join(UnitLatest, UnitLatest.device_id == Device.id)
        .join(CalibrationRow, CalibrationRow.id == UnitLatest.valid_calibration_id)
        .join(Run, Run.id == CalibrationRow.run_id)
        .where(Device.model == bindparam("model"))
        .order_by(Device.serial)
    )


def fleet_latest_valid(archive: Archive, model: str) -> list[dict[str, Any]]:
    """The units of `model` (registered model) that have a valid calibration, by serial:
    serial, run_id and started_at of each one's latest valid calibration."""
    check_text(model, "model")
    with reading(archive) as conn:
        return [dict(r._mapping) for r in conn.execute(_latest_valid_runs(), {"model": model})]


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
    with reading(archive) as conn:  # fetched at once (per-row fetches cost more)
        rows = conn.execute(_FLEET_VALUES, {"model": model, "name": name}).all()
    return [
        {"serial": s, "calibration_id": c, "value": v, "temperature_c": t} for s, c, v, t in rows
    ]


def fleet_lineage(archive: Archive, rows: list[dict[str, Any]]) -> None:
    """Add run_id and started_at of its calibration to each of `rows` (fleet_values)."""
    ids = sorted({r["calibration_id"] for r in rows})
    stmt = (
        select(CalibrationRow.id, Run.run_id, Run.started_at)
        .join(Run, Run.id == CalibrationRow.run_id)
        .where(CalibrationRow.id.in_(ids))
    )
    with reading(archive) as conn:
        runs = {cal: (run_id, t) for cal, run_id, t in conn.execute(stmt)} if ids else {}
    for r in rows:
        r["run_id"], r["started_at"] = runs[r["calibration_id"]]
