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


def _tidy_help(params: list[Any]) -> None:
    """Metavars for people: none on a flag (typer shows ``<bool>``), the option's name
    (``--archive ARCHIVE``) or its choices on the others, the argument's name in capitals."""
    from typer.core import TyperArgument, TyperOption

    for p in params:
        if p.metavar is not None:
            continue
        if isinstance(p, TyperOption):
            if p.is_flag or p.is_bool_flag:
                p.metavar = ""
            elif p.type_descriptor.is_choice:
                p.metavar = p.display_type(None).strip("<>")
            else:
                p.metavar = max(p.opts, key=len).lstrip("-").upper().replace("-", "_")
        elif isinstance(p, TyperArgument):
            p.metavar = (p.name or "").upper()
            p.display_type_rich = lambda ctx: None  # the name says it; no <str> column


class CalibGroup(typer.core.TyperGroup):
    """Typer's group with `_tidy_help` applied to its own and its commands' parameters."""

    def get_params(self, ctx):  # noqa: ANN001, ANN201 - click's signature
        params = super().get_params(ctx)
        _tidy_help(params)
        return params

    def get_command(self, ctx, cmd_name):  # noqa: ANN001, ANN201 - click's signature
        cmd = super().get_command(ctx, cmd_name)
        if cmd is not None:
            _tidy_help(cmd.get_params(ctx))
        return cmd


def sub_app(help: str) -> typer.Typer:  # noqa: A002 - typer's name
    """A group of subcommands (`calib query ...`) with the same help conventions."""
    return typer.Typer(cls=CalibGroup, no_args_is_help=True, help=help)


app = typer.Typer(
    cls=CalibGroup, no_args_is_help=True, help="IMU calibration pipeline and archive."
)

# `calib --help` lists the commands under these headings, by task (`group_commands`).
PANELS = {
    "Process": ("process", "reprocess", "centrifuge", "apply", "thermal"),
    "Inspect": ("inspect", "show", "history", "repeatability"),
    "Query": ("query", "trend", "fleet"),
    "Report": ("report", "serve"),
    "Export": ("export",),
    "Admin": ("verify", "backup", "restore"),
}


def group_commands() -> None:
    """Put every registered command and group under its `PANELS` heading.

    Raises
    ------
    LookupError : a command that no heading lists (add it to PANELS).
    """
    where = {name: panel for panel, names in PANELS.items() for name in names}
    for info in [*app.registered_commands, *app.registered_groups]:
        name = info.name or info.callback.__name__.replace("_", "-")
        if name not in where:
            raise LookupError(f"calib {name}: no help panel; add it to cli_shared.PANELS")
        info.rich_help_panel = where[name]


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
    verbose: Annotated[
        bool,
        typer.Option(
            "--verbose", "-v", help="Prefect's and the pipeline's progress logs on stderr."
        ),
    ] = False,
) -> None:
    """IMU calibration pipeline and archive."""
    quiet_logs(verbose)
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


def quiet_logs(verbose: bool) -> None:
    """Prefect's logs at warning level unless `verbose` (its INFO lines of every flow and
    task run are progress, which the progress bar and the result table already show).

    Set in the environment before Prefect is imported (commands import it when they
    need it), so the temporary API server it starts gets them too. Without --verbose
    that server reports only critical errors: the ones it logs when calib ends it while
    it still records task-run events (``Error flushing N events`` and a traceback) are
    about Prefect's own run history of a server that ends with calib, never about a run's
    outcome or the archive. A setting made by the user in the environment wins.
    """
    import logging

    if verbose:
        os.environ["PREFECT_LOGGING_LEVEL"] = "INFO"
        logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
        return
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    os.environ.setdefault("PREFECT_SERVER_LOGGING_LEVEL", "CRITICAL")


def open_archive(arg: str | None):
    from storage.db import open_archive as open_

    return open_(arg)


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


def print_facts(facts: dict[str, Any], title: str, paths: tuple[str, ...] = ()) -> None:
    """A flat dict as a two-column table (what, value); long values wrap, never cut.

    The values of the keys in `paths` (file paths) follow the table one per line, whole
    (``output: /the/path``): a path wrapped inside a cell cannot be copied.
    """
    table = Table(title=title, show_header=False)
    table.add_column("what", style="bold", no_wrap=True)
    table.add_column("value", overflow="fold")
    for key, value in facts.items():
        if key in paths:
            continue
        if isinstance(value, list):
            value = ", ".join(map(str, value)) or None
        table.add_row(_label(key), "-" if value is None else str(value))
    out.print(table)
    for key in paths:
        if facts.get(key) is not None:
            out.print(f"{_label(key)}: {facts[key]}", soft_wrap=True, markup=False, highlight=False)


def _label(key: str) -> str:
    """A JSON key for people: ``calibration_temperature_c`` -> ``calibration temperature (°C)``."""
    for suffix, unit in (("_c", "°C"), ("_s", "s"), ("_days", "days")):
        if key.endswith(suffix):
            return f"{key[: -len(suffix)].replace('_', ' ')} ({unit})"
    return key.replace("_", " ")


def warn(message: str) -> None:
    """A warning on stderr (markup in `message` is not interpreted)."""
    from rich.markup import escape

    err.print(f"[yellow]warning:[/yellow] {escape(message)}", soft_wrap=True)
