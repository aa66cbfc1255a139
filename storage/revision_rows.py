"""A new calibration revision's row (superseding the current one) and its child rows
(processing steps, checks), inserted by one executemany (storage.archive and
storage.rejudgement write them).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from sqlalchemy import insert
from sqlalchemy.orm import Session

from calib_core.calibration import CheckResult, StepRecord
from storage.schema import Base, CalibrationRow


def add_revision(s: Session, previous: CalibrationRow | None, **columns: Any) -> CalibrationRow:
    """Add the calibration revision of `columns`; `previous`, the run's current one until
    now (None for a new run), is superseded by it."""
    cal = CalibrationRow(**columns)
    s.add(cal)
    s.flush()
    if previous is not None:
        previous.superseded_by = cal.id
    return cal


def step_row(
    run_pk: int, cal_id: int, seq: int, step: StepRecord, source_revision: str | None
) -> dict[str, Any]:
    """The ``processing_steps`` row of `step`, the `seq`-th of revision `cal_id`."""
    return {
        "run_id": run_pk,
        "calibration_id": cal_id,
        "seq": seq,
        "name": step.name,
        "settings": step.settings,
        "statistics": step.statistics,
        "software_version": step.software_version,
        "source_revision": source_revision,
    }


def check_rows(
    cal_id: int,
    checks: Iterable[CheckResult],
    profile_name: str | None,
    profile_version: str | None,
) -> list[dict[str, Any]]:
    """The ``check_results`` rows of revision `cal_id`, judged against the named profile."""
    return [
        {
            "calibration_id": cal_id,
            "name": c.name,
            "value": c.value,
            "limit": c.limit,
            "passed": c.passed,
            "detail": c.detail,
            "profile_name": profile_name,
            "profile_version": profile_version,
        }
        for c in checks
    ]


def insert_many(s: Session, model: type[Base], rows: list[dict[str, Any]]) -> None:
    """INSERT the rows in one executemany, on the session's connection (Core).

    The tens of step, parameter and check rows of a run need no ORM objects,
    whose bookkeeping cost more than the SQL; the ORM's bulk insert of the same
    rows, the same statement and defaults, still cost more than Core.
    """
    if rows:  # an empty parameter list would insert one row of defaults
        s.connection().execute(insert(model.__table__), rows)
