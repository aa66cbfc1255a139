"""Signed approval (storage.approval) and the audit trail on the command line.

Known truth: the run `fill` archived and the key made here. A signature checks
only for the exact record signed: one changed value must make it fail, a
changed approval event must make its signature fail, a wrong passphrase must
not open the key.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_seal import _tamper
from test_verify_backup import cli, fill

from storage.approval import ApprovalError, approvals, approve, generate_key, load_key
from storage.db import Archive
from storage.verify import verify

PASS = "correct horse battery"


@pytest.fixture
def key(tmp_path: Path) -> Path:
    path = tmp_path / "keys" / "jane.key"
    path.parent.mkdir()
    generate_key(path, "Jane Approver", PASS)
    return path


def _signature_problems(archive: Archive) -> list[str]:
    return [p.detail for p in verify(archive, orphans=False).problems if p.kind == "signature"]


def test_approve_verify_tamper_verify_fails(
    archive: Archive, tmp_path: Path, key: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ids = fill(archive, tmp_path)
    monkeypatch.setenv("CALIB_KEY_PASSPHRASE", PASS)
    monkeypatch.setenv("CALIB_USER", "jane")
    res = cli(archive, "approve", ids[1][:8], "--key", str(key), monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    assert f"run {ids[1]} revision 1 approved by Jane Approver" in res.output
    (a,) = approvals(archive, ids[1])
    assert (a.meaning, a.signer, a.revision) == ("approved", "Jane Approver", 1)
    assert a.public_key == json.loads(key.with_name("jane.key.pub").read_text())["public_key"]
    assert verify(archive, orphans=False).ok

    res = cli(archive, "audit", ids[1], monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    lines = res.stdout.strip().splitlines()
    assert [line.split("\t")[3] for line in lines] == ["archived", "approved"]
    assert "\tjane\tapproved\t" in lines[1] and "approved by Jane Approver" in lines[1]

    # One value of the approved record changed: the approval no longer holds.
    _tamper(
        archive,
        "UPDATE check_results SET value = 0 WHERE calibration_id = "
        "(SELECT c.id FROM calibrations c JOIN runs r ON r.id = c.run_id "
        "WHERE r.run_id = :r)",
        r=ids[1],
    )
    found = _signature_problems(archive)
    assert len(found) == 1 and "approved by Jane Approver" in found[0], found
    assert "no longer holds" in found[0]
    res = cli(archive, "verify", "--no-orphans", monkeypatch=monkeypatch)
    assert res.exit_code == 1 and "SIGNATURE" in res.stdout
    # and the changed record is not signed again
    with pytest.raises(ApprovalError, match="no longer match its seal"):
        approve(archive, ids[1], load_key(key, PASS), signer="Jane Approver")


def test_a_forged_approval_does_not_verify(archive: Archive, tmp_path: Path, key: Path) -> None:
    ids = fill(archive, tmp_path)
    approve(archive, ids[0], load_key(key, PASS), signer="Jane Approver", meaning="reviewed")
    assert verify(archive, orphans=False).ok
    # the signer's name changed in the stored event: the signature is over the old one
    _tamper(
        archive,
        "UPDATE audit_events SET detail = :d WHERE action = 'approved'",
        d=json.dumps({**_detail(archive), "signer": "Chief Metrologist"}),
    )
    found = _signature_problems(archive)
    assert len(found) == 1 and "does not verify" in found[0], found


def _detail(archive: Archive) -> dict:
    from sqlalchemy import select

    from storage.schema import AuditEvent

    with archive.engine().connect() as conn:
        return conn.execute(
            select(AuditEvent.detail).where(AuditEvent.action == "approved")
        ).scalar_one()


def test_keys_are_protected_and_never_overwritten(tmp_path: Path, key: Path) -> None:
    with pytest.raises(ApprovalError, match="wrong passphrase"):
        load_key(key, "not the passphrase")
    with pytest.raises(FileExistsError):
        generate_key(key, "Someone Else", PASS)
    with pytest.raises(ValueError, match="passphrase"):
        generate_key(tmp_path / "short.key", "X", "short")
    assert key.stat().st_mode & 0o077 == 0  # readable by its owner only


def test_audit_lists_by_serial_and_since(
    archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ids = fill(archive, tmp_path)
    res = cli(archive, "audit", "0012", "--json", monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    events = json.loads(res.stdout)
    # serial 0012: its two runs archived, then the first one revised with the reason recorded
    assert [(e["action"], e["run_id"]) for e in events] == [
        ("archived", ids[0]),
        ("archived", ids[1]),
        ("revised", ids[0]),
    ]
    assert events[2]["reason"].startswith("processed again (no reason given): settings")
    res = cli(archive, "audit", "--since", "2999-01-01", "--json", monkeypatch=monkeypatch)
    assert json.loads(res.stdout) == []
    res = cli(archive, "audit", "--since", "yesterday", monkeypatch=monkeypatch)
    assert res.exit_code == 2 and "since" in res.output


@pytest.mark.slow
def test_the_certificate_shows_the_approval(tmp_path: Path, key: Path) -> None:
    """A real run (the MPU-6000 sample through the pipeline): its certificate says
    NOT APPROVED, then who approved it and when, then that the approval no longer holds."""
    from pipelines.ingest import discover_runs
    from pipelines.process import process_run
    from pipelines.reports.run_reports import report_run
    from storage.db import resolve_archive

    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    samples = Path(__file__).resolve().parent.parent / "data_samples" / "mpu6000_MPU0001"
    (source,) = discover_runs([samples])
    run_id = process_run(source, arch)["run_id"]

    def certificate() -> str:
        written = report_run(arch, run_id, tmp_path / "out", pdf=False)
        return Path(written["html"]).read_text()

    assert "NOT APPROVED" in certificate()
    event = approve(arch, run_id, load_key(key, PASS), signer="Jane Approver")
    page = certificate()
    assert "NOT APPROVED" not in page and "Electronically approved" in page
    assert f"Jane Approver, {event.at.isoformat()[:19].replace('T', ' ')} UTC" in page
    _tamper(arch, "UPDATE runs SET operator = 'Mallory' WHERE run_id = :r", r=run_id)
    page = certificate()
    assert "NO LONGER VALID" in page and "NOT APPROVED" in page
    arch.dispose()
