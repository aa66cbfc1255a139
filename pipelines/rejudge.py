"""Repeatability by run time, the pipeline glue: a unit's runs judged again when a run
made before them is archived after them.

A run's repeatability group is its own values and those of the unit's runs (same
procedure, comparable conditions) made before it by run time
(`calib_core.verification.comparable_runs`). A batch archives runs in the order its
workers finish, and a lab may archive a forgotten older run later: so after each
archived run, every run of the unit from that run's time on whose group now holds
another set of runs is judged again, as a new revision (same parameters and steps,
repeatability checks and verdict judged again, the reason in the audit trail). Whatever
the order of archiving, each run ends judged against the runs made before it.
"""

from __future__ import annotations

from typing import Any

from calib_core import verification
from calib_core.calibration import CheckResult, StepRecord
from calib_core.checks import DEVICE_PREFIX, REPEAT_PREFIX, overall_verdict
from calib_core.conditions import counts_against_verdict
from calib_core.conditions import status as condition_status
from calib_core.tolerances import ToleranceProfile
from pipelines import shared_reference
from storage import queries
from storage.archive import ArchiveError
from storage.db import Archive
from storage.rejudgement import Rejudgement, rejudge_run
from storage.settings_hash import REJUDGE_STEP

# Judgements made again after a concurrent writer changed the unit's runs meanwhile;
# each attempt sees at least one more committed change, and a unit has few runs in flight.
MAX_ATTEMPTS = 8


def run_values(candidate: dict[str, Any]) -> verification.RunValues:
    """A `storage.queries.repeatability_candidates` entry as the group's `RunValues`."""
    return verification.RunValues(
        candidate["run_id"],
        (candidate["environment"] or {}).get("temperature_c"),
        candidate["parameters"],
    )


def group_of(
    current: verification.RunValues,
    earlier: list[dict[str, Any]],
    profile: ToleranceProfile,
    archive: Archive | None = None,
    shared: dict[str, tuple] | None = None,
) -> list[verification.RunValues]:
    """The repeatability group of `current` among the `earlier` runs (most recent first).

    With `archive`, a group large enough to be judged carries each run's shared reference
    (pipelines.shared_reference: runs on the same reference share its Type B); `shared` is
    that of `current` when it is not archived yet.
    """
    rules = profile.repeatability
    others = [run_values(c) for c in earlier]
    group = verification.comparable_runs(
        current, others, rules["temperature_tol_c"], int(rules["max_runs"])
    )
    if archive is not None and len(group) >= int(rules["min_runs"]):
        group = shared_reference.with_shared(archive, group, shared)
    return group


def with_repeatability(checks: list[CheckResult], repeat: list[CheckResult]) -> list[CheckResult]:
    """`checks` with their repeatability checks replaced by `repeat`, where `check_run` puts
    them: before the device check."""
    kept = [c for c in checks if not c.name.startswith(REPEAT_PREFIX)]
    at = next((i for i, c in enumerate(kept) if c.name.startswith(DEVICE_PREFIX)), len(kept))
    return [*kept[:at], *repeat, *kept[at:]]


def rejudge_from(archive: Archive, serial: str, procedure: str, run_id: str) -> dict[str, Any]:
    """Judge again the runs of `serial` by `procedure` from run `run_id`'s time on (itself
    included) whose repeatability group changed; the runs that group now holds `run_id`.

    Returns
    -------
    run id -> {"checks": list[CheckResult], "verdict": str, "revision": int} of each run
    judged again (a new revision), {} when every judgement still holds.

    Raises
    ------
    ArchiveError when concurrent writers kept changing the unit's runs.
    """
    done: dict[str, Any] = {}
    for _ in range(MAX_ATTEMPTS):
        stale = False
        cands = queries.repeatability_candidates(archive, serial, procedure)  # newest first
        at = next((i for i, c in enumerate(cands) if c["run_id"] == run_id), None)
        if at is None:  # not (or no longer) current: nothing from it to judge
            return done
        for i in range(at, -1, -1):  # the run itself, then the later runs, oldest first
            cand = cands[i]
            # made before it: started earlier (a run started at the same instant is not)
            earlier = [c for c in cands[i + 1 :] if c["started_at"] < cand["started_at"]]
            new = _judged_again(archive, cand, earlier, run_id)
            if new is None:
                continue
            result = rejudge_run(archive, new[0])
            if result is None:
                stale = True
                break
            done[cand["run_id"]] = {**new[1], "revision": result.revision}
        if not stale:
            return done
    raise ArchiveError(
        f"runs of {serial} from run {run_id} on: not judged again, the unit's runs kept "
        f"changing while they were judged ({MAX_ATTEMPTS} attempts); process {run_id} again"
    )


def _judged_again(
    archive: Archive, cand: dict[str, Any], earlier: list[dict[str, Any]], trigger: str
) -> tuple[Rejudgement, dict[str, Any]] | None:
    """The new judgement of `cand` if its group changed and holds `trigger`, else None."""
    current = run_values(cand)
    record = queries.judgement(archive, cand["calibration_id"])
    step = record["check_step"]
    if step is None or "thresholds" not in step["settings"]:
        return None  # judged before thresholds were archived: nothing to judge again by
    profile = ToleranceProfile.from_dict(step["settings"]["thresholds"])
    group = group_of(current, earlier, profile, archive)
    ids = [r.run_id for r in group]
    if ids == step["statistics"].get("repeatability_group"):
        return None
    if trigger not in ids and cand["run_id"] != trigger:
        return None  # not this run's doing: the scan of the run that changed it judges it
    checks = with_repeatability(record["checks"], verification.repeatability(group, profile))
    verdict = overall_verdict(checks)
    stats = {
        **step["statistics"],
        "checks": len(checks),
        "failed": sum(counts_against_verdict(c) for c in checks),
        "verdict": verdict,
        "repeatability_group": ids,
    }
    reason = (
        f"repeatability judged again by run time after run {trigger} was archived: "
        f"group {', '.join(ids)}"
    )
    step_record = StepRecord(  # rejudge_run adds the runs judged against to its settings
        REJUDGE_STEP,
        settings={"reason": reason},
        statistics={"repeatability_group": ids, "verdict": verdict},
    )
    judged = Rejudgement(
        run_id=cand["run_id"],
        calibration_id=cand["calibration_id"],
        earlier=[e["run_id"] for e in earlier],
        checks=checks,
        check_statistics=stats,
        verdict=verdict,
        step=step_record,
        reason=reason,
    )
    return judged, {"checks": checks, "verdict": verdict}


def check_entry(c: CheckResult) -> dict[str, Any]:
    """A check as the `calib process --json` document gives it (docs/cli.md): a run's
    outcome (`pipelines.process.run_outcome`) and its checks as archived now."""
    return {
        "name": c.name,
        "value": c.value,
        "limit": c.limit,
        "passed": c.passed,
        "status": condition_status(c),
    }


def as_archived_now(archive: Archive, outcomes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The batch's outcomes with the verdict and checks their runs' current revisions hold.

    A run judged again by another run of the batch (archived after it, made before it)
    reports its judgement at the batch's end, as the archive holds it.
    """
    ids = [o["run_id"] for o in outcomes if o["status"] == "ok" and o["run_id"]]
    now = queries.current_judgements(archive, ids) if ids else {}
    out = []
    for o in outcomes:
        judged = now.get(o["run_id"]) if o["status"] == "ok" else None
        if judged is not None:
            checks = [check_entry(c) for c in judged["checks"]]
            if (judged["verdict"], checks) != (o["verdict"], o["checks"]):
                o = {**o, "verdict": judged["verdict"], "checks": checks}
        out.append(o)
    return out
