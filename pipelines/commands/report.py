"""`calib report RUN_ID`: protocol, HTML certificate and PDF of an archived run."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli_shared import ArchiveOpt, app, err, fail, open_run, print_json


@app.command()
def report(
    run_id: str,
    archive: ArchiveOpt = None,
    pdf: Annotated[bool, typer.Option("--pdf/--no-pdf", help="Also write the PDF.")] = True,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Folder (default: the run's folder).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the written paths.")] = False,
    form: Annotated[
        str, typer.Option("--format", help="certificate (protocol, HTML, PDF) or dcc "
                                            "(Digital Calibration Certificate XML).")
    ] = "certificate",
) -> None:
    """Write the test protocol, the HTML certificate and the PDF of an archived run.

    Everything is read from the archive (run summary, checks, Parquet samples) and
    the lab profile (lab.toml); the files go into the run's archive folder unless
    --output names another. --format dcc writes the PTB DCC XML instead.
    """
    from pipelines.reports.certificate import report_run

    arch, run_id = open_run(archive, run_id)
    try:
        written = report_run(arch, run_id, output, pdf=pdf, form=form)
    except (KeyError, LookupError, ValueError) as exc:
        fail(str(exc))
    except OSError as exc:  # a read-only archive, a full disk
        from storage.write_failures import describe

        fail(f"{describe(exc) or exc}; the reports can go elsewhere with --output DIR")
    verdict = written.pop("verdict")
    if as_json:
        print_json({"run_id": run_id, "verdict": verdict,
                    **{k: str(v) for k, v in written.items()}})  # fmt: skip
        return
    for kind, path in written.items():
        err.print(f"wrote {kind}: {path}")
