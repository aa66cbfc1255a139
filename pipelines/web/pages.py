"""The archive browser's pages: the Jinja2 environment, the security headers, `render`.

Every page is rendered on the server with autoescaping on (an archived string such as
``<script>alert(1)</script>`` is shown as text). The routers (runs, units, equipment)
render with `render`; the application (pipelines.web.app) includes the routers.
"""

from __future__ import annotations

import gc
import sys
from pathlib import Path
from typing import Any

import jinja2
from fastapi import Request
from fastapi.responses import HTMLResponse
from fastapi.templating import Jinja2Templates

from pipelines.web import present

TEMPLATES = Path(__file__).resolve().parent / "templates"
SECURITY_HEADERS = {
    # No script, no plugin, nothing from elsewhere: the pages need none of it.
    "Content-Security-Policy": "default-src 'none'; style-src 'unsafe-inline'; img-src 'self' "
    "data:; form-action 'self'; base-uri 'none'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}


def _environment() -> jinja2.Environment:
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(TEMPLATES),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters.update(present.FILTERS)
    env.globals.update(present.GLOBALS)
    return env


templates = Jinja2Templates(env=_environment())


_modules_frozen = 0  # len(sys.modules) at the last freeze_imports


def freeze_imports() -> None:
    """Move every object there is out of the garbage collector's sight (`gc.freeze`) when
    modules were imported since the last call: at start (the libraries' ~160k objects),
    then after the first page that imports the science stack it fits with. None of
    them is ever garbage, and a full collection scanning them every few fleet pages of
    a large archive cost more CPU than the pages."""
    global _modules_frozen
    if len(sys.modules) != _modules_frozen:
        gc.collect()
        gc.freeze()
        _modules_frozen = len(sys.modules)


def unfreeze_imports() -> None:
    """Back in the garbage collector's sight (at shutdown: an app started again in one
    process, tests, freezes afresh)."""
    global _modules_frozen
    gc.unfreeze()
    _modules_frozen = 0


def render(request: Request, template: str, status_code: int = 200, **context: Any) -> HTMLResponse:
    """Render `template` with `context` (plus the request and the archive's name)."""
    archive = request.app.state.archive
    context.setdefault("title", "")
    page = templates.TemplateResponse(
        request,
        template,
        {"archive_name": archive.display_url, **context},
        status_code=status_code,
        headers=SECURITY_HEADERS,
    )
    freeze_imports()
    return page
