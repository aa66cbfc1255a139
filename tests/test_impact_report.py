"""The impact record in `calib serve` and typeset for the nonconformity record: a rate
table found 120 ppm fast, its runs looked back on and applied (`calib impact --apply`)
into a real SQLite archive, served by the real application (TestClient), and the PDF
typeset by WeasyPrint read back with poppler's pdftotext."""

from __future__ import annotations

import csv
import io
import re

import pytest
from fastapi.testclient import TestClient
from test_impact import RATE_PPM, apply_rate_error, archive_rate_table_runs
from typer.testing import CliRunner

from calib_core.reference_errors import parse_error
from calib_testing.documents import html_words, pdf_pages
from pipelines.cli import app
from pipelines.impact import html_report, impact, pdf_report, record_doc
from storage import queries
from storage.db import resolve_archive
from storage.queries import open_readonly
from storage.queries.impact import calibration_temperatures, impact_records

REASON = f"out-of-tolerance reference RT-7: rate_error_ppm={RATE_PPM:g}"


@pytest.fixture(scope="module")
def applied(tmp_path_factory):
    """Two runs on RT-7 in March (one goes from pass to fail), one on RT-8; applied."""
    tmp = tmp_path_factory.mktemp("impact_report")
    arch = resolve_archive(str(tmp / "archive"))
    arch.upgrade()
    runs = archive_rate_table_runs(arch, tmp, "AEC")
    doc = apply_rate_error(arch)
    assert [r["status"] for r in doc["runs"]] == ["revised", "revised"]
    ro = open_readonly(arch)
    from pipelines.web.app import create_app

    with TestClient(create_app(ro)) as client:
        yield {"archive": arch, "runs": runs, "doc": doc, "client": client, "tmp": tmp}
    ro.dispose()


def test_the_archive_holds_the_applied_record(applied):
    (rec,) = impact_records(applied["archive"])
    assert rec["reason"] == REASON and rec["equipment_serial"] == "RT-7"
    assert rec["period"] == {"from": "2026-03-01", "to": "2026-03-31"}
    got = [
        (r["run_id"], r["verdict_before"], r["verdict_after"], r["revision"]) for r in rec["runs"]
    ]
    want = [
        (r["run_id"], r["verdict_before"], r["verdict_after"], 2) for r in applied["doc"]["runs"]
    ]
    assert sorted(got) == sorted(want)
    assert applied["runs"]["C"] not in {r["run_id"] for r in rec["runs"]}  # RT-8


def test_only_runs_in_the_period_and_on_that_equipment(applied):
    """The period's ends are whole UTC days, both inclusive; another table's runs never."""
    from pipelines.impact import select_runs

    arch, runs = applied["archive"], applied["runs"]
    error = parse_error("rate_error_ppm=1")
    for since, until, want in (
        ("2026-03-10", "2026-03-10", ["A"]),  # A started 09:00 that day
        ("2026-03-11", "2026-03-20", ["E"]),  # C (2026-03-11) is on RT-8
        ("2026-03-01", None, ["A", "E"]),
        ("2026-03-21", None, []),
    ):
        if not want:
            with pytest.raises(LookupError, match="no archived run used equipment 'RT-7'"):
                select_runs(arch, "RT-7", since, until, error)
            continue
        got = [r["run_id"] for r in select_runs(arch, "RT-7", since, until, error)]
        assert got == [runs[k] for k in want], (since, until)
    got = [r["run_id"] for r in select_runs(arch, "RT-8", "2026-03-11", "2026-03-11", error)]
    assert got == [runs["C"]]


def test_impact_pages_in_calib_serve(applied):
    client, doc = applied["client"], applied["doc"]
    listing = client.get("/impact")
    assert listing.status_code == 200
    assert REASON in listing.text and "2026-03-01 to 2026-03-31" in listing.text
    (key,) = re.findall(r'href="/impact/([0-9a-f]{12})"', listing.text)
    page = client.get(f"/impact/{key}")
    assert page.status_code == 200
    table = page.text[page.text.index('id="impact-runs"') :]
    for r in doc["runs"]:
        row = table[table.index(r["run_id"]) :].split("</tr>")[0]
        assert f"badge {r['verdict_before']}" in row and f"badge {r['verdict_after']}" in row
        for m in r["moved"]:
            assert f"{m['name']} {m['before']:.6g} -&gt; {m['after']:.6g}" in row
    assert "1 &rarr; 2" in table and "verdict(s) changed" in page.text
    assert applied["runs"]["C"] not in page.text
    assert "None" not in page.text and "nan" not in page.text.lower().split()
    assert client.get("/impact/000000000000").status_code == 404
    assert client.get(f"/impact/{key}?x=1").status_code == 400
    got = client.get(f"/impact/{key}/report.csv")
    rows = list(csv.DictReader(io.StringIO(got.text)))
    assert sorted((w["run_id"], w["verdict_before"], w["verdict_after"]) for w in rows) == sorted(
        (r["run_id"], r["verdict_before"], r["verdict_after"]) for r in doc["runs"]
    )
    pdf = client.get(f"/impact/{key}/report.pdf")
    assert pdf.status_code == 200 and pdf.content.startswith(b"%PDF-")
    assert pdf.headers["content-type"] == "application/pdf"


@pytest.mark.slow
def test_every_word_of_the_html_report_is_in_the_pdf(applied, tmp_path):
    """The applied record's report typeset, not cut; "page x of y" on every page."""
    (rec,) = impact_records(applied["archive"])
    doc = record_doc(rec)
    words = html_words(html_report(doc))
    pdf = tmp_path / "record.pdf"
    pdf.write_bytes(pdf_report(doc))
    pages = pdf_pages(pdf)
    text = "\f".join(pages)
    found, joined = set(text.split()), "".join(text.split())
    # A word longer than its table cell (a run id) is broken across lines: it is then
    # found with the line breaks taken out.
    missing = sorted({w for w in words if w not in found and w not in joined})
    assert not missing, missing
    # the report is the whole record: every run and every moved parameter is in it
    assert {r["run_id"] for r in rec["runs"]} <= set(words)
    moved = {m["name"] for r in rec["runs"] for m in r["moved"]}
    assert "gyr.scale.x" in moved and moved <= set(words)
    for n, page in enumerate(pages, start=1):
        assert f"page {n} of {len(pages)}" in page


@pytest.mark.slow
def test_calib_impact_writes_the_pdf(applied, tmp_path):
    """`calib impact ... --pdf FILE`: the look-back typeset; its run ids in the text."""
    pdf = tmp_path / "impact.pdf"
    res = CliRunner().invoke(
        app,
        ["impact", "RT-7", "--from", "2026-03-01", "--to", "2026-03-31",
         "--error", f"rate_error_ppm={RATE_PPM}", "--pdf", str(pdf), "--json",
         "--archive", str(applied["archive"].root)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    joined = "".join("".join(pdf_pages(pdf)).split())
    assert all(r["run_id"] in joined for r in applied["doc"]["runs"])
    assert "".join(REASON.split()) in joined


def test_impact_records_on_each_back_end(archive, tmp_path):
    """The record and the revision's temperature read back on SQLite and PostgreSQL."""
    run_id = archive_rate_table_runs(archive, tmp_path, "A")["A"]
    impact(archive, "RT-7", parse_error(f"rate_error_ppm={RATE_PPM}"), "2026-03-01", apply=True)
    (rec,) = impact_records(archive)
    assert rec["reason"] == REASON and rec["period"] == {"from": "2026-03-01", "to": None}
    assert [(r["run_id"], r["revision"], r["current"]) for r in rec["runs"]] == [(run_id, 2, True)]
    cal_id = queries.run_summary(archive, run_id).calibration.calibration_id
    assert calibration_temperatures(archive, [cal_id]) == {cal_id: 20.0}  # the manifest's
