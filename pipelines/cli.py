"""The `calib` command. Data goes to stdout (tables, or JSON with --json); logs go to stderr."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

import pipelines  # noqa: F401 - sets the no-telemetry environment before Prefect loads

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="IMU calibration pipeline and archive."
)
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


def open_archive(arg: str | None):
    from storage.db import resolve_archive

    arch = resolve_archive(arg)
    arch.upgrade()
    return arch


def fail(message: str) -> None:
    err.print(f"[red]error:[/red] {message}")
    raise typer.Exit(2)


def print_json(doc: Any) -> None:
    sys.stdout.write(json.dumps(doc, indent=2, default=str) + "\n")


@app.command()
def process(
    paths: Annotated[list[Path], typer.Argument(help="Run folders, or folders holding runs.")],
    archive: ArchiveOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the JSON document.")] = False,
) -> None:
    """Ingest, solve, check and archive every run under PATHS (a Prefect flow)."""
    from pipelines.flows import process_batch

    outcomes = process_batch([str(p) for p in paths], archive)
    if as_json:
        print_json({"runs": outcomes})
    else:
        table = Table(title="Processed runs")
        for col in ("run", "serial", "status", "verdict", "failed checks", "protocol / error"):
            table.add_column(col)
        for o in outcomes:
            failed = sum(not c["passed"] for c in o["checks"])
            detail = o["error"] if o["status"] == "failed" else (o["protocol"] or "")
            style = {"ok": "green", "duplicate": "yellow", "failed": "red"}[o["status"]]
            table.add_row(
                o["run_id"] or "-",
                o["serial"] or "-",
                f"[{style}]{o['status']}[/]",
                o["verdict"] or "-",
                str(failed),
                detail,
            )
        out.print(table)
    raise typer.Exit(1 if any(o["status"] == "failed" for o in outcomes) else 0)


@app.command()
def history(
    serial: str,
    archive: ArchiveOpt = None,
    as_json: Annotated[bool, typer.Option("--json")] = False,
) -> None:
    """Every calibration revision of a serial, oldest first."""
    from storage import queries

    df = queries.history(open_archive(archive), serial)
    if as_json:
        print_json(json.loads(df.to_json(orient="records", date_format="iso")))
        return
    if df.empty:
        fail(f"no calibrations archived for serial {serial!r}")
    print_frame(df, f"History of {serial}")


@app.command()
def show(
    run_id: str,
    archive: ArchiveOpt = None,
    as_json: Annotated[bool, typer.Option("--json")] = False,
) -> None:
    """One archived run: unit, raw files, steps, parameters, checks."""
    from storage import queries

    try:
        summary = queries.run_summary(open_archive(archive), run_id)
    except (KeyError, LookupError, ValueError) as exc:
        fail(str(exc))
    if as_json:
        print_json(summary)
        return
    out.print_json(json.dumps(summary, default=str))


@app.command()
def export(
    run_id: str,
    archive: ArchiveOpt = None,
    fmt: Annotated[str, typer.Option("--format", help="json")] = "json",
    output: Annotated[Path | None, typer.Option("--output", "-o")] = None,
) -> None:
    """Export a run's calibration (canonical JSON)."""
    from storage import queries

    if fmt != "json":
        fail(f"unknown export format {fmt!r}; expected: json")
    try:
        doc = queries.export_calibration(open_archive(archive), run_id)
    except (KeyError, LookupError, ValueError) as exc:
        fail(str(exc))
    text = json.dumps(doc, indent=2, default=str) + "\n"
    if output is None:
        sys.stdout.write(text)
    else:
        output.write_text(text, encoding="utf-8")
        err.print(f"wrote {output}")


def print_frame(df, title: str) -> None:
    table = Table(title=title)
    for col in df.columns:
        table.add_column(str(col))
    for row in df.itertuples(index=False):
        table.add_row(*("" if v is None else str(v) for v in row))
    out.print(table)


# Commands of the other areas live in pipelines/commands/ and register themselves on `app`.
from pipelines.commands import register_all  # noqa: E402

register_all()

if __name__ == "__main__":
    app()
