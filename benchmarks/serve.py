"""`calib serve` benchmark: page times on the archive benchmark's 100k-run archive.

Builds the synthetic archive of benchmarks/archive.py (10k units of three models, 100k
runs, 5M parameter rows; bulk-loaded, schema by the real migrations), opens it as the
server does (storage.queries.open_readonly: SQLite ``mode=ro``; PostgreSQL in read-only
transactions as the ``calib_reader`` role) and requests each page through the whole
application (FastAPI's TestClient: routing, validation, queries, templates, SVG; no
network) for randomly chosen runs, units, equipment and filters:

- runs: the first page of the runs list (50 rows, newest first);
- runs_filtered: model + one month + verdict, sorted by serial;
- runs_deep: a random page of 50 among the first 2000 of the whole list;
- run: a run's page; lineage: a value's lineage page;
- unit: a unit's page (25 parameters x 10 runs: trends, forecasts, sparklines, a chart);
- fleet: the largest model's fleet (6k units) for a random parameter; nothing is cached
  between requests, so each is what the first view after a change of the archive costs;
- models, equipment, equipment_item (a rate table with ~5k runs, its lapsed runs), verify
  (the status page; the integrity check itself re-reads the file store and is not timed).

Target: page_p95_ms <= 200 for every page on SQLite and PostgreSQL.
``page_cpu_p95_ms`` is this process's CPU time per request (application, templates and,
for SQLite, the database engine; not PostgreSQL's server): what a page costs a core of
its own, since the wall time on a shared machine grows with its load average.
Progress goes to stderr, a table to stdout; the LAST stdout line is one JSON object::

    {"sqlite": {"page_p95_ms": {page: ms}, "page_p50_ms": {...}, "page_cpu_p95_ms": {...}},
     "postgresql": {...}, "pages": [...], "runs": int, "requests_per_page": int}

Run: ``.venv/bin/python benchmarks/serve.py [--runs N] [--requests N]
[--backend sqlite|postgresql|both] [--keep DIR] [--postgresql-url URL]`` (--keep builds
the SQLite archive in DIR once and reuses it; --postgresql-url times a loaded one).
~3 min for SQLite at 100k runs on 2 shared cores, about twice that for PostgreSQL.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from datetime import timedelta
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from archive import (  # noqa: E402 - the archive benchmark's generator and loaders
    N_EQUIPMENT,
    NAMES,
    SEED,
    SPAN_S,
    T0,
    Synth,
    load_postgresql,
    load_sqlite,
    log,
)

from storage.db import Archive, default_archive_url  # noqa: E402

PAGES = (
    "runs",
    "runs_filtered",
    "runs_deep",
    "run",
    "lineage",
    "unit",
    "fleet",
    "models",
    "equipment",
    "equipment_item",
    "verify",
)
TARGET_MS = 200.0


def page_urls(synth: Synth, rng: np.random.Generator) -> dict[str, Callable[[], str]]:
    """Page name -> a factory of one randomly chosen URL of that page."""

    def run() -> str:
        return f"/runs/{synth.run_id(int(rng.integers(synth.n_runs)))}"

    def filtered() -> str:
        d = (T0 + timedelta(seconds=float(rng.uniform(0, SPAN_S - 40 * 86400)))).date()
        return (
            f"/runs?model=MPU-6000&from={d}&to={d + timedelta(days=30)}&verdict=pass"
            "&sort=serial&order=asc"
        )

    def fleet() -> str:
        return f"/fleet?model=MPU-6000&parameter={NAMES[int(rng.integers(len(NAMES)))]}"

    return {
        "runs": lambda: "/runs",
        "runs_filtered": filtered,
        "runs_deep": lambda: f"/runs?page={int(rng.integers(1, 41))}",
        "run": run,
        "lineage": lambda: f"{run()}/lineage/{NAMES[int(rng.integers(len(NAMES)))]}",
        "unit": lambda: f"/units/{synth.serial(int(rng.integers(synth.n_units)))}",
        "fleet": fleet,
        "models": lambda: "/models",
        "equipment": lambda: "/equipment",
        "equipment_item": lambda: (
            f"/equipment/item?kind=rate_table&serial=RT-{int(rng.integers(N_EQUIPMENT))}"
        ),
        "verify": lambda: "/verify",
    }


def bench(archive: Archive, synth: Synth, requests: int) -> dict[str, dict[str, float]]:
    """p50 / p95 (ms) of each page over `requests` random requests (after 3 warm-ups)."""
    from fastapi.testclient import TestClient

    from pipelines.web.app import create_app
    from storage.queries import open_readonly

    ro = open_readonly(archive)
    rng = np.random.default_rng(SEED + 23)
    out: dict[str, dict[str, float]] = {}
    with TestClient(create_app(ro)) as client:
        for page, make in page_urls(synth, rng).items():
            urls = [make() for _ in range(requests + 3)]
            for u in urls[:3]:
                _get(client, u)
            times, cpu = np.empty(requests), np.empty(requests)
            for i, u in enumerate(urls[3:]):
                t, c = time.perf_counter(), time.process_time()
                _get(client, u)
                times[i], cpu[i] = time.perf_counter() - t, time.process_time() - c
            out[page] = {
                "p50_ms": 1e3 * float(np.median(times)),
                "p95_ms": 1e3 * float(np.percentile(times, 95)),
                "cpu_p95_ms": 1e3 * float(np.percentile(cpu, 95)),
            }
            log(
                f"  {page}: p50 {out[page]['p50_ms']:.1f} ms, p95 {out[page]['p95_ms']:.1f} ms, "
                f"CPU p95 {out[page]['cpu_p95_ms']:.1f} ms"
            )
    ro.dispose()
    return out


def _get(client, url: str) -> None:  # noqa: ANN001 - a TestClient
    r = client.get(url)
    if r.status_code != 200:
        raise RuntimeError(f"{url}: HTTP {r.status_code}: {r.text[-300:]}")


def sqlite_archive(folder: Path, synth: Synth) -> Archive:
    """The synthetic archive as SQLite in `folder` (loaded once; reused if present)."""
    archive = Archive(default_archive_url(folder), folder)
    marker = folder / f"loaded-{synth.n_runs}"
    if not marker.exists():
        shutil.rmtree(folder, ignore_errors=True)
        archive.upgrade()
        t = time.perf_counter()
        load_sqlite(archive, synth)
        log(f"sqlite: loaded {synth.n_runs} runs in {time.perf_counter() - t:.0f} s")
        marker.touch()
    archive.dispose()
    return archive


def postgresql_bench(synth: Synth, requests: int, work: Path) -> dict[str, dict[str, float]]:
    """Load into a private PostgreSQL server, grant the roles, time the pages as the owner
    (the server switches to calib_reader)."""
    from calib_testing.pgserver import admin_execute, private_server
    from storage.roles import apply_roles

    with private_server(
        shared_buffers="512MB", max_wal_size="4GB", synchronous_commit="off"
    ) as server:
        admin_execute(server, 'CREATE DATABASE "bench"')
        pg = Archive(server.rsplit("/", 1)[0] + "/bench", work / "pg")
        pg.upgrade()
        t = time.perf_counter()
        load_postgresql(pg, synth)
        log(f"postgresql: loaded {synth.n_runs} runs in {time.perf_counter() - t:.0f} s")
        apply_roles(pg)
        pg.dispose()
        result = bench(pg, Synth(synth.n_runs), requests)
        pg.dispose()
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=100_000)
    ap.add_argument("--requests", type=int, default=40, help="timed requests per page")
    ap.add_argument("--backend", choices=("sqlite", "postgresql", "both"), default="both")
    ap.add_argument("--keep", type=Path, help="folder for the SQLite archive, kept and reused")
    ap.add_argument(
        "--postgresql-url",
        help="time this already loaded archive (with the "
        "roles granted) instead of loading a private server",
    )
    args = ap.parse_args()
    log(f"{args.runs} runs, {max(1, args.runs // 10)} units; {args.requests} requests per page")
    work = Path(tempfile.mkdtemp(prefix="calib-serve-bench-"))
    results: dict[str, dict[str, dict[str, float]]] = {}
    try:
        if args.backend in ("sqlite", "both"):
            folder = args.keep or work / "sqlite"
            archive = sqlite_archive(folder, Synth(args.runs))
            log("sqlite: timing pages")
            results["sqlite"] = bench(archive, Synth(args.runs), args.requests)
        if args.backend in ("postgresql", "both") and args.postgresql_url:
            log("postgresql: timing pages")
            pg = Archive(args.postgresql_url, work / "pg")
            results["postgresql"] = bench(pg, Synth(args.runs), args.requests)
        elif args.backend in ("postgresql", "both"):
            log("postgresql: loading")
            results["postgresql"] = postgresql_bench(Synth(args.runs), args.requests, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"{'page':<16}{'back end':<12}{'p50 ms':>10}{'p95 ms':>10}")
    for backend, res in results.items():
        for page, r in res.items():
            flag = "" if r["p95_ms"] <= TARGET_MS else "  > target"
            print(f"{page:<16}{backend:<12}{r['p50_ms']:>10.1f}{r['p95_ms']:>10.1f}{flag}")
    summary = {
        b: {
            "page_p95_ms": {p: round(r["p95_ms"], 1) for p, r in res.items()},
            "page_p50_ms": {p: round(r["p50_ms"], 1) for p, r in res.items()},
            "page_cpu_p95_ms": {p: round(r["cpu_p95_ms"], 1) for p, r in res.items()},
        }
        for b, res in results.items()
    }
    print(
        json.dumps(
            {**summary, "pages": list(PAGES), "runs": args.runs, "requests_per_page": args.requests}
        )
    )


if __name__ == "__main__":
    main()
