"""The "due" page of the archive browser: units to recall, each with its recalibration
interval from its own and its fleet's drift (pipelines/recall.py, docs/interval.md)."""

from __future__ import annotations

from datetime import date

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse
from starlette.exceptions import HTTPException

from pipelines.web import forms
from pipelines.web.pages import render

router = APIRouter()


@router.get("/due", response_class=HTMLResponse)
def due_page(request: Request) -> HTMLResponse:
    """Every unit's due date, or those due on or before ``before`` (YYYY-MM-DD)."""
    from pipelines.recall import recall_list

    q = forms.params(request, ("before",))
    text = q.get("before", "")
    try:
        before = date.fromisoformat(text) if text else None
    except ValueError:
        raise HTTPException(400, f"before: expected a date YYYY-MM-DD, got {text!r}") from None
    items = forms.checked(recall_list, request.app.state.archive, before)
    return render(
        request,
        "due.html",
        title="Due for recalibration",
        items=items,
        before=text,
        today=date.today().isoformat(),
    )
