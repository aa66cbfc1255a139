"""Pages of equipment (due dates, runs made while its calibration had lapsed) and of the
archive's integrity (storage.verify, on request: it re-reads every archived file)."""

from __future__ import annotations

import time

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse

from pipelines.web import forms
from pipelines.web.pages import render
from storage import queries

router = APIRouter()
LAPSED_LIST_MAX = 200  # rows listed (the count says how many there are), as the fleet lists


@router.get("/equipment", response_class=HTMLResponse)
def equipment_list(request: Request) -> HTMLResponse:
    """Every piece of equipment with its latest recorded due date and state today."""
    forms.params(request, ())
    items = [
        {**e, "state": queries.due_state(e["calibration_due"])}
        for e in queries.equipment_list(request.app.state.archive)
    ]
    return render(request, "equipment_list.html", title="Equipment", items=items)


@router.get("/equipment/item", response_class=HTMLResponse)
def equipment_item(request: Request) -> HTMLResponse:
    """One piece of equipment: its calibration periods as recorded with runs, lapsed runs."""
    archive = request.app.state.archive
    q = forms.params(request, ("kind", "serial"))
    kind, serial = q.get("kind", ""), q.get("serial", "")
    item = forms.checked(queries.equipment_item, archive, kind, serial)
    lapsed, n_lapsed = queries.lapsed_page(archive, kind, serial, LAPSED_LIST_MAX)
    return render(
        request,
        "equipment.html",
        title=f"Equipment {kind} {serial}",
        item=item,
        lapsed=lapsed,
        n_lapsed=n_lapsed,
        item_state=queries.due_state(
            max(
                (p["calibration_due"] for p in item["periods"] if p["calibration_due"]),
                default=None,
            )
        ),
    )


@router.get("/verify", response_class=HTMLResponse)
def verify_page(request: Request) -> HTMLResponse:
    """The archive's facts; with ``run=1`` the full integrity check (every file re-hashed)."""
    from storage.verify import verify

    archive = request.app.state.archive
    q = forms.params(request, ("run",))
    run = forms.choice(q, "run", ("0", "1"), "0") == "1"
    facts = queries.facts(archive)
    report, seconds = None, None
    if run:
        from pipelines.trust import lab_approvers

        t0 = time.perf_counter()
        report = verify(archive, orphans=True, approvers=forms.checked(lab_approvers))
        seconds = time.perf_counter() - t0
    return render(
        request, "verify.html", title="Verify", facts=facts, report=report, seconds=seconds
    )
