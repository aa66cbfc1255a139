"""`calib validate RUN_ID... [--with imucal,allantools]`, the CLI: an archived run solved
again by independent public implementations (pipelines/validation, docs/validation.md).

The ground-truth benchmark runs from a checkout (benchmarks/validation_set.py): its
simulated cases need the simulator, which the product does not import.
"""

from __future__ import annotations

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
    json_out: JsonOpt = False,
    archive: ArchiveOpt = None,
) -> None:
    """Archived runs solved again by independent implementations (E_n per parameter, kept
    sealed).

    Per parameter ours, theirs, the difference, the combined standard uncertainty and E_n
    (k = 2); each comparison archived as a sealed validation record of the run."""
    from pipelines.validation import compare

    if not run_ids:
        fail("give at least one run id")
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
