"""The ground-truth benchmark's full set (`calib validate --benchmark`) timed: wall time and
per procedure the figures of docs/validation.md. Last line: one JSON object with
benchmark_seconds, workers, and per procedure efficiency_vs_crlb and coverage_95.

Usage: python benchmarks/validation_set.py [--workers N] [--reduced]
"""

from __future__ import annotations

import argparse
import json
import time

from pipelines.validation import benchmark


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--reduced", action="store_true")
    args = ap.parse_args()
    start = time.perf_counter()
    doc = benchmark.run_benchmark(
        benchmark.load_set(), reduced=args.reduced, workers=args.workers, progress=print
    )
    wall = time.perf_counter() - start
    figures = {
        p: {"efficiency_vs_crlb": s["efficiency_vs_crlb"], "coverage_95": s["coverage_95"]}
        for p, s in doc["procedures"].items()
    }
    print(
        json.dumps(
            {"benchmark_seconds": round(wall, 1), "workers": args.workers, "procedures": figures}
        )
    )


if __name__ == "__main__":
    main()
