"""Archive benchmark: 100k simulated runs (5M parameter rows) in SQLite and PostgreSQL.

Bulk-loads a synthetic archive straight into the tables (SQLite ``executemany``,
PostgreSQL ``COPY``; not `archive_run` per run, which would take hours), with
the schema built by the real migrations, then times the queries of
`storage.queries` as the CLI calls them:

- latest_valid: `latest_valid(serial, as_of)` for random units and dates;
- lineage: `lineage(run_id, parameter)` for random runs and parameters;
- history: `serial_parameter_history(serial, parameter)`;
- lapsed: `lapsed_runs(equipment_serial)` (a rate table with ~5k runs);
- units: `units(model, date range, verdict)` over one month;
- fleet: `fleet(model, parameter)` over the largest model (60% of the units).

The archive: 10k units of three models, 10 runs each over 2020-2025, one
calibration per run (90% pass), 25 parameters at two temperatures each (50
rows per calibration), 3 raw files, 3 steps, 2 checks and one rate table (of
20, with calibration due dates, some lapsed) per run.

Targets: latest_valid and lineage p95 < 10 ms, history p95 < 50 ms,
fleet < 1 s, on both back ends. Progress goes to stderr; a table of p50/p95
per query and back end to stdout; the LAST stdout line is one JSON object::

    {"sqlite": {"latest_valid_p95_ms", "lineage_p95_ms", "history_p95_ms", "fleet_s",
                "latest_valid_cpu_p95_ms", "lineage_cpu_p95_ms", "load_average", "verify_..."},
     "postgresql": {...}, "runs": int, "parameter_rows": int, "verify_runs": int}

``fleet_s`` is the slowest of the timed fleet calls; ``*_cpu_p95_ms`` the p95 of this
process's CPU time per call (the whole query on SQLite, the client's part on
PostgreSQL), which a busy machine's waits for a core do not inflate; ``load_average``
the 1-minute load before and after the queries were timed. Run:
``.venv/bin/python benchmarks/archive.py [--runs N] [--verify-runs N] [--backends
sqlite,postgresql]`` (~5-8 min on 2
cores for 100k, plus ~10 min per back end for 1000 verify runs).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from datetime import UTC, date, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("DO_NOT_TRACK", "1")

from calib_core import params  # noqa: E402
from calib_testing.pgserver import admin_execute, libpq_dsn, private_server  # noqa: E402
from storage import queries, unit_latest  # noqa: E402
from storage.db import Archive, default_archive_url  # noqa: E402

RUNS_PER_UNIT = 10
MODELS = [("MPU-6000", 0.6), ("ADXL355", 0.3), ("BMI088", 0.1)]
NAMES = params.ACC_LINEAR + params.GYR_LINEAR + ["acc.noise.x"]  # 25 canonical names
TEMPS = (20.0, 40.0)  # deg C: each parameter at two temperatures -> 50 rows per calibration
N_EQUIPMENT = 20
CHUNK_RUNS = 5_000
# Tables with rows per run, in the order their foreign keys need.
RUN_TABLES = (
    "runs",
    "run_equipment",
    "raw_files",
    "calibrations",
    "processing_steps",
    "parameters",
    "check_results",
)
T0 = datetime(2020, 1, 1, tzinfo=UTC)
SPAN_S = 6 * 365 * 86400
SAMPLES = {"latest_valid": 300, "lineage": 300, "history": 200, "lapsed": 20, "units": 50}
FLEET_CALLS = 5
SEED = 20261122
# JSON columns: the same small documents for every run (built once).
SITE_JSON = json.dumps({"latitude_deg": 55.75, "height_m": 150.0})
SETTINGS_JSON = json.dumps({"outlier_sigma": 3.0})
DOCUMENT_JSON = json.dumps({"procedure": "six_position"})
STEP_JSON = {n: json.dumps({"step": n}) for n in ("ingest", "outliers", "solve")}
STATS_JSON = json.dumps({"n": 1000})


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# --- synthetic archive -----------------------------------------------------------------


class Synth:
    """Deterministic synthetic archive; rows as tuples in table column order."""

    def __init__(self, n_runs: int, seed: int = SEED) -> None:
        rng = np.random.default_rng(seed)
        self.n_runs = n_runs
        self.n_units = max(1, n_runs // RUNS_PER_UNIT)
        shares = np.array([s for _, s in MODELS])
        self.unit_model = rng.choice(len(MODELS), self.n_units, p=shares / shares.sum())
        self.run_unit = np.arange(n_runs) % self.n_units
        self.run_t = np.sort(rng.uniform(0, SPAN_S, n_runs))  # s after T0, in run-id order
        self.run_pass = rng.random(n_runs) < 0.9
        self.run_eq = rng.integers(0, N_EQUIPMENT, n_runs)
        self.run_temp = rng.uniform(18, 28, n_runs)
        # Equipment due dates: 2021..2026, so runs after the date count as lapsed.
        self.eq_due = [
            date(2021, 1, 1) + timedelta(days=int(d)) for d in rng.integers(0, 1800, N_EQUIPMENT)
        ]
        self.rng = rng

    def serial(self, unit: int) -> str:
        return f"U{unit:06d}"

    def run_id(self, run: int) -> str:
        return f"R{run:012x}"

    def started(self, run: int) -> datetime:
        return T0 + timedelta(seconds=float(self.run_t[run]))

    def devices(self) -> list[tuple]:
        now = datetime.now(UTC)
        return [
            (u + 1, self.serial(u), MODELS[self.unit_model[u]][0], "Acme", None, now)
            for u in range(self.n_units)
        ]

    def equipment(self) -> list[tuple]:
        return [
            (
                e + 1,
                "rate_table",
                "AC1120",
                f"RT-{e}",
                "0.01%",
                self.eq_due[e],
                self.eq_due[e] - timedelta(days=365),
            )
            for e in range(N_EQUIPMENT)
        ]

    def chunk(self, lo: int, hi: int) -> dict[str, list[tuple]]:
        """Rows of runs lo..hi-1 for every run-dependent table (ids are run index based)."""
        rng = self.rng
        now = datetime.now(UTC)
        out: dict[str, Any] = {k: [] for k in RUN_TABLES}
        n_p = len(NAMES) * len(TEMPS)
        values = rng.normal(0, 0.05, (hi - lo, n_p))
        stds = np.abs(rng.normal(0, 1e-3, (hi - lo, n_p)))
        for r in range(lo, hi):
            rid, pk = self.run_id(r), r + 1
            started = self.started(r)
            eq = int(self.run_eq[r])
            out["runs"].append(
                (
                    pk,
                    rid,
                    int(self.run_unit[r]) + 1,
                    started,
                    "operator",
                    "six_position",
                    SITE_JSON,
                    9.8155,
                    f'{{"temperature_c": {self.run_temp[r]:.2f}}}',
                    None,
                    f"{r:064x}",
                    MODELS[self.unit_model[self.run_unit[r]]][0],  # as the devices row
                    "Acme",
                    None,
                    "mpu6000",
                    f"runs/{rid}",
                    None,
                    None,
                    now,
                )
            )
            out["run_equipment"].append((pk, pk, eq + 1, self.eq_due[eq], None))
            for j in range(3):
                sha = f"{r:056x}{j:08x}"
                out["raw_files"].append(
                    (3 * r + j + 1, pk, f"f{j}.txt", sha, 4096, "csv", f"objects/{sha[:2]}/{sha}")
                )
            verdict = "pass" if self.run_pass[r] else "fail"
            out["calibrations"].append(
                (
                    pk,
                    pk,
                    1,
                    f"{r:064x}",
                    SETTINGS_JSON,
                    "0.1.0",
                    "abc123",
                    now,
                    None,
                    DOCUMENT_JSON,
                    verdict,
                    "mpu6000",
                    "1",
                )
            )
            for j, name in enumerate(("ingest", "outliers", "solve")):
                out["processing_steps"].append(
                    (
                        3 * r + j + 1,
                        pk,
                        pk,
                        j,
                        name,
                        STEP_JSON[name],
                        STATS_JSON,
                        "0.1.0",
                        "abc123",
                    )
                )
            for j in range(2):
                out["check_results"].append(
                    (
                        2 * r + j + 1,
                        pk,
                        f"check{j}",
                        0.01,
                        0.1,
                        verdict == "pass" or j == 1,
                        "",
                        "mpu6000",
                        "1",
                    )
                )
        # Parameters (50 per run, 5M in all) built column-wise with numpy, then zipped:
        # a Python loop per row would dominate the load.
        n = hi - lo
        names = np.repeat(NAMES, len(TEMPS)).tolist()
        units = np.repeat([params.unit_of(x) for x in NAMES], len(TEMPS)).tolist()
        out["parameters"] = zip(
            range(lo * n_p + 1, hi * n_p + 1),
            np.repeat(np.arange(lo, hi) + 1, n_p).tolist(),
            names * n,
            values.ravel().tolist(),
            stds.ravel().tolist(),
            units * n,
            list(TEMPS) * (len(NAMES) * n),
            strict=True,
        )
        return out


COLUMNS = {
    "devices": "id, serial, model, manufacturer, specification, created_at",
    "equipment": "id, kind, model, serial, accuracy_class, calibration_due, calibrated_on",
    "runs": "id, run_id, device_id, started_at, operator, procedure, site, gravity, environment, "
    "manifest_text, raw_hash, model, manufacturer, specification, tolerance_profile, run_dir, "
    "samples_path, samples_sha256, created_at",
    "run_equipment": "id, run_id, equipment_id, calibration_due, calibrated_on",
    "raw_files": "id, run_id, name, sha256, size, format, stored_path",
    "calibrations": "id, run_id, revision, settings_hash, settings, software_version, "
    "source_revision, created_at, superseded_by, document, verdict, profile_name, profile_version",
    "processing_steps": "id, run_id, calibration_id, seq, name, settings, statistics, "
    "software_version, source_revision",
    "parameters": "id, calibration_id, name, value, std, unit, temperature_c",
    "check_results": 'id, calibration_id, name, value, "limit", passed, detail, profile_name, '
    "profile_version",
}


def _sqlite_value(v):  # noqa: ANN001, ANN202
    # The formats SQLAlchemy's SQLite dialect writes (UTCDateTime stores naive UTC).
    if isinstance(v, datetime):
        return v.astimezone(UTC).strftime("%Y-%m-%d %H:%M:%S.%f")
    if isinstance(v, date):
        return v.isoformat()
    return v


def load_sqlite(archive: Archive, synth: Synth) -> None:
    raw = archive.engine().raw_connection()
    cur = raw.cursor()
    cur.execute("PRAGMA synchronous=OFF")  # a benchmark load: durability is not measured

    def put(table: str, rows: Iterable[tuple]) -> None:
        marks = ", ".join("?" * len(COLUMNS[table].split(",")))
        if table != "parameters":  # (numbers and strings only: no conversion needed)
            rows = [tuple(_sqlite_value(v) for v in r) for r in rows]
        cur.executemany(f"INSERT INTO {table} ({COLUMNS[table]}) VALUES ({marks})", rows)

    _load(synth, put, lambda: cur.execute("BEGIN"), lambda: cur.execute("COMMIT"))
    raw.close()
    _derive_unit_latest(archive)
    with archive.engine().begin() as conn:
        conn.exec_driver_sql("ANALYZE")


def load_postgresql(archive: Archive, synth: Synth) -> None:
    import psycopg

    with psycopg.connect(libpq_dsn(archive.url)) as conn, conn.cursor() as cur:

        def put(table: str, rows: Iterable[tuple]) -> None:
            with cur.copy(f"COPY {table} ({COLUMNS[table]}) FROM STDIN") as cp:
                for r in rows:
                    cp.write_row(r)

        _load(synth, put, lambda: None, conn.commit)
        for table in COLUMNS:  # later inserts (archive_run) continue after the loaded ids
            cur.execute(
                f"SELECT setval(pg_get_serial_sequence('{table}', 'id'), "
                f"(SELECT coalesce(max(id), 1) FROM {table}))"
            )
        conn.commit()
    # Statistics first: without them the planner joins the derivation's picks to the
    # parameters by a nested loop over the whole table (minutes at 20k runs, not
    # seconds). An archive grown by archive_run has them from autovacuum.
    admin_execute(archive.url, "ANALYZE")
    _derive_unit_latest(archive)
    admin_execute(archive.url, "VACUUM ANALYZE")


def _derive_unit_latest(archive: Archive) -> None:
    """The derived picks and values per unit (storage.unit_latest), as archive_run keeps them."""
    with archive.engine().begin() as conn:
        unit_latest.rebuild(conn)


def _load(synth: Synth, put: Callable, begin: Callable, commit: Callable) -> None:
    t0 = time.perf_counter()
    begin()
    put("devices", synth.devices())
    put("equipment", synth.equipment())
    commit()
    for lo in range(0, synth.n_runs, CHUNK_RUNS):
        rows = synth.chunk(lo, min(lo + CHUNK_RUNS, synth.n_runs))
        begin()
        for table in RUN_TABLES:
            put(table, rows[table])
        commit()
        done = min(lo + CHUNK_RUNS, synth.n_runs)
        if done % (5 * CHUNK_RUNS) == 0 or done == synth.n_runs:
            log(f"  {done} runs loaded ({time.perf_counter() - t0:.0f} s)")


# --- timing ----------------------------------------------------------------------------


def timed(fn: Callable[[], object], n: int, cpu: np.ndarray | None = None) -> np.ndarray:
    """Wall seconds of `n` calls; their CPU seconds (this process's) into `cpu` if given."""
    out = np.empty(n)
    for i in range(n):
        c, t = time.process_time(), time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t
        if cpu is not None:
            cpu[i] = time.process_time() - c
    return out


def cases(synth: Synth, rng: np.random.Generator) -> Iterator[tuple[str, Callable[[], Callable]]]:
    """(query name, factory of one randomly chosen call)."""

    def latest():  # noqa: ANN202
        u = int(rng.integers(synth.n_units))
        at = (T0 + timedelta(seconds=float(rng.uniform(0, SPAN_S)))).date()
        return lambda a: queries.latest_valid(a, synth.serial(u), at)

    def lineage():  # noqa: ANN202
        r, n = int(rng.integers(synth.n_runs)), NAMES[int(rng.integers(len(NAMES)))]
        return lambda a: queries.lineage(a, synth.run_id(r), n)

    def history():  # noqa: ANN202
        u, n = int(rng.integers(synth.n_units)), NAMES[int(rng.integers(len(NAMES)))]
        return lambda a: queries.serial_parameter_history(a, synth.serial(u), n)

    def lapsed():  # noqa: ANN202
        e = int(rng.integers(N_EQUIPMENT))
        return lambda a: queries.lapsed_runs(a, f"RT-{e}")

    def units():  # noqa: ANN202
        d = (T0 + timedelta(seconds=float(rng.uniform(0, SPAN_S - 40 * 86400)))).date()
        return lambda a: queries.units(
            a, model="MPU-6000", date_from=d, date_to=d + timedelta(days=30), verdict="pass"
        )

    yield from [
        ("latest_valid", latest),
        ("lineage", lineage),
        ("history", history),
        ("lapsed", lapsed),
        ("units", units),
    ]


def bench(archive: Archive, synth: Synth) -> dict[str, dict[str, float]]:
    rng = np.random.default_rng(SEED + 1)
    result = {}
    for name, make in cases(synth, rng):
        calls = [make() for _ in range(SAMPLES[name])]
        for c in calls[:5]:  # warm the caches and the statement cache
            c(archive)
        it, cpu = iter(calls), np.empty(len(calls))
        s = timed(lambda it=it: next(it)(archive), len(calls), cpu)
        # CPU: of this process (the whole query on SQLite; the client's part on
        # PostgreSQL); on a busy machine the wall p95 also holds waits for a core.
        result[name] = {
            "p50_ms": 1e3 * float(np.median(s)),
            "p95_ms": 1e3 * float(np.percentile(s, 95)),
            "cpu_p95_ms": 1e3 * float(np.percentile(cpu, 95)),
        }
        r = result[name]
        log(
            f"  {name}: p50 {r['p50_ms']:.2f} ms, p95 {r['p95_ms']:.2f} ms "
            f"(CPU p95 {r['cpu_p95_ms']:.2f} ms)"
        )
    queries.fleet(archive, "MPU-6000", "acc.bias.x")  # warm
    s = timed(
        lambda: queries.fleet(archive, "MPU-6000", NAMES[int(rng.integers(len(NAMES)))]),
        FLEET_CALLS,
    )
    n = len(queries.fleet(archive, "MPU-6000", "acc.bias.x"))
    result["fleet"] = {
        "p50_ms": 1e3 * float(np.median(s)),
        "p95_ms": 1e3 * float(np.percentile(s, 95)),
        "max_s": float(s.max()),
        "rows": n,
    }
    log(f"  fleet ({n} values): p50 {1e3 * np.median(s):.0f} ms, max {s.max():.3f} s")
    return result


# --- verify on real-looking runs ----------------------------------------------------------

SAMPLE_RUN = ROOT / "data_samples" / "mpu6000_MPU0001"


def template_run(work: Path):  # noqa: ANN201 - (RunIn, protocol bytes)
    """The MPU-6000 sample processed once by the real pipeline (ingest, solve, checks)."""
    from pipelines.ingest import RunSource, load_run
    from pipelines.process import (
        check_run,
        ingest_step,
        protocol_of,
        run_record,
        solve_loaded,
    )

    scratch = Archive(default_archive_url(work / "template"), work / "template")
    scratch.upgrade()
    loaded = load_run(RunSource(SAMPLE_RUN, "mpu6000", "MPU0001"))
    cal, steps, settings, *_ = solve_loaded(loaded)
    judged = check_run(loaded, cal, scratch, "R000000000000")
    run = run_record(loaded, cal, [ingest_step(loaded, 0.0), *steps], settings, judged)
    protocol = protocol_of(loaded, cal, judged, "R000000000000").encode()
    scratch.dispose()
    return run, protocol


def real_runs(n: int, work: Path) -> Iterator:
    """`n` variants of the template: other raw bytes (one line), serial, time, values."""
    from dataclasses import replace

    from storage.run_input import RawFileIn

    run, protocol = template_run(work)
    rng = np.random.default_rng(SEED + 2)
    originals = [(f, Path(f.path).read_bytes()) for f in run.raw_files]
    folder = work / "variant"
    folder.mkdir()
    for i in range(n):
        raw = []
        for f, data in originals:
            body = f"# variant {i}\n".encode() + data
            path = folder / f.name
            path.write_bytes(body)
            raw.append(
                RawFileIn(path, f.name, hashlib.sha256(body).hexdigest(), len(body), f.format)
            )
        params_i = [
            replace(p, value=p.value * (1 + 1e-3 * rng.standard_normal())) for p in run.parameters
        ]
        yield (
            replace(
                run,
                serial=f"MPU{i % 100:04d}",
                raw_files=raw,
                parameters=params_i,
                started_at=T0 + timedelta(hours=i),
            ),
            protocol,
        )


def bench_verify(archive: Archive, n: int, work: Path) -> dict[str, float]:
    """Archive `n` real-looking runs, then time verify with and without the seals."""
    from storage.archive import archive_run
    from storage.verify import verify

    archive.upgrade()
    t = time.perf_counter()
    for run, protocol in real_runs(n, work):
        archive_run(archive, run, {f"{run.serial}_result.txt": protocol})
    log(f"  {n} real-looking runs archived in {time.perf_counter() - t:.0f} s")
    times = {}
    # Each timed twice in turns, the faster kept: the first pass also warms the caches.
    for name, seals in (("files_only", False), ("full", True)) * 2:
        t = time.perf_counter()
        report = verify(archive, orphans=False, seals=seals)
        times[name] = min(times.get(name, np.inf), time.perf_counter() - t)
        assert report.ok and report.runs_checked == n, report.problems[:3]
    per_1k = {k: v * 1000 / n for k, v in times.items()}
    log(
        f"  verify: {per_1k['full']:.2f} s per 1k runs with seals, "
        f"{per_1k['files_only']:.2f} s files only ({report.bytes_checked / 1e6:.0f} MB read)"
    )
    return {
        "verify_s_per_1k_runs": round(per_1k["full"], 3),
        "verify_files_only_s_per_1k_runs": round(per_1k["files_only"], 3),
        "verify_ratio": round(per_1k["full"] / per_1k["files_only"], 3),
    }


def run_backend(
    kind: str, archive: Archive, synth: Synth
) -> tuple[dict[str, dict[str, float]], list[float]]:
    """The figures of `bench`, and the 1-minute load average before and after it."""
    log(f"{kind}: migrating")
    archive.upgrade()
    t = time.perf_counter()
    (load_sqlite if kind == "sqlite" else load_postgresql)(archive, synth)
    log(f"{kind}: loaded in {time.perf_counter() - t:.0f} s; timing queries")
    archive.dispose()
    before = round(os.getloadavg()[0], 2)
    result = bench(archive, synth)
    return result, [before, round(os.getloadavg()[0], 2)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=100_000)
    ap.add_argument("--verify-runs", type=int, default=1000)
    ap.add_argument(
        "--backends", default="sqlite,postgresql", help="comma-separated, of sqlite, postgresql"
    )
    args = ap.parse_args()
    backends = [b for b in args.backends.split(",") if b]
    if not backends or set(backends) - {"sqlite", "postgresql"}:
        ap.error(f"--backends: expected some of sqlite, postgresql, got {args.backends!r}")
    synth = Synth(args.runs)
    n_params = args.runs * len(NAMES) * len(TEMPS)
    log(f"{args.runs} runs, {synth.n_units} units, {n_params} parameter rows")
    work = Path(tempfile.mkdtemp(prefix="calib-bench-"))
    results, verify_results, loads = {}, {}, {}
    try:
        if "sqlite" in backends:
            sq = Archive(default_archive_url(work / "sqlite"), work / "sqlite")
            results["sqlite"], loads["sqlite"] = run_backend("sqlite", sq, Synth(args.runs))
            sq.dispose()
            log("sqlite: verify")
            vq = Archive(default_archive_url(work / "vsqlite"), work / "vsqlite")
            verify_results["sqlite"] = bench_verify(vq, args.verify_runs, work / "vs")
            vq.dispose()
        if "postgresql" in backends:
            with private_server(
                shared_buffers="512MB", max_wal_size="4GB", synchronous_commit="off"
            ) as server:
                admin_execute(server, 'CREATE DATABASE "bench"')
                pg = Archive(server.rsplit("/", 1)[0] + "/bench", work / "pg")
                results["postgresql"], loads["postgresql"] = run_backend(
                    "postgresql", pg, Synth(args.runs)
                )
                pg.dispose()
                log("postgresql: verify")
                admin_execute(server, 'CREATE DATABASE "vbench"')
                vp = Archive(server.rsplit("/", 1)[0] + "/vbench", work / "vpg")
                verify_results["postgresql"] = bench_verify(vp, args.verify_runs, work / "vp")
                vp.dispose()
    finally:
        shutil.rmtree(work, ignore_errors=True)

    print(f"{'query':<14}{'back end':<12}{'p50 ms':>10}{'p95 ms':>10}{'CPU p95 ms':>12}")
    for backend, res in results.items():
        for q, r in res.items():
            cpu = f"{r['cpu_p95_ms']:>12.2f}" if "cpu_p95_ms" in r else ""
            print(f"{q:<14}{backend:<12}{r['p50_ms']:>10.2f}{r['p95_ms']:>10.2f}{cpu}")
    summary = {
        b: {
            "latest_valid_p95_ms": round(r["latest_valid"]["p95_ms"], 3),
            "lineage_p95_ms": round(r["lineage"]["p95_ms"], 3),
            "latest_valid_cpu_p95_ms": round(r["latest_valid"]["cpu_p95_ms"], 3),
            "lineage_cpu_p95_ms": round(r["lineage"]["cpu_p95_ms"], 3),
            "load_average": loads[b],
            "history_p95_ms": round(r["history"]["p95_ms"], 3),
            "fleet_s": round(r["fleet"]["max_s"], 4),
            **verify_results[b],
        }
        for b, r in results.items()
    }
    print(f"verify per 1k real-looking runs ({args.verify_runs} archived), target ratio <= 2:")
    for b, v in verify_results.items():
        print(
            f"  {b:<12} {v['verify_s_per_1k_runs']:.2f} s with seals, "
            f"{v['verify_files_only_s_per_1k_runs']:.2f} s files only, ratio {v['verify_ratio']}"
        )
    print(
        json.dumps(
            {
                **summary,
                "runs": args.runs,
                "parameter_rows": n_params,
                "verify_runs": args.verify_runs,
            }
        )
    )


if __name__ == "__main__":
    main()
