"""`calib validate --benchmark`, the CLI: the ground-truth benchmark run on the installed
software, its per-procedure figures printed and its report written (docs/validation.md).

`benchmark_command` does the work; `calib validate` (pipelines/commands/validate.py, the
cross-check of archived runs by independent implementations) calls it for `--benchmark`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pipelines.cli_shared import fail, out, print_json, print_table


def benchmark_command(
    json_out: bool,
    out_dir: Path | None,
    reduced: bool,
    workers: int,
    set_file: Path | None,
    realdata: Path | None,
) -> None:
    """Run the benchmark set, print per procedure efficiency_vs_crlb and coverage_95 (JSON
    with `json_out`), write the report (HTML, PDF, JSON) into `out_dir` when given; the
    public sessions from `realdata` when given."""
    from pipelines.validation import benchmark, benchmark_report

    try:
        set_doc = benchmark.load_set(set_file) if set_file else benchmark.load_set()
    except ValueError as exc:
        fail(str(exc))
    doc = benchmark.run_benchmark(set_doc, reduced=reduced, workers=workers, realdata=realdata)
    written = benchmark_report.write_report(doc, out_dir) if out_dir else {}
    if json_out:
        summary = {k: v for k, v in doc.items() if k != "cases"}
        print_json({**summary, "report": {k: str(v) for k, v in written.items()}})
        return
    _print(doc)
    for kind, path in written.items():
        out.print(f"{kind}: {path}")


def _print(doc: dict[str, Any]) -> None:
    rows = [
        {
            "procedure": proc,
            "efficiency_vs_crlb": s["efficiency_vs_crlb"],
            "coverage_95": s["coverage_95"],
            "replicates": s["replicates"],
            "meets": s["meets_targets"],
        }
        for proc, s in doc["procedures"].items()
    ]
    title = f"{doc['set']['name']} {doc['set']['version']} ({doc['seconds']} s)"
    print_table(rows, title)
    for s in doc["sessions"]:
        if s["status"] != "compared":
            out.print(f"session {s['id']}: {s['status']} ({s['reason']})")
            continue
        within = sum(r["within_tolerance"] for r in s["parameters"])
        out.print(f"session {s['id']}: {within} of {len(s['parameters'])} within the reference")
