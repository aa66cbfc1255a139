"""Reprocessing a selection of the archive (`calib reprocess --all/--serial/...`): real SQLite
archive, real Prefect flow runs (`pipelines.flows.reprocess_batch`), real subprocesses.

Runs are simulated at the simulator's default 50 Hz (a few tenths of a second each to
process). They are judged by a lab profile ``lab`` (the shipped MPU-6000 profile with
limits set per test, in a CALIB_PROFILES folder), so that a profile change is a real
change of a profile file, as a lab makes it.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import func, select
from test_batch import wait_first_run_finished

import pipelines.process as process_module
from calib_core.simulate import random_errors, six_position_integral_run
from calib_testing.calib_command import CALIB, run_calib
from calib_testing.run_writers import six_position_manifest, write_csv_run
from pipelines.changes import change_report, family
from pipelines.direct import discover, process_in_process
from pipelines.provenance import SOFTWARE_VERSION
from pipelines.reprocess import changed_pairs, plan_reprocess, reprocess_in_process
from storage import queries, schema
from storage.db import resolve_archive

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = (ROOT / "pipelines" / "profiles" / "mpu6000.toml").read_text()
SUBPROCESS_TIMEOUT_S = 240  # a batch of simulated runs on a shared 2-core machine
LOOSE = 1e3  # a limit no simulated value comes near


def lab_profile(folder: Path, version: str, acc_bias: float = LOOSE, gyr_bias: float = LOOSE):
    """Write ``labrule.toml``: the shipped profile with bias limits acc_bias (m/s^2), gyr_bias
    (deg/s), and the gyro noise limit lifted (the simulated noise is above the MPU-6000's)."""
    text = SHIPPED
    for old, new in (
        ('name = "mpu6000"', 'name = "labrule"'),
        ('version = "3"', f'version = "{version}"'),
        ('"gyr.noise.*"\nhigh = 0.05', '"gyr.noise.*"\nhigh = 1000'),
        ('"gyr.bias.*"\nbound = 20', f'"gyr.bias.*"\nbound = {gyr_bias!r}'),
        ("pattern wins\nbound = 0.8", f"pattern wins\nbound = {acc_bias!r}"),
        ('"acc.bias.*"\nbound = 0.5', f'"acc.bias.*"\nbound = {acc_bias!r}'),
    ):
        assert old in text, old  # the shipped profile changed: adapt this test
        text = text.replace(old, new)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "labrule.toml").write_text(text)


def archived_runs(tmp_path: Path, seeds: list[int]) -> tuple[str, list[dict]]:
    """One run per seed (serial LAB<seed>, started on day <seed> of November 2026) processed
    into a fresh SQLite archive; returns the archive folder and the outcomes."""
    for seed in seeds:
        rng = np.random.default_rng(seed)
        sim = six_position_integral_run(random_errors(rng), rng)
        m = six_position_manifest(f"LAB{seed}", started=f"2026-11-{seed:02d}T09:00:00+00:00")
        m["run"]["tolerance_profile"] = "labrule"
        write_csv_run(sim.segments, tmp_path / "day" / f"run{seed}", m)
    sources, failed = discover([str(tmp_path / "day")])
    assert not failed
    archive = str(tmp_path / "archive")
    outcomes = process_in_process(sources, archive)
    assert [o["status"] for o in outcomes] == ["ok"] * len(seeds), outcomes
    shutil.rmtree(tmp_path / "day")  # from here on only the archive has the runs
    return archive, outcomes


def calibrations_per_run(archive: str) -> dict[str, int]:
    arch = resolve_archive(archive)
    with arch.engine().connect() as conn:
        rows = conn.execute(
            select(schema.Run.run_id, func.count(schema.CalibrationRow.id))
            .join(schema.CalibrationRow, schema.CalibrationRow.run_id == schema.Run.id)
            .group_by(schema.Run.run_id)
        ).all()
    arch.dispose()
    return dict(rows)


def test_selection_reprocessed_twice_gives_revisions_then_duplicates(
    prefect_harness, tmp_path: Path, monkeypatch
) -> None:
    """New software: the selected runs (started since the 2nd) get revision 2 with the
    reason, the run before the date is left alone; the same flow again reprocesses nothing
    (every run a duplicate). Same raw bytes and solver: the change report finds no change."""
    from pipelines.flows import reprocess_batch  # Prefect: imported when run, not when collected

    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path / "profiles"))
    lab_profile(tmp_path / "profiles", "1")
    archive, first = archived_runs(tmp_path, [1, 2, 3, 4])
    monkeypatch.setattr(process_module, "SOFTWARE_VERSION", "9.9.9-reprocess-batch")

    selection = {"since": "2026-11-02"}
    once = reprocess_batch("solver upgrade", selection, archive=archive, workers=2)
    assert [o["status"] for o in once] == ["revised"] * 3, once
    twice = reprocess_batch("solver upgrade", selection, archive=archive, workers=2)
    assert [o["status"] for o in twice] == ["duplicate"] * 3, twice
    assert sorted(o["run_id"] for o in twice) == sorted(o["run_id"] for o in once)

    counts = calibrations_per_run(archive)
    assert counts == {first[0]["run_id"]: 1, **{o["run_id"]: 2 for o in once}}
    arch = resolve_archive(archive)
    with arch.engine().connect() as conn:
        reasons = (
            conn.execute(
                select(schema.ProcessingStep.settings).where(
                    schema.ProcessingStep.name == "reprocess"
                )
            )
            .scalars()
            .all()
        )
    assert reasons == [{"reason": "solver upgrade"}] * 3
    assert [(e["action"], e["reason"]) for e in queries.audit_trail(arch)][-3:] == [
        ("revised", "solver upgrade")
    ] * 3  # the audit trail keeps the reason given
    # Every filter, on the archive as it now is (3 runs revised by the new software).
    for filters, expected in (
        ({"software_version": "9.9.9-reprocess-batch"}, [o["run_id"] for o in once]),
        ({"software_version": SOFTWARE_VERSION}, [first[0]["run_id"]]),  # left alone
        ({"until": "2026-11-02"}, [first[0]["run_id"], once[0]["run_id"]]),
        ({"since": "2026-11-03T00:00:00+00:00", "until": "2026-11-03"}, [once[1]["run_id"]]),
        ({"serial": "LAB4"}, [once[2]["run_id"]]),
        (
            {"model": "MPU-6000", "profile": "labrule"},
            [first[0]["run_id"]] + [o["run_id"] for o in once],
        ),
        ({"model": "ADXL355"}, []),
        ({"profile": "mpu6000"}, []),
    ):
        assert [r["run_id"] for r in queries.select_runs(arch, **filters)] == expected, filters
    with pytest.raises(ValueError, match="until: expected a date"):
        queries.select_runs(arch, until="last week")
    # the duplicates' revisions, made by the first pass of this reprocessing, are current
    report = change_report(changed_pairs(arch, twice, "solver upgrade"))
    assert report["runs"] == 3 and report["verdicts"] == {}
    # Same bytes, same deterministic solver: every value equal, so no |z| above 0.
    assert all(row["changed"] == 0 and row["max_z"] == 0.0 for row in report["families"].values())
    assert {"acc.bias", "acc.scale", "gyr.bias", "gyr.scale"} <= set(report["families"])
    arch.dispose()


def _largest(outcome: dict, fam: str) -> float:
    return max(abs(p["value"]) for n, p in outcome["parameters"].items() if family(n) == fam)


def _between(values: list[float]) -> float:
    """A limit half way between the middle two values: half the runs above it."""
    v = sorted(values)
    return (v[len(v) // 2 - 1] + v[len(v) // 2]) / 2


def test_profile_change_flips_the_expected_verdicts_and_the_report_counts_them(
    prefect_harness, tmp_path: Path, monkeypatch
) -> None:
    """Profile v2 limits the accelerometer biases so half the runs fail; v3 lifts that and
    limits the gyro biases instead. Reprocessed under v3 (a Prefect flow), a run flips
    pass->fail exactly when its gyro bias is over the new limit and its accelerometer bias
    was within the old one, fail->pass the other way round (simple acceptance: a value is
    judged against the limit itself, so the split is known from the archived values)."""
    from pipelines.flows import reprocess_batch  # Prefect: imported when run, not when collected

    profiles = tmp_path / "profiles"
    monkeypatch.setenv("CALIB_PROFILES", str(profiles))
    lab_profile(profiles, "1")
    seeds = [5, 6, 7, 8, 9, 10]
    archive, first = archived_runs(tmp_path, seeds)
    assert {o["verdict"] for o in first} == {"pass"}, [o["checks"] for o in first]
    acc = {o["run_id"]: _largest(o, "acc.bias") for o in first}
    gyr = {o["run_id"]: _largest(o, "gyr.bias") for o in first}  # rad/s
    acc_limit, gyr_limit = _between(list(acc.values())), _between(list(gyr.values()))

    lab_profile(profiles, "2", acc_bias=acc_limit)
    arch = resolve_archive(archive)
    todo, skipped = plan_reprocess(arch, {"serial": None})
    assert len(todo) == len(seeds) and not skipped  # a new profile version: nothing done yet
    v2 = reprocess_in_process(arch, todo, skipped, "acc bias limit")
    assert {o["run_id"]: o["verdict"] for o in v2} == {
        r: "fail" if a > acc_limit else "pass" for r, a in acc.items()
    }

    lab_profile(profiles, "3", gyr_bias=float(np.rad2deg(gyr_limit)))
    v3 = reprocess_batch("gyro bias limit instead", {}, archive=archive, workers=2)
    assert [o["status"] for o in v3] == ["revised"] * len(seeds), v3
    report = change_report(changed_pairs(arch, v3))
    failing_before = {r for r, a in acc.items() if a > acc_limit}
    failing_now = {r for r, g in gyr.items() if g > gyr_limit}
    expected = {
        "pass->fail": sorted(failing_now - failing_before),
        "fail->pass": sorted(failing_before - failing_now),
    }
    assert expected["pass->fail"] and expected["fail->pass"]  # the seeds give both kinds
    assert {k: sorted(v) for k, v in report["flipped"].items()} == expected
    assert report["verdicts"] == {k: len(v) for k, v in expected.items()}
    assert report["runs"] == len(seeds)
    assert all(row["changed"] == 0 for row in report["families"].values())
    arch.dispose()


def test_change_report_counts_changes_beyond_k_combined_uncertainties() -> None:
    """|new-old| against k * sqrt(u_new^2 + u_old^2): with u = 0.3 and 0.4 (combined 0.5)
    and k = 3, a change of 1.49 is within, 1.51 beyond; a missing std is "unjudged"."""

    def pair(run_id: str, d: float, verdicts=("pass", "pass"), std=0.4) -> dict:
        old = {
            "verdict": verdicts[0],
            "parameters": {"acc.bias.x": (1.0, 0.3), "gyr.scale.y": (0.0, None)},
        }
        new = {
            "verdict": verdicts[1],
            "parameters": {"acc.bias.x": (1.0 + d, std), "gyr.scale.y": (d, None)},
        }
        return {"run_id": run_id, "old": old, "new": new}

    report = change_report(
        [pair("A", 1.49), pair("B", -1.51, ("pass", "fail")), pair("C", 0.0, ("fail", "pass"))],
        k=3,
    )
    assert report["families"]["acc.bias"] == {
        "runs": 3,
        "changed": 1,
        "unjudged": 0,
        "max_z": pytest.approx(1.51 / 0.5),
    }
    assert report["families"]["gyr.scale"]["unjudged"] == 2  # A and B differ, C does not
    assert report["flipped"] == {"pass->fail": ["B"], "fail->pass": ["C"]}
    with pytest.raises(ValueError, match="k: expected a finite number > 0"):
        change_report([], k=0)


def test_kill_during_a_reprocess_batch_then_rerun_reprocesses_every_run_once(
    prefect_harness, tmp_path: Path
) -> None:
    """`calib reprocess --all` killed with SIGKILL once a run has been revised: the same
    command again revises the rest and skips the revised ones as duplicates, so every
    run ends with exactly two revisions, the second made under the new profile, and
    the archive verifies."""
    from prefect.settings import PREFECT_API_URL

    profiles = tmp_path / "profiles"
    os.environ["CALIB_PROFILES"] = str(profiles)  # for archived_runs in this process
    try:
        lab_profile(profiles, "1")
        seeds = list(range(11, 19))  # 8 runs: the batch is still going at the first revision
        archive, _ = archived_runs(tmp_path, seeds)
    finally:
        del os.environ["CALIB_PROFILES"]
    lab_profile(profiles, "2", acc_bias=0.4)
    env = {
        **os.environ,
        "PREFECT_API_URL": PREFECT_API_URL.value(),
        "CALIB_PROFILES": str(profiles),
        "PYTHONPATH": str(ROOT),
    }
    cmd = [CALIB, "--verbose", "reprocess", "--all", "--reason", "profile v2"]
    cmd += ["--archive", archive]
    cmd += ["--flow", "--workers", "2", "--no-progress"]
    log = tmp_path / "stderr.txt"
    with log.open("w") as stderr:
        proc = subprocess.Popen(cmd, stderr=stderr, stdout=subprocess.DEVNULL, env=env)
    wait_first_run_finished(proc, log)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=SUBPROCESS_TIMEOUT_S)
    assert proc.returncode == -signal.SIGKILL
    cut = calibrations_per_run(archive)
    assert 1 <= sum(n == 2 for n in cut.values()) < len(seeds), cut  # killed mid-batch

    again = run_calib(*cmd[1:], "--json", env=env, timeout=SUBPROCESS_TIMEOUT_S)
    assert again.returncode == 0, again.stderr[-3000:]
    doc = json.loads(again.stdout)
    statuses = {o["run_id"]: o["status"] for o in doc["runs"]}
    assert len(statuses) == len(seeds)
    assert {r for r, s in statuses.items() if s == "duplicate"} == {
        r for r, n in cut.items() if n == 2
    }
    assert {r for r, s in statuses.items() if s == "revised"} == {
        r for r, n in cut.items() if n == 1
    }
    assert doc["summary"]["failed"] == 0 and doc["changes"]["runs"] == len(seeds)
    assert set(calibrations_per_run(archive).values()) == {2}  # each run reprocessed once
    verify = run_calib("verify", "--archive", archive, env=env)
    assert verify.returncode == 0, verify.stdout[-2000:] + verify.stderr[-2000:]
