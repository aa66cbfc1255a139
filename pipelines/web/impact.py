"""The impact pages of the archive browser: the applied out-of-tolerance look-backs
(`calib impact --apply`, docs/impact.md), one record's runs with the parameters that
moved and the verdicts before and after, and the record as PDF or CSV for the lab's
nonconformity record."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse, Response
from starlette.exceptions import HTTPException

from pipelines.web import forms
from pipelines.web.pages import render

router = APIRouter()


def _records(request: Request) -> list[dict[str, Any]]:
    from storage.queries.impact import impact_records

    return forms.checked(impact_records, request.app.state.archive)


def _record(request: Request, key: str) -> dict[str, Any]:
    forms.params(request, ())
    for rec in _records(request):
        if rec["key"] == key:
            return rec
    raise HTTPException(404, f"no impact record {key!r} in this archive")


def _texts(r: dict[str, Any]) -> list[str]:
    """What moved in a run: its corrected temperature (a chamber offset), the checks whose
    outcome changed, its parameters."""
    from pipelines.impact import checks_text, moved_text, temperature_text

    texts = [temperature_text(r), checks_text(r)]
    return [t for t in texts if t] + [moved_text(m) for m in r["moved"]]


@router.get("/impact", response_class=HTMLResponse)
def impact_list(request: Request) -> HTMLResponse:
    """Every applied look-back, newest first, with how many verdicts it changed."""
    forms.params(request, ())
    items = [
        {
            **rec,
            "n_runs": len(rec["runs"]),
            "n_changed": sum(r["verdict_before"] != r["verdict_after"] for r in rec["runs"]),
        }
        for rec in _records(request)
    ]
    return render(request, "impact_list.html", title="Impact records", items=items)


@router.get("/impact/{key}", response_class=HTMLResponse)
def impact_page(request: Request, key: str) -> HTMLResponse:
    """One look-back: the error, and per run the verdicts before and after and what moved."""
    rec = _record(request, key)
    runs = [{**r, "moved_text": _texts(r)} for r in rec["runs"]]
    return render(
        request,
        "impact.html",
        title=rec["reason"],
        rec=rec,
        runs=runs,
        n_changed=sum(r["verdict_before"] != r["verdict_after"] for r in runs),
    )


@router.get("/impact/{key}/report.pdf")
def impact_pdf(request: Request, key: str) -> Response:
    """The record typeset as PDF (pipelines.impact.pdf_report), for the nonconformity file."""
    from pipelines.impact import pdf_report, record_doc

    data = pdf_report(record_doc(_record(request, key)))
    return _download(data, "application/pdf", f"impact-{key}.pdf")


@router.get("/impact/{key}/report.csv")
def impact_csv(request: Request, key: str) -> Response:
    """The record as CSV, one row per run (pipelines.impact.CSV_COLUMNS)."""
    from pipelines.impact import csv_report, record_doc

    data = csv_report(record_doc(_record(request, key))).encode("utf-8")
    return _download(data, "text/csv; charset=utf-8", f"impact-{key}.csv")


def _download(data: bytes, media_type: str, filename: str) -> Response:
    return Response(
        data,
        media_type=media_type,
        headers={"Content-Disposition": f'attachment; filename="{filename}"'},
    )
