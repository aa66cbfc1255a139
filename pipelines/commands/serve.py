"""`calib serve`: the read-only web browser of the archive (pipelines/web, docs/serve.md)."""

from __future__ import annotations

from typing import Annotated

import typer

from pipelines.cli_shared import ArchiveOpt, app, err, fail


@app.command()
def serve(
    archive: ArchiveOpt = None,
    host: Annotated[str, typer.Option("--host", help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="TCP port.")] = 8000,
    reader_role: Annotated[
        str,
        typer.Option("--reader-role", help="PostgreSQL: the read-only role to act as."),
    ] = "calib_reader",
) -> None:
    """Browse the archive in a web browser (read-only: runs, units, fleets, equipment)."""
    import uvicorn

    from pipelines.web.app import create_app
    from storage.db import resolve_archive
    from storage.queries import open_readonly

    try:
        ro = open_readonly(resolve_archive(archive), reader_role)
    except (FileNotFoundError, LookupError, PermissionError, ValueError) as exc:
        fail(f"{exc}")
    err.print(f"serving {ro.display_url} read-only on http://{host}:{port}/ (Ctrl-C stops)")
    uvicorn.run(create_app(ro), host=host, port=port, log_level="warning")
