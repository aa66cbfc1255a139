"""`calib serve`: the read-only web browser of the archive (pipelines/web, docs/serve.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli_shared import ArchiveOpt, app, err, fail, fail_on


@app.command()
def serve(
    archive: ArchiveOpt = None,
    host: Annotated[str, typer.Option("--host", help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="TCP port.")] = 8000,
    reader_role: Annotated[
        str,
        typer.Option("--reader-role", help="PostgreSQL: the read-only role to act as."),
    ] = "calib_reader",
    users: Annotated[
        Path | None,
        typer.Option(
            "--users",
            help="Users and scrypt password hashes (calib serve-user): "
            "every page asks for a login. Needed on any address but loopback.",
        ),
    ] = None,
    proxy_user_header: Annotated[
        str | None,
        typer.Option(
            "--proxy-user-header",
            help="Behind a reverse proxy that logs users in "
            "and sets this header (docs/serve.md): requests without it are refused.",
        ),
    ] = None,
) -> None:
    """Browse the archive in a web browser (read-only: runs, units, fleets, equipment)."""
    import uvicorn

    from pipelines.web.app import create_app
    from pipelines.web.auth import is_loopback, load_users, require_login
    from storage.db import resolve_archive
    from storage.queries import open_readonly

    if not is_loopback(host) and users is None and not proxy_user_header:
        fail(
            f"--host {host} is reachable from other machines: a login is required; give "
            "--users FILE (calib serve-user FILE NAME makes it) or --proxy-user-header NAME "
            "behind a reverse proxy that logs users in (docs/serve.md)"
        )
    try:
        known = load_users(users) if users is not None else None
        ro = open_readonly(resolve_archive(archive), reader_role)
    except (FileNotFoundError, LookupError, PermissionError, ValueError) as exc:
        fail(f"{exc}")
    app = create_app(ro)
    if known is not None or proxy_user_header:
        require_login(app, known, proxy_user_header)
    login = " with a login" if known is not None or proxy_user_header else ""
    message = f"serving {ro.display_url} read-only{login} on http://{host}:{port}/ (Ctrl-C stops)"

    class Announcing(uvicorn.Server):
        """Says "serving" once the socket accepts connections, not before."""

        async def startup(self, sockets=None) -> None:  # noqa: ANN001 - uvicorn's signature
            await super().startup(sockets)
            if self.started:
                err.print(message, soft_wrap=True)

    config = uvicorn.Config(app, host=host, port=port, log_level="warning")
    Announcing(config).run()


@app.command("serve-user")
def serve_user(
    users: Annotated[Path, typer.Argument(help="The users file (made if missing, mode 600).")],
    name: Annotated[str, typer.Argument(help="The user's login name.")],
) -> None:
    """Add a user to the users file of `calib serve --users` (password: env
    CALIB_SERVE_PASSWORD or asked), stored as a scrypt hash."""
    import os

    from pipelines.web.auth import add_user

    password = os.environ.get("CALIB_SERVE_PASSWORD") or typer.prompt(
        f"Password of {name}", hide_input=True, confirmation_prompt=True
    )
    with fail_on(ValueError):
        add_user(users, name, password)
    err.print(f"user {name} added to {users}")
