"""Free text of a manifest is checked at ingest, the same on SQLite and PostgreSQL; a unit's
description that changes between runs of one serial is flagged in the run's checks."""

from __future__ import annotations

import shutil
import threading
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import pytest
from sqlalchemy import insert, select, text
from test_archive import make_run

from calib_core.calibration import CheckResult
from pipelines.ingest import discover_runs
from pipelines.ingest.errors import IngestError
from pipelines.ingest.free_text import TEXT_MAX_CHARS
from pipelines.ingest.manifest import parse_manifest
from pipelines.process import SAME_DESCRIPTION, process_run
from pipelines.run_task import is_transient
from storage import queries
from storage.archive import PG_UNIT_LOCK, StaleCheckError, archive_run
from storage.schema import Device, Run

ROOT = Path(__file__).resolve().parents[1]
CSV_RUN = ROOT / "data_samples" / "csv_IMU-2026-0042"


def manifest_with(old: str, new: str) -> str:
    text = (CSV_RUN / "run.toml").read_text()
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize(
    ("old", "new", "field", "problem"),
    [
        (
            'operator = "J. Doe"',
            f'operator = "{"x" * 100_000}"',
            "run.operator",
            f"text of 100000 characters; at most {TEXT_MAX_CHARS}",
        ),
        (
            'operator = "J. Doe"',
            'operator = "J. Doe\\u0000"',
            "run.operator",
            "control character '\\x00' (U+0000) at character 7",
        ),
        (
            'model = "MPU-6000"',
            'model = "MPU\\n6000"',
            "unit.model",
            "control character '\\n' (U+000A) at character 4; expected printable text on one",
        ),
        ('operator = "J. Doe"', 'operator = "J. \\u001bDoe"', "run.operator", "U+001B"),
    ],
)
def test_bad_text_names_the_field(old: str, new: str, field: str, problem: str) -> None:
    with pytest.raises(IngestError) as info:
        parse_manifest(manifest_with(old, new), "run.toml")
    assert info.value.field == field and info.value.file == "run.toml"
    assert problem in info.value.problem


def test_description_may_span_lines() -> None:
    spec = 'specification = "6-axis MEMS, +-2000 deg/s, +-16 g"'
    m = parse_manifest(manifest_with(spec, 'specification = "line 1\\nline 2\\tend"'))
    assert m.unit.specification == "line 1\nline 2\tend"


def copy_run(tmp_path: Path, name: str, old: str, new: str, salt: str) -> Path:
    """The CSV sample run with a changed manifest and other raw bytes (a new run id)."""
    folder = tmp_path / name
    shutil.copytree(CSV_RUN, folder)
    (folder / "run.toml").write_text(manifest_with(old, new))
    with open(folder / "imu.csv", "a") as f:
        f.write(salt)
    return folder


def test_nul_in_operator_fails_alike_on_every_back_end(archive, tmp_path: Path) -> None:
    folder = copy_run(tmp_path, "nul", 'operator = "J. Doe"', 'operator = "J. Doe\\u0000"', "")
    (source,) = discover_runs([folder])
    out = process_run(source, archive)
    assert out["status"] == "failed" and "internal error" not in out["error"]
    assert "field 'run.operator': control character" in out["error"]
    with archive.engine().connect() as conn:
        assert conn.exec_driver_sql("SELECT count(*) FROM runs").scalar() == 0


def archived_check(archive, run_id: str) -> CheckResult:  # noqa: ANN001
    checks = queries.run_summary(archive, run_id).calibration.checks
    return {c.name: c for c in checks}["device:description"]


@pytest.mark.slow
def test_model_change_for_a_serial_is_flagged(archive, tmp_path: Path) -> None:
    (first,) = discover_runs([CSV_RUN])
    out = process_run(first, archive)
    assert out["status"] == "ok"
    first_id = out["run_id"]
    check = archived_check(archive, first_id)
    assert check.passed and check.detail == SAME_DESCRIPTION

    folder = copy_run(tmp_path, "swapped", 'model = "MPU-6000"', 'model = "ICM-20602"', "\n")
    (second,) = discover_runs([folder])
    out = process_run(second, archive)
    assert out["status"] == "ok"
    check = archived_check(archive, out["run_id"])
    assert not check.passed
    assert "archived as model 'MPU-6000' by 'InvenSense'" in check.detail
    assert "this run says model 'ICM-20602'" in check.detail
    assert out["verdict"] in ("needs review", "fail")
    assert f"(run {first_id}, started " in check.detail
    second_id = out["run_id"]
    # Each run keeps its own description; the first one's check is as it was.
    for run_id, model in ((first_id, "MPU-6000"), (second_id, "ICM-20602")):
        assert queries.run_summary(archive, run_id).device.model == model
    assert queries.earlier_descriptions(archive, "IMU-2026-0042", first_id) == []

    # Back to the first model: still flagged, naming the run that said otherwise.
    folder = copy_run(tmp_path, "back", 'operator = "J. Doe"', 'operator = "J. Roe"', "\n\n")
    (third,) = discover_runs([folder])
    out = process_run(third, archive)
    check = archived_check(archive, out["run_id"])
    assert not check.passed, check
    assert f"archived as model 'ICM-20602' by 'InvenSense' (run {second_id}," in check.detail
    assert "MPU-6000' by 'InvenSense' (run" not in check.detail


def test_each_other_description_names_its_latest_run_by_run_time(archive, tmp_path: Path) -> None:  # noqa: ANN001
    """Runs archived in the reverse of their run time: each description the unit was
    archived under is named with the latest run by run time that gave it, latest first."""
    said = {2: "ICM-20602", 5: "ICM-20602", 8: "MPU-9250"}  # month of the run -> model
    ids = {}
    for month in sorted(said, reverse=True):
        start = datetime(2024, month, 1, 8, 30, tzinfo=UTC)
        run = make_run(tmp_path / str(month), serial="0077", seed=40 + month, started_at=start)
        ids[month] = archive_run(archive, replace(run, device_model=said[month]), {}).run_id
    found = queries.earlier_descriptions(archive, "0077", "R000000000000")  # a new run's
    assert [(d["model"], d["run_id"]) for d in found] == [
        ("MPU-9250", ids[8]),
        ("ICM-20602", ids[5]),
    ]


def test_a_pass_made_stale_by_a_concurrent_run_is_refused(archive, tmp_path: Path) -> None:  # noqa: ANN001
    """Two runs of one unit checked at once, the other committed first with another model:
    the later one's passed device:description no longer holds, and it is not archived."""
    archive_run(archive, make_run(tmp_path / "a", serial="0012", seed=1), {})
    passed = CheckResult("device:description", None, None, True, SAME_DESCRIPTION)
    later = make_run(tmp_path / "b", serial="0012", seed=2)
    later = replace(later, device_model="ICM-20602", checks=[*later.checks, passed])
    with pytest.raises(StaleCheckError) as info:
        archive_run(archive, later, {})
    assert "describes the unit as model 'MPU-6000' by 'InvenSense'" in str(info.value)
    assert is_transient(info.value)  # the batch processes the run again
    with archive.engine().connect() as conn:
        assert conn.exec_driver_sql("SELECT count(*) FROM runs").scalar() == 1
    # The same run with its check failed (as a fresh check makes it) is archived.
    failed = replace(passed, passed=False, detail="serial 0012 is archived as ...")
    relabelled = replace(later, checks=[*later.checks[:-1], failed])
    assert archive_run(archive, relabelled, {}).status == "ok"


def test_a_run_of_the_unit_committing_meanwhile_is_waited_for(archive, tmp_path: Path) -> None:  # noqa: ANN001
    """A writer holds the unit (as archive_run does, PostgreSQL: its advisory lock;
    SQLite: the write lock) and commits a run under another model: a run whose check
    passed before that waits for it, then is refused rather than archived unflagged."""
    archive_run(archive, make_run(tmp_path / "a", serial="0012", seed=1), {})
    passed = CheckResult("device:description", None, None, True, SAME_DESCRIPTION)
    later = make_run(tmp_path / "b", serial="0012", seed=2)
    later = replace(later, checks=[*later.checks, passed])
    outcome: list[BaseException | str] = []

    def archive_later() -> None:
        try:
            outcome.append(archive_run(archive, later, {}).status)
        except StaleCheckError as exc:
            outcome.append(exc)

    engine = archive.engine().execution_options(sqlite_begin="IMMEDIATE")
    with engine.begin() as conn:
        if conn.dialect.name == "postgresql":
            conn.execute(
                text("SELECT pg_advisory_xact_lock(:k, hashtext('0012'))"), {"k": PG_UNIT_LOCK}
            )
        device = conn.execute(select(Device.id).where(Device.serial == "0012")).scalar_one()
        conn.execute(
            insert(Run).values(
                run_id="R0000000000ff",
                device_id=device,
                started_at=datetime(2024, 6, 1, tzinfo=UTC),
                procedure="six_position",
                site={},
                gravity=9.81,
                environment={},
                raw_hash="f" * 64,
                model="ICM-20602",
                manufacturer="TDK",
                run_dir="runs/x",
            )
        )
        worker = threading.Thread(target=archive_later)
        worker.start()
        time.sleep(1.5)  # the worker checks its plan and reaches the unit's lock
        assert worker.is_alive() and not outcome
    worker.join(timeout=60)
    assert len(outcome) == 1 and isinstance(outcome[0], StaleCheckError), outcome
    assert "run R0000000000ff, archived while this run was checked" in str(outcome[0])
