"""`calib verify --recompute`: every archived revision solved again from its raw bytes.

Known truth: the sample runs of data_samples/ processed into a real archive (SQLite file,
PostgreSQL server) by `process_run`; untouched, each revision solves again to the very
values, checks, steps and documents it holds. A revision made up with the project's own
write code (every value + 0.5, its document rewritten to match, sealed by
`seal_calibration`, the chain moved forward, a settings hash of ``f``s) passes the seals
and the audit chain: recomputation must find it, naming run, revision and parameter, and
plain verify must find its settings hash.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session
from typer.testing import CliRunner

from pipelines.cli import app
from pipelines.direct import discover
from pipelines.process import process_run
from pipelines.recompute import plan_recompute, recompute_in_process, summarize
from storage import schema, seal, unit_latest
from storage.db import Archive
from storage.revision_rows import add_revision, check_rows, insert_many, step_row
from storage.verify import verify

SAMPLES = Path(__file__).resolve().parents[1] / "data_samples"
FORGED_SHIFT = 0.5  # added to every value of the made-up revision (SI units)


def process_samples(archive: Archive, folders: list[str]) -> list[str]:
    """The sample runs under `folders` (names in data_samples/) archived; their run ids."""
    sources, failed = discover([str(SAMPLES / f) for f in folders])
    assert not failed, failed
    outcomes = [process_run(s, archive) for s in sources]
    assert all(o["status"] == "ok" for o in outcomes), [o["error"] for o in outcomes]
    return [o["run_id"] for o in outcomes]


def forge_revision(archive: Archive, run_id: str) -> tuple[int, list[str]]:
    """Revision n+1 of `run_id` made up with the archive's own write code: every parameter
    value + FORGED_SHIFT in rows and document, the steps and checks copied, settings hash
    ``f`` * 64, sealed and chained as a revision; (its revision, the parameter names)."""
    with Session(archive.engine()) as s, s.begin():
        run = s.scalars(select(schema.Run).where(schema.Run.run_id == run_id)).one()
        prev = s.scalars(
            select(schema.CalibrationRow).where(
                schema.CalibrationRow.run_id == run.id,
                schema.CalibrationRow.superseded_by.is_(None),
            )
        ).one()
        document = {
            **prev.document,
            "parameters": {
                n: {**p, "value": p["value"] + FORGED_SHIFT}
                for n, p in prev.document["parameters"].items()
            },
        }
        keep = ("settings", "software_version", "source_revision", "verdict")
        cal = add_revision(
            s,
            prev,
            run_id=run.id,
            revision=prev.revision + 1,
            settings_hash="f" * 64,
            document=document,
            profile_name=prev.profile_name,
            profile_version=prev.profile_version,
            **{k: getattr(prev, k) for k in keep},
        )
        steps = s.scalars(
            select(schema.ProcessingStep)
            .where(schema.ProcessingStep.calibration_id == prev.id)
            .order_by(schema.ProcessingStep.seq)
        ).all()
        insert_many(
            s,
            schema.ProcessingStep,
            [step_row(run.id, cal.id, st.seq, _step(st), st.source_revision) for st in steps],
        )
        params = s.scalars(
            select(schema.ParameterRow).where(schema.ParameterRow.calibration_id == prev.id)
        ).all()
        rows = [
            {"calibration_id": cal.id, "name": p.name, "value": p.value + FORGED_SHIFT,
             "std": p.std, "unit": p.unit, "temperature_c": p.temperature_c}
            for p in params
        ]  # fmt: skip
        insert_many(s, schema.ParameterRow, rows)
        checks = s.scalars(
            select(schema.CheckResultRow).where(schema.CheckResultRow.calibration_id == prev.id)
        ).all()
        insert_many(
            s,
            schema.CheckResultRow,
            check_rows(
                cal.id, [_check(c) for c in checks], prev.profile_name, prev.profile_version
            ),
        )
        s.flush()
        unit_latest.refresh(s.connection(), run.device_id)
        seal.seal_calibration(s.connection(), cal.id, "revised", reason="routine")
        return cal.revision, sorted(p.name for p in params)


def _step(row: schema.ProcessingStep):  # noqa: ANN202 - a StepRecord
    from calib_core.calibration import StepRecord

    return StepRecord(row.name, row.settings, row.statistics, row.software_version)


def _check(row: schema.CheckResultRow):  # noqa: ANN202 - a CheckResult
    from calib_core.calibration import CheckResult

    return CheckResult(row.name, row.value, row.limit, row.passed, row.detail)


def _cli_env(archive: Archive) -> dict[str, str]:
    return {"CALIB_FILESTORE": str(archive.root), "COLUMNS": "250"}


def _archive_arg(archive: Archive) -> str:
    return str(archive.root) if archive.is_sqlite else archive.url


@pytest.mark.slow
def test_samples_recompute_identical_and_a_forged_revision_is_named(archive: Archive) -> None:
    """Every sample run on the archive's back end (SQLite file, PostgreSQL server): each
    revision identical; then a made-up revision of the MPU-6000 run is named by
    `calib verify --recompute`, and plain verify flags its settings hash."""
    folders = [p.name for p in sorted(SAMPLES.iterdir()) if p.is_dir()]
    run_ids = process_samples(archive, folders)
    outcomes = recompute_in_process(archive, plan_recompute(archive))
    assert {o["run_id"] for o in outcomes} == set(run_ids)
    for o in outcomes:
        assert o["status"] == "identical", (o["run_id"], o["error"], o["revisions"])
    summary = summarize(outcomes)
    assert summary["ok"] and summary["revisions"]["identical"] == len(run_ids)

    (mpu,) = [o["run_id"] for o in outcomes if o["serial"] == "MPU0001"]
    revision, names = forge_revision(archive, mpu)
    # The seals and the chain hold: the made-up revision was sealed by the archive's code.
    found = verify(archive, orphans=False).problems
    assert [(p.kind, p.path, p.runs) for p in found] == [
        ("record", f"calibrations/{revision}/settings_hash", [mpu])
    ], found
    res = CliRunner().invoke(
        app,
        ["verify", "--recompute", mpu, "--archive", _archive_arg(archive), "--no-progress"],
        env=_cli_env(archive),
    )
    assert res.exit_code == 1, res.output
    (line,) = [ln for ln in res.stdout.splitlines() if ln.startswith("DIFFERS")]
    kind, run, rev, what = line.split("\t")
    assert (run, rev) == (mpu, str(revision))
    assert what.startswith(f"parameters/{names[0]}/value: archived "), what
    # the revision before it, untouched, still solves again to itself
    res = CliRunner().invoke(
        app,
        ["verify", "--recompute", mpu, "--archive", _archive_arg(archive), "--json"],
        env=_cli_env(archive),
    )
    doc = json.loads(res.stdout)
    by_revision = {r["revision"]: r for r in doc["runs"][0]["revisions"]}
    assert by_revision[revision - 1]["status"] == "identical"
    forged = by_revision[revision]
    assert forged["status"] == "differs"
    for name in names:
        assert f"parameters/{name}/value" in forged["fields"] or forged["differences"] > 20
    assert "calibrations/settings_hash" in forged["fields"] or forged["differences"] > 20


def test_recompute_selection_is_checked(archive: Archive) -> None:
    """RUN_ID, --sample and --all only with --recompute, exactly one of them."""
    arg = ["--archive", _archive_arg(archive)]
    for args, said in (
        (["verify", "--sample", "2"], "--sample: only with --recompute"),
        (["verify", "--recompute"], "name the runs"),
        (["verify", "--recompute", "--all", "--sample", "2"], "give one of"),
    ):
        res = CliRunner().invoke(app, [*args, *arg], env=_cli_env(archive))
        assert res.exit_code == 2 and said in res.output, res.output
    with pytest.raises(ValueError, match="--sample: expected a number of runs >= 1"):
        plan_recompute(archive, None, 0)
    with pytest.raises(LookupError):
        plan_recompute(archive, ["R000000000000"], None)
