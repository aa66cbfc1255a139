"""As found / as left (ISO/IEC 17025 7.8.4.2), the pipeline glue of `calib_core.as_found`.

When the archive holds an earlier valid calibration of the unit (`storage.queries.
latest_calibration` as of just before this run), its parameters are evaluated on this run's
fit segments and archived as the step ``as_found`` of the new revision: the earlier run, and
per error parameter the earlier value, the as-left value, the error as found with its
standard and expanded uncertainty and its verdict against the run's tolerance profile. A
solve that cannot be made on the corrected data leaves the step with the reason
(``statistics.refused``); the run itself is judged on its as-left values only.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from datetime import datetime, timedelta
from typing import Any

from calib_core import as_found
from calib_core.calibration import Calibration, StepRecord
from calib_core.recording import Recording
from calib_core.tolerances import ToleranceProfile
from calib_core.uncertainty import Budget
from storage import queries
from storage.db import Archive
from storage.queries.records import DatedRevision

STEP = "as_found"


def earlier_calibration(archive: Archive, serial: str, started: datetime) -> DatedRevision | None:
    """The unit's latest valid calibration from a run started before `started` (or None)."""
    return queries.latest_calibration(archive, serial, started - timedelta(microseconds=1))


def as_found_step(
    earlier: DatedRevision,
    cal: Calibration,
    fit: Mapping[str, Recording],
    settings: Mapping[str, Any],
    budgets: Mapping[str, Budget],
    profile: ToleranceProfile | None,
    solve_found: Callable[[Calibration], Calibration] | None = None,
) -> StepRecord:
    """The step ``as_found`` of a run whose unit has the `earlier` calibration.

    Parameters
    ----------
    earlier : `earlier_calibration` of the unit.
    cal : this run's calibration (as left); its procedure and gravity solve the as-found.
    fit : the run's preprocessed fit segments, as solved.
    settings : the run's settings, as solved.
    budgets : this run's GUM budgets (their U is the as-found error's, calib_core.as_found).
    profile : the run's tolerance profile (None: no verdicts).
    solve_found : the earlier calibration -> the as-found solve, in place of
        `as_found.evaluate` on `fit` (a record streamed in chunks, `fit` empty).
    """
    started = time.perf_counter()
    said = {
        "earlier_run_id": earlier.run_id,
        "earlier_revision": earlier.revision,
        "earlier_started_at": earlier.started_at.isoformat(),
        "method": "earlier parameters applied to this run's samples, error model solved "
        f"again by procedure {cal.procedure}",
    }
    try:
        before = Calibration.from_dict(earlier.document)
        if solve_found is not None:
            found = solve_found(before)
        else:
            found = as_found.evaluate(before, fit, cal.procedure, cal.gravity, settings)
    except ValueError as exc:
        return StepRecord(STEP, settings=said, statistics={"refused": str(exc)})
    rows = as_found.judge(found, before, cal, budgets, profile)
    return StepRecord(
        STEP,
        settings=said,
        statistics={
            "parameters": [r.to_dict() for r in rows],
            "seconds": round(time.perf_counter() - started, 4),
        },
    )
