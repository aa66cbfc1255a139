"""`calib validate RUN_ID... [--with imucal,allantools]`, the CLI: an archived run solved
again by independent public implementations (pipelines/validation, docs/validation.md);
`calib validate --benchmark`: the ground-truth benchmark of the installed software, its
simulated cases from a provider found at run time (pipelines/validation/cases.py).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from pipelines.cli_shared import (
    ArchiveOpt,
    JsonOpt,
    app,
    fail,
    fail_on,
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
    bench: Annotated[
        bool,
        typer.Option(
            "--benchmark",
            help="Run the ground-truth benchmark (simulated runs with known truth, the public"
            " sessions) instead of validating archived runs, and write its report.",
        ),
    ] = False,
    reduced: Annotated[
        bool, typer.Option("--reduced", help="--benchmark: each case's few replicates (a check).")
    ] = False,
    out: Annotated[
        Path,
        typer.Option("--out", help="--benchmark: folder of the report (JSON, HTML, PDF)."),
    ] = Path("benchmark-report"),
    set_file: Annotated[
        Path | None,
        typer.Option("--set", help="--benchmark: a set file in place of the versioned one."),
    ] = None,
    realdata: Annotated[
        Path | None,
        typer.Option("--realdata", help="--benchmark: folder of the public recordings."),
    ] = None,
    cases: Annotated[
        str | None,
        typer.Option(
            "--cases",
            help="--benchmark: MODULE[:NAME] providing the simulated cases (default: the"
            " entry point group imu_calib.benchmark_cases).",
        ),
    ] = None,
    workers: Annotated[
        int, typer.Option("--workers", min=1, help="--benchmark: processes for the cases.")
    ] = 1,
    json_out: JsonOpt = False,
    archive: ArchiveOpt = None,
) -> None:
    """Archived runs solved again by independent implementations (E_n per parameter, kept
    sealed), or the ground-truth benchmark (--benchmark).

    Per parameter ours, theirs, the difference, the combined standard uncertainty and E_n
    (k = 2); each comparison archived as a sealed validation record of the run. With
    --benchmark: per procedure efficiency against the Cramer-Rao bound and coverage of U,
    the public sessions against their references; the report written to --out."""
    from pipelines.validation import compare

    if bench:
        if run_ids:
            fail("--benchmark takes no run ids (it runs the benchmark's own set)")
        _benchmark(cases, set_file, reduced, workers, out, realdata, json_out)
        return
    if not run_ids:
        fail("give at least one run id (or --benchmark)")
    with fail_on(ValueError):
        chosen = compare.peer_names(peers)
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


def _benchmark(
    cases: str | None,
    set_file: Path | None,
    reduced: bool,
    workers: int,
    out: Path,
    realdata: Path | None,
    json_out: bool,
) -> None:
    """`calib validate --benchmark`: progress on stderr, the summary as a table or JSON."""
    from pipelines.validation.benchmark import run_and_report
    from pipelines.validation.cases import NoProviderError

    def say(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    with fail_on(NoProviderError, ValueError):
        doc = run_and_report(
            cases,
            set_file=set_file,
            reduced=reduced,
            workers=workers,
            out=out,
            realdata=realdata,
            progress=say,
        )
    if json_out:
        print_json(doc)
        return
    _print_benchmark(doc)


def _print_benchmark(doc: dict[str, Any]) -> None:
    """The benchmark's summary: a row per procedure, a line per session, the report."""
    from pipelines.cli_shared import out

    def fmt(x: float | None) -> str:
        return "-" if x is None else f"{x:.3g}"

    rows = [
        [p, fmt(s["efficiency_vs_crlb"]), fmt(s["coverage_95"]), str(s["replicates"]),
         "yes" if s["meets_targets"] else "no"]
        for p, s in doc["procedures"].items()
    ]  # fmt: skip
    title = f"{doc['set']['name']} {doc['set']['version']} ({doc['seconds']} s)"
    header = ["procedure", "efficiency_vs_crlb", "coverage_95", "replicates", "meets targets"]
    print_table(title, header, rows)
    for c in doc["conditions"]:
        out.print(f"condition {c['id']}: coverage_95 {fmt(c['coverage_95'])}", markup=False)
    for key, p in doc["peers"].items():
        if p["status"] == "compared":
            out.print(
                f"{key}: E_n <= 1 for {fmt(p['e_n_within_1'])}, largest {fmt(p['e_n_max'])}"
                f" ({p['e_n_max_parameter']}), {p['replicates']} replicates",
                markup=False,
            )
    for s in doc["sessions"]:
        if s["status"] != "compared":
            out.print(f"session {s['id']}: {s['status']} ({s['reason']})", markup=False)
            continue
        within = sum(r["within_tolerance"] for r in s["parameters"])
        out.print(f"session {s['id']}: {within} of {len(s['parameters'])} within the reference")
    for kind, path in doc["report"].items():
        out.print(f"report ({kind}): {path}", markup=False)


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
