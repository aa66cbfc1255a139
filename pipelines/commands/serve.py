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
    from storage.browse import open_readonly
    from storage.db import resolve_archive

    try:
        ro = open_readonly(resolve_archive(archive), reader_role)
    except (FileNotFoundError, LookupError, PermissionError, ValueError) as exc:
        fail(f"{exc}")
    message = f"serving {ro.display_url} read-only on http://{host}:{port}/ (Ctrl-C stops)"

    class Announcing(uvicorn.Server):
        """Says "serving" once the socket accepts connections, not before."""

        async def startup(self, sockets=None) -> None:  # noqa: ANN001 - uvicorn's signature
            await super().startup(sockets)
            if self.started:
                err.print(message, soft_wrap=True)

    config = uvicorn.Config(create_app(ro), host=host, port=port, log_level="warning")
    Announcing(config).run()
