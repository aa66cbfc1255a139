"""A run's verdict does not depend on the order runs are archived in.

The sample unit IMU-R-0003 (four quarterly runs, its z accelerometer bias drifting) is
processed one run at a time in time order, reversed and shuffled, and as batches with
the process runner (`tests/test_dask.py` runs it on a Dask cluster): each run's current
verdict and checks are the same every time, judged against the runs made before it
(pipelines.rejudge). Runs judged again keep the reason in the audit trail and their
seals verify.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from pipelines.direct import discover
from pipelines.process import process_run
from storage import queries
from storage.db import Archive, open_archive
from storage.verify import verify

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data_samples" / "history_IMU-R-0003"
SERIAL = "IMU-R-0003"
# The runs by date, as `calib process` in time order judges them: three runs are the
# profile's fewest for repeatability, and the drifting z bias does not repeat.
IN_TIME_ORDER = {
    "2026-02-03": "pass",
    "2026-05-05": "pass",
    "2026-08-04": "needs review",
    "2026-11-03": "needs review",
}


def run_folders(order: list[str]) -> list[str]:
    """The sample's run folders in the order of `order` (dates)."""
    return [str(SAMPLE / day) for day in order]


def judgements(archive: Archive) -> dict[str, dict[str, Any]]:
    """Run date -> verdict, checks and repeatability group (dates) of its current revision."""
    hist = queries.history(archive, SERIAL)
    current = hist[~hist["superseded"]]
    day = {r: f"{s:%Y-%m-%d}" for r, s in zip(hist["run_id"], hist["started_at"], strict=True)}
    now = queries.current_judgements(archive, list(current["run_id"]))
    out = {}
    for run_id in current["run_id"]:
        group = queries.run_summary(archive, run_id).calibration.step_statistics("check")
        # The device check passes alike when the unit's runs agree on its description.
        checks = [c for c in now[run_id]["checks"] if not c.name.startswith("device:")]
        out[day[run_id]] = {
            "verdict": now[run_id]["verdict"],
            "checks": checks,
            "group": [day[r] for r in group["repeatability_group"]],
        }
    return out


def process_in_order(archive: Archive, order: list[str]) -> list[dict[str, Any]]:
    sources, failed = discover(run_folders(order))
    assert not failed and len(sources) == len(order)
    return [process_run(s, archive) for s in sources]


def check_time_order(seen: dict[str, dict[str, Any]], name: str) -> None:
    """Each run's verdict as in time order, judged against the runs made before it."""
    assert {d: j["verdict"] for d, j in seen.items()} == IN_TIME_ORDER, name
    for day, judged in seen.items():
        earlier = [d for d in IN_TIME_ORDER if d < day][::-1]  # most recent first
        assert judged["group"] == [day, *earlier], (name, day)


def test_in_process_any_order_gives_the_verdicts_of_time_order(tmp_path: Path) -> None:
    orders = {
        "time": list(IN_TIME_ORDER),
        "reversed": list(IN_TIME_ORDER)[::-1],
        "shuffled": ["2026-08-04", "2026-02-03", "2026-11-03", "2026-05-05"],
    }
    seen = {}
    for name, order in orders.items():
        archive = open_archive(tmp_path / name)
        try:
            outcomes = process_in_order(archive, order)
            assert all(o["status"] == "ok" for o in outcomes), outcomes
            seen[name] = judgements(archive)
            check_time_order(seen[name], name)
            if name == "time":  # nothing judged again
                assert len(queries.history(archive, SERIAL)) == 4
            else:  # judged again: the reason is in the audit trail, every seal verifies
                reasons = [e["reason"] or "" for e in queries.audit_trail(archive, SERIAL)]
                assert any("judged again by run time" in r for r in reasons)
                report = verify(archive, orphans=False)
                assert report.ok, report.problems
            if name == "reversed":  # the last run archived (the first made) sees them all
                assert outcomes[-1]["message"].count("judged again") == 3, outcomes[-1]
        finally:
            archive.dispose()
    assert seen["reversed"] == seen["time"] and seen["shuffled"] == seen["time"]
    # the drifting bias is what does not repeat
    failed = {c.name for c in seen["time"]["2026-11-03"]["checks"] if not c.passed}
    assert {n for n in failed if n.startswith("repeat:")} == {"repeat:acc.bias.z"}


@pytest.mark.slow
def test_process_runner_batches_in_any_order_give_the_same_verdicts(
    prefect_harness, tmp_path: Path
) -> None:
    from pipelines.flows import process_batch

    seen = {}
    for name, order in (("time", list(IN_TIME_ORDER)), ("reversed", list(IN_TIME_ORDER)[::-1])):
        target = tmp_path / name
        outcomes = process_batch(run_folders(order), str(target), runner="process", workers=2)
        archive = open_archive(target)
        try:
            seen[name] = judgements(archive)
            # the batch's document says what the archive holds at the batch's end
            by_id = {o["run_id"]: o for o in outcomes}
            hist = queries.history(archive, SERIAL)
            for run_id, started in zip(hist["run_id"], hist["started_at"], strict=True):
                assert by_id[run_id]["verdict"] == IN_TIME_ORDER[f"{started:%Y-%m-%d}"]
        finally:
            archive.dispose()
        check_time_order(seen[name], name)
    assert seen["reversed"] == seen["time"]


def test_a_judgement_made_on_an_older_state_is_not_written(tmp_path: Path) -> None:
    """`rejudge_run` writes only while the revision is current and the unit's earlier runs
    are those the judgement saw; else nothing is written and the caller judges again."""
    from calib_core.calibration import StepRecord
    from storage.rejudgement import Rejudgement, rejudge_run

    archive = open_archive(tmp_path / "a")
    try:
        process_in_order(archive, ["2026-11-03", "2026-08-04"])  # Nov judged again once
        assert len(queries.history(archive, SERIAL)) == 3  # Nov revisions 1, 2; Aug 1
        cands = queries.repeatability_candidates(archive, SERIAL, "six_position")
        nov, aug = cands  # newest first
        record = queries.judgement(archive, nov["calibration_id"])
        judged = Rejudgement(
            run_id=nov["run_id"],
            calibration_id=nov["calibration_id"],
            earlier=[],
            checks=[],
            check_statistics=record["check_step"]["statistics"],
            verdict="pass",
            step=StepRecord("rejudge"),
            reason="test: judged without the August run",
        )
        assert rejudge_run(archive, judged) is None  # the August run is there now
        stale = replace(judged, earlier=[aug["run_id"]], calibration_id=-1)
        assert rejudge_run(archive, stale) is None  # no such revision
        assert len(queries.history(archive, SERIAL)) == 3
    finally:
        archive.dispose()


def test_a_revision_judged_again_has_a_settings_hash_a_reader_recomputes(
    archive: Archive,
) -> None:
    """The revision judged again keeps the settings of the one it supersedes; its settings
    hash covers them and the runs its sealed `rejudge` step was judged against, so verify
    recomputes it and a changed list of runs shows."""
    from sqlalchemy import select, update

    from storage.schema import CalibrationRow, ProcessingStep, Run
    from storage.settings_hash import JUDGED_AGAINST, settings_hash

    process_in_order(archive, ["2026-11-03", "2026-08-04"])  # Nov judged again once
    cands = queries.repeatability_candidates(archive, SERIAL, "six_position")
    nov, aug = (c["run_id"] for c in cands)  # newest first
    with archive.engine().connect() as conn:
        rows = conn.execute(
            select(CalibrationRow.__table__, Run.procedure)
            .join(Run, Run.id == CalibrationRow.run_id)
            .where(Run.run_id == nov)
            .order_by(CalibrationRow.revision)
        ).all()
        first, again = rows
        step = conn.execute(
            select(ProcessingStep.id, ProcessingStep.settings).where(
                ProcessingStep.calibration_id == again.id, ProcessingStep.name == "rejudge"
            )
        ).one()
    assert step.settings[JUDGED_AGAINST] == [aug]
    assert again.settings == first.settings
    parts = (again.settings, again.procedure, again.profile_name, again.profile_version)
    assert first.settings_hash == settings_hash(*parts)
    assert again.settings_hash == settings_hash(*parts, [aug])
    assert verify(archive, orphans=False).ok

    with archive.engine().begin() as conn:  # as if judged against no run
        conn.execute(
            update(ProcessingStep)
            .where(ProcessingStep.id == step.id)
            .values(settings={**step.settings, JUDGED_AGAINST: []})
        )
    found = verify(archive, orphans=False, seals=False).problems
    assert [(p.kind, p.path) for p in found] == [("record", "calibrations/2/settings_hash")]
