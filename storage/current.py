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
cannot disagree.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import ColumnElement, Select, select

from storage.schema import CalibrationRow, Run

PASS = "pass"

CURRENT: ColumnElement[bool] = CalibrationRow.superseded_by.is_(None)
VALID: ColumnElement[bool] = CURRENT & (CalibrationRow.verdict == PASS)
# Latest first: runs (index ix_runs_device_id_started_at_id walked backwards), then
# of a run's current revisions the later one.
LATEST_RUN_FIRST = (Run.started_at.desc(), Run.id.desc())
LATEST_FIRST = (*LATEST_RUN_FIRST, CalibrationRow.id.desc())


def latest_valid_pick(*where: Any) -> Select:
    """``SELECT calibrations.id``: the latest valid calibration among runs meeting `where`
    (conditions on Run, e.g. its unit and a start bound); make it a scalar subquery."""
    return (
        select(CalibrationRow.id)
        .join(Run, Run.id == CalibrationRow.run_id)
        .where(VALID, *where)
        .order_by(*LATEST_FIRST)
        .limit(1)
    )
