"""Centrifuge procedure, the CLI: `calib centrifuge RUN [--repeat RUN2]`.

The report goes to stdout (or the JSON document with --json) and to a text
file. Exit codes: 0 done, 2 invalid input.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli_shared import app, fail, out, print_json


@app.command()
def centrifuge(
    run: Annotated[Path, typer.Argument(help="Centrifuge run folder (run.toml + data).")],
    repeat: Annotated[
        Path | None,
        typer.Option("--repeat", help="Repeat run of the same unit: validate the model on it."),
    ] = None,
    report: Annotated[
        Path | None,
        typer.Option("--report", help="Text report file (default RUN/centrifuge_report.txt)."),
    ] = None,
    alpha: Annotated[
        float | None,
        typer.Option(help="Significance level of the F and t tests (default: manifest, 0.05)."),
    ] = None,
    t_test: Annotated[
        str | None,
        typer.Option(
            "--t-test",
            help="two-sided or one-sided (the paper's) coefficient t test (default: manifest, "
            "two-sided).",
        ),
    ] = None,
    steer: Annotated[
        str | None,
        typer.Option(help="What ends the reduction: t (t tests) or F (model F) (default: t)."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the JSON document.")] = False,
) -> None:
    """Solve a centrifuge run: reduced high-g model per axis, F/t statistics, validation."""
    from pipelines.centrifuge import process_centrifuge
    from pipelines.ingest import IngestError

    if alpha is not None and not 0.0 < alpha < 1.0:
        fail(f"--alpha must be in (0, 1), got {alpha}")
    try:
        outcome = process_centrifuge(
            run, repeat=repeat, report_path=report, alpha=alpha, t_test=t_test, steer=steer
        )
    except (ValueError, IngestError, OSError) as exc:
        fail(str(exc))
        return
    if as_json:
        print_json(outcome.to_dict())
    else:
        out.print(outcome.report, markup=False, highlight=False, soft_wrap=True)
