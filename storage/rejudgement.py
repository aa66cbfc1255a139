"""A run's current revision judged again against the unit's earlier runs: a new revision
with the same parameters, document and steps, its own checks and verdict (`rejudge_run`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from calib_core.calibration import CheckResult, StepRecord
from storage import schema, seal, unit_latest
from storage.archive import ArchiveResult
from storage.current import CURRENT, LATEST_RUN_FIRST, is_current
from storage.db import Archive
from storage.revision_rows import add_revision, check_rows, insert_many, step_row
from storage.settings_hash import JUDGED_AGAINST, REJUDGE_STEP, settings_hash


@dataclass
class Rejudgement:
    """A run's current revision judged again against the unit's earlier runs.

    run_id : the run.
    calibration_id : the revision judged again; it must still be the current one.
    earlier : run ids of the unit's runs (same procedure) made before it, most recent first,
        as the new checks saw them; they must still be the archive's.
    checks : every check of the new revision.
    check_statistics : the statistics of its ``check`` step.
    verdict : the new verdict.
    step : the step record of the judgement, appended to the revision's steps.
    reason : why, into the audit trail.
    """

    run_id: str
    calibration_id: int
    earlier: list[str]
    checks: list[CheckResult]
    check_statistics: dict[str, Any]
    verdict: str
    step: StepRecord
    reason: str


def rejudge_run(archive: Archive, judged: Rejudgement) -> ArchiveResult | None:
    """A new revision of a run with the same parameters, document and steps, judged again.

    Its settings are the revision's; its ``rejudge`` step records the runs it was judged
    against (`JUDGED_AGAINST`: ``judged.earlier``), and its settings hash covers them
    besides the settings (`settings_hash`), so a reader recomputes it from the sealed
    rows (`storage.verify`). Sealed as "revised" with the reason.

    Returns
    -------
    ArchiveResult ("revised"); None when the archive changed since the checks were made
    (another revision of the run, another earlier run): judge again.
    """
    seal.check_reason(judged.reason)
    engine = archive.engine().execution_options(sqlite_begin="IMMEDIATE")
    try:
        with Session(engine) as s, s.begin():
            prev = s.get(schema.CalibrationRow, judged.calibration_id)
            run = s.get(schema.Run, prev.run_id) if prev is not None else None
            if run is None or run.run_id != judged.run_id or not is_current(prev.superseded_by):
                return None
            if _earlier_runs(s, run) != judged.earlier:
                return None
            cal = _judged_again(s, prev, run.procedure, judged)
            unit_latest.refresh(s.connection(), run.device_id)
            seal.seal_calibration(s.connection(), cal.id, "revised", reason=judged.reason)
            result = ArchiveResult(
                "revised",
                run.run_id,
                cal.revision,
                cal.id,
                archive.root / run.run_dir,
                f"run {run.run_id} judged again: revision {cal.revision} supersedes "
                f"revision {prev.revision} ({judged.reason})",
            )
    except IntegrityError:  # a concurrent revision of the same run won
        return None
    return result


def _earlier_runs(s: Session, run: schema.Run) -> list[str]:
    """Run ids of the unit's runs by the same procedure made before `run`, with a current
    revision, most recent first (`storage.queries.repeatability_candidates`' order)."""
    return list(
        s.scalars(
            select(schema.Run.run_id)
            .join(schema.CalibrationRow, schema.CalibrationRow.run_id == schema.Run.id)
            .where(
                schema.Run.device_id == run.device_id,
                schema.Run.procedure == run.procedure,
                schema.Run.started_at < run.started_at,
                CURRENT,
            )
            .order_by(*LATEST_RUN_FIRST)
        )
    )


# What a revision judged again keeps of the one it supersedes.
_KEPT = (
    "settings",
    "software_version",
    "source_revision",
    "document",
    "profile_name",
    "profile_version",
)


def _judged_again(
    s: Session, prev: schema.CalibrationRow, procedure: str, judged: Rejudgement
) -> schema.CalibrationRow:
    """The rows of the new revision: `prev`'s, with the checks and verdict of `judged`."""
    revision = 1 + s.scalar(
        select(func.max(schema.CalibrationRow.revision)).where(
            schema.CalibrationRow.run_id == prev.run_id
        )
    )
    cal = add_revision(
        s,
        prev,
        run_id=prev.run_id,
        revision=revision,
        settings_hash=settings_hash(
            prev.settings, procedure, prev.profile_name, prev.profile_version, judged.earlier
        ),
        verdict=judged.verdict,
        **{c: getattr(prev, c) for c in _KEPT},
    )
    steps = (
        s.execute(
            select(schema.ProcessingStep)
            .where(schema.ProcessingStep.calibration_id == prev.id)
            .order_by(schema.ProcessingStep.seq)
        )
        .scalars()
        .all()
    )
    rows = [
        step_row(
            prev.run_id,
            cal.id,
            i,
            StepRecord(
                st.name,
                st.settings,
                judged.check_statistics if st.name == "check" else st.statistics,
                st.software_version,
            ),
            st.source_revision,
        )
        for i, st in enumerate(steps)
    ]
    step = judged.step
    settings = {**step.settings, JUDGED_AGAINST: judged.earlier}
    again = StepRecord(REJUDGE_STEP, settings, step.statistics, step.software_version)
    rows.append(step_row(prev.run_id, cal.id, len(rows), again, prev.source_revision))
    insert_many(s, schema.ProcessingStep, rows)
    params = s.execute(
        select(
            schema.ParameterRow.name,
            schema.ParameterRow.value,
            schema.ParameterRow.std,
            schema.ParameterRow.unit,
            schema.ParameterRow.temperature_c,
        )
        .where(schema.ParameterRow.calibration_id == prev.id)
        .order_by(schema.ParameterRow.id)
    ).all()
    insert_many(s, schema.ParameterRow, [{"calibration_id": cal.id, **p._mapping} for p in params])
    checks = check_rows(cal.id, judged.checks, prev.profile_name, prev.profile_version)
    insert_many(s, schema.CheckResultRow, checks)
    s.flush()
    return cal
