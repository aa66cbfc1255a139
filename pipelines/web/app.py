"""The archive browser's FastAPI application: the routers, error pages, read-only methods.

Every page is rendered on the server (pipelines.web.pages); charts are inline SVG;
there is no JavaScript and nothing is fetched from elsewhere. The archive is
opened read-only (storage.queries.open_readonly) and only GET (and HEAD) routes exist.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from starlette.exceptions import HTTPException

from pipelines.web import due, equipment, impact, navigation, runs, units
from pipelines.web.pages import SECURITY_HEADERS, freeze_imports, render, unfreeze_imports
from storage.db import Archive


@contextlib.asynccontextmanager
async def _lifespan(_app: FastAPI) -> AsyncIterator[None]:
    """At start, the imported libraries' objects out of the garbage collector's sight
    (`pipelines.web.pages.freeze_imports`); the pages that import more freeze again."""
    freeze_imports()
    try:
        yield
    finally:
        unfreeze_imports()


MAX_ECHO = 80  # characters of one word of a request echoed into an error page


def clipped(message: str) -> str:
    """`message` with every word longer than MAX_ECHO characters cut (a query value of
    100,000 characters is named by its length, not echoed back)."""
    import re

    def cut(m: re.Match[str]) -> str:
        return f"{m.group()[: MAX_ECHO // 2]}... ({len(m.group())} characters)"

    return re.sub(rf"\S{{{MAX_ECHO + 1},}}", cut, message)


def create_app(archive: Archive) -> FastAPI:
    """The application on a read-only archive (storage.queries.open_readonly)."""
    app = FastAPI(
        title="imu-calib archive",
        docs_url=None,
        redoc_url=None,
        openapi_url=None,
        lifespan=_lifespan,
    )
    app.state.archive = archive
    for module in (runs, units, equipment, due, impact, navigation):
        app.include_router(module.router)

    @app.get("/", include_in_schema=False)
    def index() -> RedirectResponse:
        return RedirectResponse("/runs", status_code=303)

    @app.exception_handler(HTTPException)
    async def _http_error(request: Request, exc: HTTPException) -> HTMLResponse:
        return render(
            request,
            "error.html",
            exc.status_code,
            title=f"Error {exc.status_code}",
            status=exc.status_code,
            message=clipped(str(exc.detail)),
        )

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> HTMLResponse:
        msgs = [
            f"{'.'.join(str(p) for p in e.get('loc', ())[1:]) or 'request'}: {e.get('msg')}"
            for e in exc.errors()
        ]
        return render(
            request,
            "error.html",
            400,
            title="Error 400",
            status=400,
            message=clipped("; ".join(msgs)),
        )

    @app.middleware("http")
    async def _read_only(request: Request, call_next):  # noqa: ANN001, ANN202
        if request.method not in ("GET", "HEAD"):
            return HTMLResponse(
                "the archive browser is read-only",
                status_code=405,
                headers={"Allow": "GET, HEAD", **SECURITY_HEADERS},
            )
        head = request.method == "HEAD"
        if head:  # answered as GET without the body (the routes are GET routes)
            request.scope["method"] = "GET"
        response = await call_next(request)
        for k, v in SECURITY_HEADERS.items():
            response.headers.setdefault(k, v)
        if head:
            return Response(status_code=response.status_code, headers=dict(response.headers))
        return response

    return app
