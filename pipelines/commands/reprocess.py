"""`calib reprocess RUN_ID` (the work: pipelines.reprocess)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli_shared import ArchiveOpt, app, err, fail, open_run, out, print_json


@app.command("reprocess")
def reprocess_command(
    run_id: str,
    archive: ArchiveOpt = None,
    keep: Annotated[
        Path | None,
        typer.Option("--keep", help="Rebuild the run folder here and keep it (for inspection)."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the JSON document.")] = False,
) -> None:
    """Process RUN_ID again from the archive alone (its archived raw files and manifest)."""
    from pipelines.reprocess import ReprocessError, reprocess_run

    arch, run_id = open_run(archive, run_id)
    if keep is not None and keep.exists() and any(keep.iterdir()):
        fail(f"--keep {keep}: folder is not empty")
    try:
        outcome = reprocess_run(arch, run_id, keep)
    except ReprocessError as exc:
        fail(str(exc))
    if as_json:
        print_json({"runs": [outcome]})
    elif outcome["status"] == "failed":
        err.print(f"[red]failed:[/red] {outcome['error']}")
    else:
        out.print(
            f"{outcome['run_id']} {outcome['serial']}: {outcome['status']}, "
            f"verdict {outcome['verdict']}"
            + (f" ({outcome['message']})" if outcome["message"] else "")
        )
    raise typer.Exit(1 if outcome["status"] == "failed" else 0)
