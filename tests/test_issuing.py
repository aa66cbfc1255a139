"""Certificates of a batch issued beside its next runs (pipelines.issuing): queued on the
batch's certificate thread, every one issued and sealed by the time the batch returns.

Real runs of data_samples/ through `process_in_process` into a real SQLite archive.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pipelines.direct import process_in_process
from pipelines.ingest import discover_runs
from pipelines.issuing import issue_certificate, issuing_beside
from pipelines.reports.issue import issued
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
    with issuing_beside():
        queued = issue_certificate(arch, outcome["run_id"])
        assert queued is not None  # on the batch's thread, not done in the caller
    assert queued.done() and queued.exception() is None  # the block waited for it
    assert issued(arch, outcome["run_id"]).number == f"{outcome['run_id']}-1"
