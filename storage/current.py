"""Which calibration is current: the one rule of the archive's read side.

- a run's current revision: the one no later revision supersedes
  (``superseded_by IS NULL``);
- a valid calibration: a current revision with verdict "pass";
- a unit's latest run, and its latest valid calibration: by run start, the later
  archived run (larger id) among equal starts; of two current revisions of one run (a
  broken archive, which `calib verify` reports) the later one.

Supersession is taken as it is now, also for an `as_of` question (the archive answers
"which run started before D holds the calibration we trust today"). The questions of
storage.queries (the CLI, the web pages) and the derived tables (storage.unit_latest,
which the fleet page reads and verify checks) build their picks from these, so they
cannot disagree. The rule is written once, as `current` (a SQL condition on any form of
the calibrations table: mapped, aliased, light) and `is_current` (on a row read); the
mapped forms below are built from them on first use, so a reader of light table
clauses (storage.queries.unit_history) uses the rule without the mapped tables.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING, Any

from sqlalchemy import ColumnElement, Select, select

if TYPE_CHECKING:
    from sqlalchemy.sql.elements import UnaryExpression

PASS = "pass"


def current(calibrations: Any) -> ColumnElement[bool]:
    """The current revisions of a calibrations table (its mapped class, an alias or a
    light `table` clause with the column ``superseded_by``)."""
    return _columns(calibrations).superseded_by.is_(None)


def superseded(calibrations: Any) -> ColumnElement[bool]:
    """The revisions a later one supersedes: not `current`."""
    return _columns(calibrations).superseded_by.is_not(None)


def is_current(superseded_by: int | None) -> bool:
    """The rule on a revision read: its ``superseded_by`` value."""
    return superseded_by is None


def _columns(calibrations: Any) -> Any:
    """A table clause's columns (``.c``); a mapped class or ORM alias is its own."""
    return getattr(calibrations, "c", calibrations)


if TYPE_CHECKING:  # built on first use by `__getattr__`
    CURRENT: ColumnElement[bool]
    VALID: ColumnElement[bool]
    LATEST_RUN_FIRST: tuple[UnaryExpression, UnaryExpression]
    LATEST_FIRST: tuple[UnaryExpression, UnaryExpression, UnaryExpression]


@cache
def _mapped() -> dict[str, Any]:
    """The rule on the mapped tables (storage.schema)."""
    from storage.schema import CalibrationRow, Run

    current_ = current(CalibrationRow)
    # Latest first: runs (index ix_runs_device_id_started_at_id walked backwards), then
    # of a run's current revisions the later one.
    latest_run_first = (Run.started_at.desc(), Run.id.desc())
    return {
        "CURRENT": current_,
        "VALID": current_ & (CalibrationRow.verdict == PASS),
        "LATEST_RUN_FIRST": latest_run_first,
        "LATEST_FIRST": (*latest_run_first, CalibrationRow.id.desc()),
    }


def __getattr__(name: str) -> Any:
    if name not in ("CURRENT", "VALID", "LATEST_RUN_FIRST", "LATEST_FIRST"):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    built = _mapped()
    globals().update(built)
    return built[name]


def latest_valid_pick(*where: Any) -> Select:
    """``SELECT calibrations.id``: the latest valid calibration among runs meeting `where`
    (conditions on Run, e.g. its unit and a start bound); make it a scalar subquery."""
    from storage.schema import CalibrationRow, Run

    rule = _mapped()
    return (
        select(CalibrationRow.id)
        .join(Run, Run.id == CalibrationRow.run_id)
        .where(rule["VALID"], *where)
        .order_by(*rule["LATEST_FIRST"])
        .limit(1)
    )
