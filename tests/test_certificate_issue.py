"""The certificate issued at archive time: HTML and the PDF typeset from it (Typst),
written into the run's folder and sealed by an audit event; `calib report`, the web pages
and `calib verify` work on those archived files.

The MPU-6000 sample of data_samples/ goes through the real `process_run` into a real
SQLite archive; the PDF's text is read back with poppler's pdftotext.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from calib_testing.documents import html_words, pdf_pages
from pipelines.cli import app
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from pipelines.reports.issue import ISSUED, issued
from storage.db import resolve_archive
from storage.queries import certificate_issues as issues
from storage.verify import verify

SAMPLE = Path(__file__).resolve().parent.parent / "data_samples" / "mpu6000_MPU0001"
# Typesetting takes seconds per certificate: the slow tier.
pytestmark = [pytest.mark.usefixtures("issuing_certificates"), pytest.mark.slow]


def test_certificate_is_issued_and_sealed_when_archived(archived_sample) -> None:
    arch, run_id = archived_sample
    current = issued(arch, run_id)
    assert current is not None and current.issue == 1 and current.number == f"{run_id}-1"
    assert set(current.files) == {"protocol", "html", "pdf"}
    (event,) = [e for e in issues(arch, run_id)]
    for rel, sha in event["detail"]["files"].items():
        assert hashlib.sha256((arch.root / rel).read_bytes()).hexdigest() == sha
    assert {arch.root / rel for rel in event["detail"]["files"]} == {
        current.files["html"],
        current.files["pdf"],
    }
    assert verify(arch).ok


def test_every_word_of_the_html_certificate_is_in_the_pdf(archived_sample) -> None:
    """Typeset, not cut: each word of the HTML is in the PDF's text, the header and footer
    give the certificate number and "page x of y" on every page."""
    arch, run_id = archived_sample
    current = issued(arch, run_id)
    words = html_words(current.files["html"].read_text(encoding="utf-8"))
    pages = pdf_pages(current.files["pdf"])
    text = "\f".join(pages)
    found, joined = set(text.split()), "".join(text.split())
    # A word longer than its table cell (a SHA-256) is broken across lines: it is
    # then found with the line breaks taken out.
    missing = sorted({w for w in words if w not in found and w not in joined})
    assert len(words) > 500 and not missing, missing
    assert len(pages) >= 3
    for n, page in enumerate(pages, start=1):
        assert f"page {n} of {len(pages)}" in page
        assert page.count(f"Certificate {current.number}") >= 2  # header and footer


def test_calib_report_hands_out_the_archived_files_and_reissues(archived_sample, tmp_path) -> None:
    arch, run_id = archived_sample
    first = issued(arch, run_id)
    before = {k: p.read_bytes() for k, p in first.files.items()}
    args = ["report", run_id, "--archive", str(arch.root), "--json"]
    got = json.loads(CliRunner().invoke(app, args).stdout)
    assert got["certificate"] == first.number
    assert {k: Path(got[k]) for k in ("protocol", "html", "pdf")} == first.files
    copied = json.loads(CliRunner().invoke(app, [*args, "--output", str(tmp_path)]).stdout)
    assert Path(copied["pdf"]).read_bytes() == before["pdf"]
    assert len(issues(arch, run_id)) == 1  # handing out issues nothing

    result = CliRunner().invoke(app, [*args, "--reissue", "--reason", "lab profile completed"])
    assert result.exit_code == 0, result.output
    second = json.loads(result.stdout)
    assert second["certificate"] == f"{run_id}-1-2"
    assert Path(second["pdf"]) != first.files["pdf"]
    assert f"Certificate {run_id}-1-2" in "".join(pdf_pages(Path(second["pdf"])))
    assert {k: p.read_bytes() for k, p in first.files.items()} == before  # earlier issue kept
    events = issues(arch, run_id)
    assert [e["detail"]["issue"] for e in events] == [1, 2]
    assert issued(arch, run_id).number == f"{run_id}-1-2"
    assert verify(arch).ok


def test_verify_reports_a_changed_issued_certificate(tmp_path) -> None:
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    (source,) = discover_runs([SAMPLE])
    run_id = process_run(source, arch)["run_id"]
    pdf = issued(arch, run_id).files["pdf"]
    pdf.write_bytes(pdf.read_bytes() + b"%% one byte more than issued\n")
    report = verify(arch)
    assert not report.ok
    said = " ".join(p.detail for p in report.problems)
    assert re.search(rf"{run_id} revision 1: issued file \S+{pdf.name} changed", said), said
    pdf.unlink()
    assert "is missing" in " ".join(p.detail for p in verify(arch).problems)


def test_web_pages_serve_the_archived_files(archived_sample) -> None:
    from pipelines.web.app import create_app
    from storage.queries import open_readonly

    arch, run_id = archived_sample
    current = issued(arch, run_id)
    ro = open_readonly(arch)
    client = TestClient(create_app(ro))
    for url, kind in (
        ("certificate.pdf", "pdf"),
        ("certificate.html", "html"),
        ("protocol.txt", "protocol"),
    ):
        r = client.get(f"/runs/{run_id}/{url}")
        assert r.status_code == 200, r.text
        assert r.content == current.files[kind].read_bytes()
        assert "attachment" in r.headers["content-disposition"]
    ro.dispose()


def test_the_issue_event_is_in_the_audit_trail(archived_sample) -> None:
    arch, run_id = archived_sample
    result = CliRunner().invoke(app, ["audit", run_id, "--archive", str(arch.root), "--json"])
    assert result.exit_code == 0, result.output
    assert ISSUED in {e["action"] for e in json.loads(result.stdout)}


def test_certificate_shows_numbers_as_the_cli_does(archived_sample) -> None:
    """The Results table: each parameter as `pipelines.reports.display.shown` gives it."""
    from pipelines.reports.display import shown
    from storage import queries

    arch, run_id = archived_sample
    html = issued(arch, run_id).files["html"].read_text(encoding="utf-8")
    for p in queries.run_summary(arch, run_id).calibration.parameters:
        s = shown(p.name, p.value, p.std)
        assert f"<td>{p.name}</td><td>{s.value}</td><td>{s.u}</td><td>{s.unit}</td>" in html


def test_issue_can_wait_for_calib_report(tmp_path, monkeypatch) -> None:
    """CALIB_ISSUE_CERTIFICATES=0: archived without a certificate; `calib report` issues it."""
    monkeypatch.setenv("CALIB_ISSUE_CERTIFICATES", "0")
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    (source,) = discover_runs([SAMPLE])
    run_id = process_run(source, arch)["run_id"]
    assert issued(arch, run_id) is None and issues(arch, run_id) == []
    result = CliRunner().invoke(app, ["report", run_id, "--archive", str(arch.root), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["certificate"] == f"{run_id}-1"
    assert issued(arch, run_id).issue == 1 and verify(arch).ok
