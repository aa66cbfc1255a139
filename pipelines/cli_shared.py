"""The `calib` command's shared parts: the Typer app, consoles, common options, output helpers.

`pipelines.cli` defines the run commands and imports `pipelines.commands`; the command
modules import these from here, never from `pipelines.cli`, so imports go one way.
"""

from __future__ import annotations

import json
import os
import sys
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

import pipelines  # noqa: F401 - sets the no-telemetry environment before Prefect loads

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="IMU calibration pipeline and archive."
)


def _version(show: bool) -> None:
    if show:
        from calib_core import __version__  # no numpy: calib_core/__init__ holds the version only

        sys.stdout.write(f"calib {__version__}\n")
        raise typer.Exit()


out = Console()
err = Console(stderr=True)

ArchiveOpt = Annotated[
    str | None,
    typer.Option(
        "--archive",
        envvar="CALIB_ARCHIVE",
        help="Archive directory or SQLAlchemy URL (default ./calib-archive).",
    ),
]


@app.callback()
def _main(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
) -> None:
    """IMU calibration pipeline and archive."""
    # A full disk, a read-only archive, a missing permission: one line saying which
    # file and what to do instead of a traceback (typer has set its own hook by now).
    previous = sys.excepthook

    def explain(kind, exc, tb) -> None:  # noqa: ANN001 - sys.excepthook's signature
        from storage.write_failures import describe

        problem = describe(exc, os.environ.get("CALIB_ARCHIVE"))
        if problem is None:
            previous(kind, exc, tb)
        else:
            err.print(f"[red]error:[/red] {problem}")

    sys.excepthook = explain


def open_archive(arg: str | None):
    from storage.db import resolve_archive

    arch = resolve_archive(arg)
    arch.upgrade()
    return arch


def open_run(archive_arg: str | None, run_id: str):  # noqa: ANN201 - (Archive, str)
    """The archive and the full id of the run that `run_id` names (the id or a unique
    prefix, as git takes them); a clear error and exit 2 otherwise."""
    from storage import queries

    arch = open_archive(archive_arg)
    try:
        return arch, queries.full_run_id(arch, run_id)
    except (LookupError, ValueError) as exc:
        fail(str(exc))


def fail(message: str) -> None:
    err.print(f"[red]error:[/red] {message}")
    raise typer.Exit(2)


def frame_records(df: Any) -> list[dict[str, Any]]:
    """A DataFrame's rows as JSON-ready dicts (dates in ISO 8601)."""
    return json.loads(df.to_json(orient="records", date_format="iso"))


def print_json(doc: Any) -> None:
    sys.stdout.write(json.dumps(doc, indent=2, default=str) + "\n")


def print_frame(df, title: str) -> None:
    table = Table(title=title)
    for col in df.columns:
        table.add_column(str(col))
    for row in df.itertuples(index=False):
        table.add_row(*("" if v is None else str(v) for v in row))
    out.print(table)
