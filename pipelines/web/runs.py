"""Pages of runs: the filtered, paged, sortable list; one run; a value's lineage; raw
files and the run's downloads (protocol, HTML/PDF certificate, canonical JSON and the
exports of `calib export`: PX4, ArduPilot, CSV, MATLAB)."""

from __future__ import annotations

from datetime import UTC
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, HTMLResponse, Response
from starlette.exceptions import HTTPException

from calib_core import params
from pipelines.reports.display import (
    RESIDUAL_UNITS,
    check_counts,
    record_notes,
    shown,
    solve_warnings,
    tolerance_text,
)
from pipelines.web import forms, svg
from pipelines.web.pages import render
from pipelines.web.present import display
from storage import queries
from storage.naming import check_safe_name

if TYPE_CHECKING:  # its decision rules' statistics (scipy) imported by the run page
    from calib_core.tolerances import ToleranceProfile
    from storage.queries.records import Revision, RunSummary

router = APIRouter()

FILTERS = ("serial", "model", "from", "to", "procedure", "verdict", "temp_min", "temp_max")
LIST_PARAMS = (*FILTERS, "sort", "order", "page", "per_page")


@router.get("/runs", response_class=HTMLResponse)
def runs_list(request: Request) -> HTMLResponse:
    """The runs (current revision each), filtered, sorted and paged."""
    archive = request.app.state.archive
    q = forms.params(request, LIST_PARAMS)
    sort = forms.choice(q, "sort", queries.SORTS, "started")
    order = forms.choice(q, "order", ("asc", "desc"), "desc")
    per_page = int(forms.choice(q, "per_page", [str(n) for n in queries.PER_PAGE], "50"))
    page = forms.integer(q, "page", 1, 1, queries.MAX_PAGE)
    f = forms.checked(
        queries.run_filter,
        serial=q.get("serial"),
        model=q.get("model"),
        date_from=q.get("from"),
        date_to=q.get("to"),
        procedure=q.get("procedure"),
        verdict=q.get("verdict"),
        env_temp_min=q.get("temp_min"),
        env_temp_max=q.get("temp_max"),
    )
    result = queries.runs_page(
        archive, f, sort=sort, descending=order == "desc", page=page, per_page=per_page
    )
    kept = {k: q[k] for k in FILTERS if q.get(k)}
    return render(
        request,
        "runs.html",
        title="Runs",
        result=result,
        filters=kept,
        sort=sort,
        order=order,
        per_page=per_page,
        choices=_choices(request),
        verdicts=queries.VERDICTS,
        per_pages=queries.PER_PAGE,
    )


def _choices(request: Request) -> dict[str, list[str]]:
    """Models and procedures for the filter form (cached for a minute: distinct scans)."""
    import time

    cache = getattr(request.app.state, "choices", None)
    if cache is None or time.monotonic() - cache[0] > 60.0:
        cache = (time.monotonic(), queries.choices(request.app.state.archive))
        request.app.state.choices = cache
    return cache[1]


def _run_id(run_id: str) -> str:
    return forms.checked(check_safe_name, run_id, "run id")


def archived_thresholds(cal: Revision) -> ToleranceProfile | None:
    """The tolerance profile archived with the verdict (the check step's settings)."""
    from calib_core.tolerances import ToleranceProfile

    doc = cal.step_settings("check").get("thresholds")
    try:
        return None if doc is None else ToleranceProfile.from_dict(doc)
    except (ValueError, KeyError, TypeError):
        return None


def _parameter_rows(cal: Revision) -> list[dict[str, Any]]:
    """Each parameter value with its display form and its tolerance check."""
    checks = {c.name: c for c in cal.checks}
    rows = []
    for p in cal.parameters:
        check = checks.get(p.name) or checks.get(f"param:{p.name}")
        rows.append(
            {
                **p.to_dict(),
                "display_unit": display(p.name, p.value)[1],
                "shown": shown(p.name, p.value, p.std),
                "check": check,
                "display_limit": tolerance_text(p.name, check, "±") or None,
            }
        )
    return rows


@router.get("/runs/{run_id}", response_class=HTMLResponse)
def run_page(request: Request, run_id: str) -> HTMLResponse:
    """Everything about one run and its current calibration revision."""
    archive = request.app.state.archive
    forms.params(request, ())
    summary = forms.checked(queries.run_summary, archive, _run_id(run_id))
    cal = summary.calibration
    revs = queries.revisions(archive, run_id)
    day = summary.started_at.astimezone(UTC).date()
    equipment = [
        {
            **e.to_dict(),
            "valid_at_run": None if e.calibration_due is None else day <= e.calibration_due,
            "state_now": queries.due_state(e.calibration_due),
        }
        for e in summary.equipment
    ]
    from calib_core.condition_rules import status as condition_status

    profile = archived_thresholds(cal)
    residuals = cal.document.get("residuals") or []
    limits = profile.residual_limits if profile else {}
    charts = [svg.residual_chart(residuals, s, *RESIDUAL_UNITS[s], limits) for s in ("acc", "gyr")]
    return render(
        request,
        "run.html",
        title=f"Run {run_id}",
        s=summary,
        revisions=revs,
        equipment=equipment,
        parameters=_parameter_rows(cal),
        charts=[c for c in charts if c],
        profile=profile,
        counts=check_counts(cal.checks),
        failed=[c for c in cal.checks if condition_status(c) == "fail"],
        notes=record_notes(cal.checks, solve_warnings(cal)),
        validations=validation_tables(summary),
    )


def validation_tables(summary: RunSummary) -> list[dict[str, Any]]:
    """The revision's validation records as the run page shows them: per peer its line
    (pipelines.validation.compare.peer_line) and its rows, numbers as text."""
    from pipelines.reports.validation import peer_line, row_texts

    return [
        {
            "id": v.id,
            "created_at": v.created_at,
            "peers": [
                {
                    "line": peer_line(p),
                    "rows": [row_texts(r) for r in p["parameters"]],
                    "notes": p.get("notes", []),
                }
                for p in v.document["peers"]
            ],
        }
        for v in summary.validations
    ]


@router.get("/runs/{run_id}/lineage/{name}", response_class=HTMLResponse)
def lineage_page(request: Request, run_id: str, name: str) -> HTMLResponse:
    """Where one archived value comes from: raw bytes, steps and settings, software, equipment."""
    archive = request.app.state.archive
    q = forms.params(request, ("revision",))
    revision = forms.integer(q, "revision", 0, 1, 1_000_000) or None
    forms.checked(params.validate, name)
    lin = forms.checked(queries.lineage, archive, _run_id(run_id), name, revision)
    values = [
        {**v, "display": display(name, v["value"]), "display_std": display(name, v["std"])[0]}
        for v in lin["parameter"]["values"]
    ]
    return render(
        request,
        "lineage.html",
        title=f"Lineage of {name} in {run_id}",
        lin=lin,
        values=values,
        name=name,
    )


@router.get("/runs/{run_id}/raw/{name}")
def raw_file(request: Request, run_id: str, name: str) -> FileResponse:
    """The archived bytes of one raw file of the run (as hashed at ingest)."""
    archive = request.app.state.archive
    forms.params(request, ())
    summary = forms.checked(queries.run_summary, archive, _run_id(run_id))
    entry = next((r for r in summary.raw_files if r.name == name), None)
    if entry is None:
        raise HTTPException(404, f"run {run_id} has no raw file {name!r}")
    root = archive.root.resolve()
    path = (root / entry.stored_path).resolve()
    if not path.is_relative_to(root) or not path.is_file():
        raise HTTPException(404, f"raw file {name!r} of run {run_id} is missing from the store")
    return FileResponse(
        path, media_type="application/octet-stream", filename=Path(name).name or "raw.bin"
    )


def _issued(archive, run_id: str, kind: str) -> Path:  # noqa: ANN001 - Archive
    """The archived file `kind` ("protocol", "html", "pdf") of the run's issued certificate."""
    from pipelines.reports.issue import PROTOCOL, issued, protocol_of

    full = _run_id(run_id)
    run = forms.checked(queries.run_summary, archive, full)  # 404 for an unknown run
    current = issued(archive, full)
    path = None if current is None else current.files.get(kind)
    if path is None and kind == PROTOCOL:  # archived with the run, issued or not
        path = protocol_of(archive, run)
    if path is None:
        raise HTTPException(
            404,
            f"run {full} has no issued certificate: `calib report {full}` "
            "issues it into the archive",
        )
    root = archive.root.resolve()
    path = path.resolve()
    if not path.is_relative_to(root) or not path.is_file():
        raise HTTPException(
            404,
            f"the issued {kind} of run {full} is missing from the archive "
            "(`calib verify` reports it)",
        )
    return path


def _archived_file(request: Request, run_id: str, kind: str, media_type: str) -> FileResponse:
    """The run's issued file `kind` ("protocol", "html", "pdf"), as archived."""
    forms.params(request, ())
    path = _issued(request.app.state.archive, run_id, kind)
    return FileResponse(path, media_type=media_type, filename=path.name)


@router.get("/runs/{run_id}/protocol.txt")
def protocol(request: Request, run_id: str) -> Response:
    """The test protocol (MPU-6000 layout) archived with the run."""
    return _archived_file(request, run_id, "protocol", "text/plain; charset=utf-8")


@router.get("/runs/{run_id}/certificate.html")
def certificate_html(request: Request, run_id: str) -> Response:
    """The issued HTML certificate (a download: it embeds its plots as PNG)."""
    return _archived_file(request, run_id, "html", "text/html; charset=utf-8")


@router.get("/runs/{run_id}/certificate.pdf")
def certificate_pdf(request: Request, run_id: str) -> Response:
    """The issued PDF certificate, as archived (never rendered by the server)."""
    return _archived_file(request, run_id, "pdf", "application/pdf")


@router.get("/runs/{run_id}/export.{fmt}")
def export_file(request: Request, run_id: str, fmt: str) -> Response:
    """The calibration of the current (or a given) revision as `calib export` writes it: the
    canonical JSON, a PX4 or ArduPilot parameter file, CSV or MATLAB file (docs/exports.md),
    with the unit's current thermal model; what the format cannot carry is listed in the file.
    PX4: ``?device_id=`` names the sensor when the run's log did not (else 400 naming it)."""
    from pipelines.run_export import FORMATS, export_run

    if fmt not in FORMATS:
        raise HTTPException(404, f"no export format {fmt!r}; formats: {', '.join(FORMATS)}")
    q = forms.params(request, ("revision", "device_id"))
    revision = forms.integer(q, "revision", 0, 1, 1_000_000) or None
    device = forms.integer(q, "device_id", 0, 1, 2**32 - 1) or None  # PX4: else the log's ids
    result = forms.checked(
        export_run,
        request.app.state.archive,
        _run_id(run_id),
        fmt,
        revision=revision,
        accel_id=device,
        gyro_id=device,
    )
    return _download(result.data, result.media_type, result.filename)


def _download(data: bytes, media_type: str, filename: str) -> Response:
    safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in filename)
    return Response(
        data,
        media_type=media_type,
        headers={"Content-Disposition": f'attachment; filename="{safe}"'},
    )
