"""`calib validate RUN_ID... [--with imucal,allantools]`, the CLI: an archived run solved
again by independent public implementations (pipelines/validation, docs/validation.md).

`--benchmark` is the ground-truth benchmark's entry (docs/validation.md); it takes no run id.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from pipelines.cli_shared import (
    ArchiveOpt,
    JsonOpt,
    app,
    fail,
    open_archive,
    print_json,
    print_table,
)


def _folder(flag: str, help: str) -> Any:  # noqa: A002, ANN401 - typer's name, an Annotated
    return Annotated[Path | None, typer.Option(flag, help=help)]


@app.command()
def validate(
    run_ids: Annotated[
        list[str] | None, typer.Argument(help="Run ids (or unique prefixes).", show_default=False)
    ] = None,
    peers: Annotated[
        str,
        typer.Option(
            "--with",
            help="Comma-separated peers to compare with: imucal, allantools "
            "(pip install 'imu-calib\\[validate]'). Default: every peer.",
        ),
    ] = "",
    benchmark: Annotated[
        bool,
        typer.Option("--benchmark", help="Score the installed software on the benchmark set."),
    ] = False,
    json_out: JsonOpt = False,
    out_dir: _folder("--out", "--benchmark: folder the report (HTML, PDF, JSON) goes to.") = None,
    reduced: Annotated[
        bool, typer.Option("--reduced", help="--benchmark: the reduced set, a quick check.")
    ] = False,
    workers: Annotated[
        int, typer.Option("--workers", min=1, help="--benchmark: processes for the cases.")
    ] = 1,
    set_file: _folder("--set", "--benchmark: a set file in place of the installed one.") = None,
    realdata: _folder("--realdata", "--benchmark: folder of the public recordings.") = None,
    archive: ArchiveOpt = None,
) -> None:
    """Archived runs solved again by independent implementations (E_n per parameter, kept
    sealed); --benchmark: the software scored on the ground-truth benchmark.

    Per parameter ours, theirs, the difference, the combined standard uncertainty and E_n
    (k = 2); each comparison archived as a sealed validation record of the run. With
    --benchmark: error against the simulated truth, efficiency against the Cramer-Rao bound,
    coverage of U at 95 % per procedure; the report a lab files with --out."""
    from pipelines.validation import compare

    if benchmark:
        if run_ids:
            fail("--benchmark takes no run id: it scores the software on its own set")
        from pipelines.commands.benchmark import benchmark_command

        benchmark_command(json_out, out_dir, reduced, workers, set_file, realdata)
        return
    if not run_ids:
        fail("give at least one run id (or --benchmark)")
    try:
        chosen = compare.peer_names(peers)
    except ValueError as exc:
        fail(str(exc))
    arch = open_archive(archive)
    if arch.read_only:
        fail(f"{arch.root}: the archive is read-only; a validation is kept as a record in it")
    results = []
    for run_id in run_ids:
        try:
            results.append(compare.validate_and_archive(arch, run_id, chosen))
        except (LookupError, ValueError) as exc:
            fail(str(exc))
        except Exception as exc:  # a read-only archive, a full disk: said, not a traceback
            from storage.write_failures import describe

            message = describe(exc, arch.url)
            if message is None:
                raise
            fail(f"{run_id}: the validation record cannot be kept: {message}")
    if json_out:
        print_json(results if len(results) > 1 else results[0])
        return
    for doc in results:
        _print(doc)


def _print(doc: dict[str, Any]) -> None:
    """One run's comparisons: a table per peer that treated it, its reason otherwise."""
    from pipelines.cli_shared import out
    from pipelines.reports.validation import COLUMNS, row_texts

    out.print(
        f"{doc['run_id']} revision {doc['revision']}: validation record {doc['validation_id']}"
    )
    for peer in doc["peers"]:
        title = f"{doc['run_id']} against {peer['peer']} {peer.get('version') or ''}".strip()
        if peer["status"] != "compared":
            out.print(f"{title}: {peer['status']} ({peer['reason']})", markup=False)
            continue
        rows = [row_texts(r) for r in peer["parameters"]]
        print_table(title, COLUMNS, rows)
        for note in peer.get("notes", []):
            out.print(f"  note: {note}", markup=False)
