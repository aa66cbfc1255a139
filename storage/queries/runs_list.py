"""Queries of the archive about many runs at once: the runs list (filters, sort, pages),
the values its filters offer, the archive's size.

Every filter is validated here (ValueError naming the filter, what was expected
and what was found) and bound; sort keys are looked up in a fixed table, so no
request string ever becomes SQL text.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import date, datetime
from typing import Any

from sqlalchemy import func, select

from storage.current import CURRENT
from storage.db import Archive
from storage.queries._common import as_instant, check_serial, check_text, check_verdict, reading
from storage.schema import CalibrationRow, Device, Run

SORTS = {
    "started": Run.started_at,
    "serial": Device.serial,
    "model": Device.model,
    "procedure": Run.procedure,
    "operator": Run.operator,
    "verdict": CalibrationRow.verdict,
    "run": Run.run_id,
}
PER_PAGE = (10, 25, 50, 100, 200)
MAX_PAGE = 100_000


@dataclass(frozen=True)
class RunFilter:
    """Validated filters of the runs list (None: not filtered). Build with `run_filter`."""

    serial: str | None = None
    model: str | None = None
    date_from: datetime | None = None
    date_to: datetime | None = None
    procedure: str | None = None
    verdict: str | None = None
    env_temp_min: float | None = None
    env_temp_max: float | None = None


def _opt_float(text: str | None, what: str) -> float | None:
    if text is None or text == "":
        return None
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{what}: expected a number (deg C), got {text!r}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise ValueError(f"{what}: expected a finite number, got {text!r}")
    return value


def run_filter(
    *,
    serial: str | None = None,
    model: str | None = None,
    date_from: str | date | None = None,
    date_to: str | date | None = None,
    procedure: str | None = None,
    verdict: str | None = None,
    env_temp_min: str | float | None = None,
    env_temp_max: str | float | None = None,
) -> RunFilter:
    """Validate the runs-list filters (empty strings mean "not filtered").

    Dates are whole UTC days or ISO 8601 date-times with a zone (storage.queries.as_instant);
    temperatures are the run environment's lab temperature, deg C, inclusive.
    """
    blank = lambda v: v is None or v == ""  # noqa: E731
    t0 = None if blank(date_from) else as_instant(date_from, "from", end_of_day=False)
    t1 = None if blank(date_to) else as_instant(date_to, "to", end_of_day=True)
    if t0 is not None and t1 is not None and t0 > t1:
        raise ValueError(f"date range: from {t0.date()} is after to {t1.date()}")
    lo = env_temp_min if isinstance(env_temp_min, float) else _opt_float(env_temp_min, "temp_min")
    hi = env_temp_max if isinstance(env_temp_max, float) else _opt_float(env_temp_max, "temp_max")
    if lo is not None and hi is not None and lo > hi:
        raise ValueError(f"temperature range: min {lo} is above max {hi}")
    return RunFilter(
        serial=None if blank(serial) else check_serial(serial),
        model=None if blank(model) else check_text(model, "model"),
        date_from=t0,
        date_to=t1,
        procedure=None if blank(procedure) else check_text(procedure, "procedure", 100),
        verdict=None if blank(verdict) else check_verdict(verdict),
        env_temp_min=lo,
        env_temp_max=hi,
    )


@dataclass
class RunsPage:
    """One page of the runs list: rows (dicts) and the total matching the filters."""

    rows: list[dict[str, Any]]
    total: int
    page: int
    per_page: int
    pages: int = field(init=False)

    def __post_init__(self) -> None:
        self.pages = max(1, -(-self.total // self.per_page))


def _filtered(stmt, f: RunFilter):  # noqa: ANN001, ANN202 - a select in, a select out
    temp = Run.environment["temperature_c"].as_float()
    conditions = [
        (f.serial, lambda v: Device.serial == v),
        (f.model, lambda v: Device.model == v),
        (f.date_from, lambda v: Run.started_at >= v),
        (f.date_to, lambda v: Run.started_at <= v),
        (f.procedure, lambda v: Run.procedure == v),
        (f.verdict, lambda v: CalibrationRow.verdict == v),
        (f.env_temp_min, lambda v: temp >= v),
        (f.env_temp_max, lambda v: temp <= v),
    ]
    for value, condition in conditions:
        if value is not None:
            stmt = stmt.where(condition(value))
    return stmt


def _count_base(f: RunFilter):  # noqa: ANN202 - a select
    """COUNT of current revisions, joining runs and devices only when a filter needs them
    (the count dominates the page, and the joins dominate the count)."""
    stmt = select(func.count()).select_from(CalibrationRow).where(CURRENT)
    device = f.serial is not None or f.model is not None
    run = device or any(
        v is not None for v in (f.date_from, f.date_to, f.procedure, f.env_temp_min, f.env_temp_max)
    )
    if run:
        stmt = stmt.join(Run, Run.id == CalibrationRow.run_id)
    if device:
        stmt = stmt.join(Device, Device.id == Run.device_id)
    return stmt


def runs_page(
    archive: Archive,
    f: RunFilter,
    *,
    sort: str = "started",
    descending: bool = True,
    page: int = 1,
    per_page: int = 50,
) -> RunsPage:
    """One page of runs (current revision of each) matching `f`, sorted by a key of SORTS.

    Rows: run_id, started_at, serial, model, procedure, operator, temperature_c,
    revision, verdict.
    """
    if sort not in SORTS:
        raise ValueError(f"sort: expected one of {', '.join(SORTS)}, got {sort!r}")
    if per_page not in PER_PAGE:
        raise ValueError(f"per_page: expected one of {PER_PAGE}, got {per_page!r}")
    if not 1 <= page <= MAX_PAGE:
        raise ValueError(f"page: expected 1..{MAX_PAGE}, got {page!r}")
    key = SORTS[sort]
    order = [key.desc() if descending else key.asc()]
    if sort != "started":
        order.append(Run.started_at.desc())
    order.append(Run.id.desc() if descending else Run.id.asc())
    base = (
        select(
            Run.run_id,
            Run.started_at,
            Device.serial,
            Device.model,
            Run.procedure,
            Run.operator,
            Run.environment["temperature_c"].as_float().label("temperature_c"),
            CalibrationRow.revision,
            CalibrationRow.verdict,
        )
        .join(Device, Device.id == Run.device_id)
        .join(CalibrationRow, (CalibrationRow.run_id == Run.id) & CURRENT)
    )
    stmt = _filtered(base, f)
    counted = _filtered(_count_base(f), f)
    with reading(archive) as conn:
        total = conn.execute(counted).scalar_one()
        rows = conn.execute(
            stmt.order_by(*order).limit(per_page).offset((page - 1) * per_page)
        ).all()
    return RunsPage([dict(r._mapping) for r in rows], total, page, per_page)


def choices(archive: Archive) -> dict[str, list[str]]:
    """Values the runs filters offer: device models and procedures in the archive."""
    with reading(archive) as conn:
        models = conn.execute(select(Device.model).distinct().order_by(Device.model)).scalars()
        procs = conn.execute(select(Run.procedure).distinct().order_by(Run.procedure)).scalars()
        return {"models": list(models), "procedures": list(procs)}


def facts(archive: Archive) -> dict[str, Any]:
    """The archive's size and schema: runs, units, schema_revision."""
    with reading(archive) as conn:
        out = {
            "runs": conn.execute(select(func.count()).select_from(Run)).scalar_one(),
            "units": conn.execute(select(func.count()).select_from(Device)).scalar_one(),
        }
    return {**out, "schema_revision": archive.schema_revision()}
