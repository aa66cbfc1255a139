"""The ground-truth benchmark (docs/validation.md): the versioned set of simulated cases run
on the installed software and scored against their truth and the Cramer-Rao bound, with
the public sessions against their references; the report a lab files written with --out.

Run from a checkout: the simulated cases come from the support package
(calib_testing.benchmark_cases), which the product never imports.

Usage: python benchmarks/validation_set.py [--workers N] [--reduced] [--out DIR]
           [--set FILE] [--realdata DIR]

Progress and a table per procedure go to stderr; the last stdout line is one JSON object:
benchmark_seconds, workers, set, software, reduced, targets, per procedure
efficiency_vs_crlb, coverage_95 and the rest of its summary, sessions, peers, report
(the paths written).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calib_testing.benchmark_cases import design  # noqa: E402
from pipelines.validation import benchmark, benchmark_report  # noqa: E402


def _say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _table(doc: dict) -> None:
    _say(f"{doc['set']['name']} {doc['set']['version']} ({doc['seconds']} s)")
    for proc, s in doc["procedures"].items():
        _say(
            f"  {proc}: efficiency_vs_crlb {s['efficiency_vs_crlb']}, coverage_95 "
            f"{s['coverage_95']}, {s['replicates']} replicates, meets {s['meets_targets']}"
        )
    for s in doc["sessions"]:
        if s["status"] != "compared":
            _say(f"  session {s['id']}: {s['status']} ({s['reason']})")
            continue
        within = sum(r["within_tolerance"] for r in s["parameters"])
        _say(f"  session {s['id']}: {within} of {len(s['parameters'])} within the reference")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--reduced", action="store_true", help="the reduced set, a quick check")
    ap.add_argument("--out", type=Path, help="folder the report (HTML, PDF, JSON) goes to")
    ap.add_argument("--set", type=Path, dest="set_file", help="a set file in place of v1")
    ap.add_argument("--realdata", type=Path, help="folder of the public recordings")
    args = ap.parse_args()
    try:
        set_doc = benchmark.load_set(args.set_file) if args.set_file else benchmark.load_set()
    except ValueError as exc:
        sys.exit(f"error: {exc}")
    start = time.perf_counter()
    doc = benchmark.run_benchmark(
        set_doc,
        design,
        reduced=args.reduced,
        workers=args.workers,
        progress=_say,
        realdata=args.realdata,
    )
    wall = time.perf_counter() - start
    written = benchmark_report.write_report(doc, args.out) if args.out else {}
    _table(doc)
    summary = {k: v for k, v in doc.items() if k != "cases"}
    summary["report"] = {k: str(v) for k, v in written.items()}
    print(json.dumps({"benchmark_seconds": round(wall, 1), "workers": args.workers, **summary}))


if __name__ == "__main__":
    main()
