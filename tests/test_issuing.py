"""Certificates of a batch issued beside its next runs (pipelines.issuing): queued on the
batch's certificate thread, every one issued and sealed by the time the batch returns; one
that cannot be issued is said in its run's outcome and leaves no file behind.

Real runs of data_samples/ through `process_in_process` into a real SQLite archive.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from pipelines.direct import process_in_process
from pipelines.ingest import discover_runs
from pipelines.issuing import issue_certificate, issuing_beside
from pipelines.process import process_run
from pipelines.reports.issue import ISSUED, issued
from storage.db import resolve_archive
from storage.queries import certificate_issues as issues
from storage.verify import verify

SAMPLES = Path(__file__).resolve().parent.parent / "data_samples"
pytestmark = pytest.mark.usefixtures("issuing_certificates")


def test_a_batch_returns_with_every_certificate_issued(tmp_path) -> None:
    sources = discover_runs([SAMPLES / "mpu6000_MPU0001", SAMPLES / "csv_IMU-2026-0042"])
    archive = str(tmp_path / "archive")
    outcomes = process_in_process(sources, archive)
    arch = resolve_archive(archive)
    assert [o["status"] for o in outcomes] == ["ok", "ok"]
    for o in outcomes:
        current = issued(arch, o["run_id"])
        assert current is not None and current.files["pdf"].read_bytes().startswith(b"%PDF-")
        assert len(issues(arch, o["run_id"])) == 1
    assert verify(arch).ok


def test_inside_a_batch_the_issue_is_queued_and_waited_for(tmp_path, monkeypatch) -> None:
    archive = str(tmp_path / "archive")
    monkeypatch.setenv("CALIB_ISSUE_CERTIFICATES", "0")  # archived without its certificate
    (outcome,) = process_in_process(discover_runs([SAMPLES / "mpu6000_MPU0001"]), archive)
    monkeypatch.setenv("CALIB_ISSUE_CERTIFICATES", "1")
    arch = resolve_archive(archive)
    assert issued(arch, outcome["run_id"]) is None
    with issuing_beside() as certificates:
        assert issue_certificate(arch, outcome["run_id"]) is None  # queued: no failure yet
        ((run_id, queued),) = certificates.queued  # on the batch's thread, not the caller's
        assert run_id == outcome["run_id"]
    assert queued.done() and queued.result() is None  # the block waited for it: issued
    assert certificates.failures() == {}
    assert issued(arch, outcome["run_id"]).number == f"{outcome['run_id']}-1"


def _refuse_certificate_events(archive: str) -> None:
    """The archive's database refuses every `certificate issued` event (a trigger): the
    issue fails after its files are written, as a database that goes away would."""
    arch = resolve_archive(archive)
    arch.upgrade()
    with sqlite3.connect(arch.root / "archive.sqlite") as db:
        db.execute(
            "CREATE TRIGGER refuse_certificates BEFORE INSERT ON audit_events "
            f"WHEN NEW.action = '{ISSUED}' BEGIN SELECT RAISE(ABORT, 'refused by test'); END"
        )


def _certificate_files(archive: str) -> list[Path]:
    return sorted(Path(archive).rglob("*_certificate*"))


def test_a_certificate_not_issued_in_a_batch_is_said_in_its_runs_outcome(tmp_path) -> None:
    """The runs stay archived, each outcome says why its certificate was not issued and how
    to issue it, and no file of it is left without its event (nothing half-issued)."""
    archive = str(tmp_path / "archive")
    _refuse_certificate_events(archive)
    sources = discover_runs([SAMPLES / "mpu6000_MPU0001", SAMPLES / "csv_IMU-2026-0042"])
    outcomes = process_in_process(sources, archive)
    arch = resolve_archive(archive)
    assert [o["status"] for o in outcomes] == ["ok", "ok"]
    for o in outcomes:
        assert "certificate not issued" in o["message"] and "refused by test" in o["message"]
        assert f"calib report {o['run_id']}" in o["message"]
        assert issued(arch, o["run_id"]) is None and issues(arch, o["run_id"]) == []
    assert _certificate_files(archive) == []
    assert verify(arch).ok


def test_a_certificate_not_issued_alone_is_said_in_the_outcome(tmp_path) -> None:
    archive = str(tmp_path / "archive")
    _refuse_certificate_events(archive)
    (source,) = discover_runs([SAMPLES / "mpu6000_MPU0001"])
    outcome = process_run(source, resolve_archive(archive))
    assert outcome["status"] == "ok" and outcome["message"].startswith("archived")
    assert "; certificate not issued: " in outcome["message"]
    assert _certificate_files(archive) == []
