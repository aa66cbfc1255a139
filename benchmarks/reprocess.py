"""Reprocessing benchmark: a whole archive re-solved as new revisions, and recomputed
(`calib verify --recompute --all`), SQLite and PostgreSQL + Dask.

Writes `--runs` simulated six-position + integral runs (calib_core.simulate at
`--rate-hz`, CSV layout; benchmarks/batch.py's generator), then on each back end:

1. process them fresh into an empty archive with the `process_batch` flow
   (SQLite: the process runner, 2 workers, as `calib process --runner process`;
   PostgreSQL: a temporary local Dask cluster of 2 single-threaded workers, as
   `calib process --runner dask`, with a private PostgreSQL server);
2. recompute them (`calib verify --recompute --all`: the `recompute_batch` flow on the
   same runner): every revision solved again from its raw bytes and compared with its
   rows; every run must come out "identical";
3. change the tolerance profile the runs name (its version, in a CALIB_PROFILES
   folder, as a lab changes a profile), so every run's settings hash changes;
4. reprocess the whole archive with the `reprocess_batch` flow on the same runner
   (`calib reprocess --all`): each run restored from its archived raw bytes,
   re-solved, archived as revision 2. Every outcome must be "revised".

Both passes are timed from the flow call to its last outcome (the pool or cluster
start included); Prefect's temporary API server is started and warmed before, and a
one-run batch warms the forkserver, so neither pass pays a one-off start the other
does not. Figures: runs/min of the reprocessing on each back end, and
reprocess_to_process_ratio = reprocessing time / fresh processing time on SQLite
(the same runs, runner and workers), with the PostgreSQL + Dask ratio beside it;
recompute_to_process = recomputation time / fresh processing time (SQLite; the
PostgreSQL + Dask one beside it), the recomputation's seconds beside the processing's.

Progress goes to stderr; the last stdout line is one JSON object:
reprocess_runs_per_min_sqlite, reprocess_runs_per_min_pg_dask,
reprocess_to_process_ratio (the issue's keys), reprocess_to_process_ratio_pg_dask,
recompute_to_process, recompute_to_process_pg_dask, process_s_*, recompute_s_*,
runs, rate_hz.

Run: ``.venv/bin/python benchmarks/reprocess.py [--runs N] [--rate-hz F] [--runs-dir DIR]
[--backends sqlite,pg_dask]`` (the issue's size is 2000 runs; ``--runs-dir`` keeps the
simulated runs for the next measurement: writing 2000 takes ~20 minutes). Each back
end's archive holds a raw copy of every run: the runs take ~15 MB each at 1 kHz, so
2000 runs need ~31 GB for the runs and as much again for one archive (the SQLite
archive is removed before the PostgreSQL pass); the script refuses a back end the free
disk cannot hold.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("DO_NOT_TRACK", "1")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import batch  # noqa: E402 - benchmarks/batch.py: the run generator

RUNS = 2000
WORKERS = 2
PROFILE = "mpu6000"  # the profile the simulated runs name (six_position_manifest)
BACKENDS = ("sqlite", "pg_dask")


def set_profile_version(folder: Path, version: str) -> None:
    """The shipped profile under another version in `folder` (CALIB_PROFILES): same limits,
    a new settings hash for every run judged by it."""
    text = (ROOT / "pipelines" / "profiles" / f"{PROFILE}.toml").read_text()
    line = next(x for x in text.splitlines() if x.startswith("version = "))
    (folder / f"{PROFILE}.toml").write_text(text.replace(line, f'version = "{version}"', 1))


def timed(label: str, call, n: int, expected: str) -> float:  # noqa: ANN001 - a flow call
    started = time.perf_counter()
    outcomes = call()
    seconds = time.perf_counter() - started
    bad = [{k: o[k] for k in ("run_id", "status", "error")} | {"revisions": o.get("revisions")}
           for o in outcomes if o["status"] != expected]  # fmt: skip
    if len(outcomes) != n or bad:
        raise SystemExit(f"{label}: {len(outcomes)} outcomes, {len(bad)} not {expected}: {bad[:1]}")
    batch.log(f"  {label}: {seconds:.1f} s, {60 * n / seconds:.1f} runs/min")
    return seconds


def backend(name: str, archive: str, day: Path, profiles: Path, runner: str, n: int):
    """Fresh processing, its recomputation, then a profile change and the reprocessing;
    their seconds."""
    from pipelines.flows import process_batch, recompute_batch, reprocess_batch
    from pipelines.recompute import plan_recompute
    from storage.db import resolve_archive

    set_profile_version(profiles, f"bench-{name}-1")
    process_s = timed(
        f"{name} process",
        lambda: process_batch([str(day)], archive, runner=runner, workers=WORKERS),
        n,
        "ok",
    )
    run_ids = plan_recompute(resolve_archive(archive))  # `calib verify --recompute --all`
    recompute_s = timed(
        f"{name} recompute",
        lambda: recompute_batch(run_ids, archive, runner=runner, workers=WORKERS),
        n,
        "identical",
    )
    set_profile_version(profiles, f"bench-{name}-2")
    reprocess_s = timed(
        f"{name} reprocess",
        lambda: reprocess_batch("benchmark", {}, archive=archive, runner=runner, workers=WORKERS),
        n,
        "revised",
    )
    return process_s, reprocess_s, recompute_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=RUNS)
    parser.add_argument("--rate-hz", type=float, default=batch.RATE_HZ)
    parser.add_argument(
        "--runs-dir",
        type=Path,
        help="keep the simulated runs in DIR/day (written there if missing) for later "
        "measurements; default: a temporary folder",
    )
    parser.add_argument(
        "--backends", default=",".join(BACKENDS), help=f"comma-separated, of {', '.join(BACKENDS)}"
    )
    args = parser.parse_args()
    backends = [b for b in args.backends.split(",") if b]
    if not backends or set(backends) - set(BACKENDS):
        parser.error(f"--backends: expected some of {', '.join(BACKENDS)}, got {args.backends!r}")
    n = args.runs
    with tempfile.TemporaryDirectory(prefix="calib-reprocess-bench-") as tmp:
        base = Path(tmp)
        profiles = base / "profiles"
        profiles.mkdir()
        # Before any worker process starts: the forkserver and Dask workers inherit it.
        os.environ["CALIB_PROFILES"] = str(profiles)
        day = runs_in(args.runs_dir or base, n, args.rate_hz)
        size = sum(f.stat().st_size for d in day.iterdir() for f in d.iterdir())
        batch.log(f"  {size / 1e9:.1f} GB of runs")
        figures = run_backends(base, day, profiles, n, size, backends)
    print(json.dumps({**figures, "runs": n, "rate_hz": args.rate_hz}))


def runs_in(folder: Path, n: int, rate_hz: float) -> Path:
    """`folder`/day holding `n` simulated runs at `rate_hz`, written unless there already
    (their rate is noted beside them: runs of another rate are refused)."""
    day, note = folder / "day", folder / "rate_hz.txt"
    if note.is_file() and float(note.read_text()) != rate_hz:
        raise SystemExit(
            f"{folder}: its runs are at {note.read_text().strip()} Hz, not {rate_hz:g}"
        )
    have = sorted(day.glob("run*")) if day.is_dir() else []
    if len(have) >= n and note.is_file():
        batch.log(f"using {n} of the {len(have)} simulated {rate_hz:g} Hz runs in {day}")
        if len(have) > n:  # the flows take a whole folder: the first n, linked into another
            day = _linked_runs(have[:n], folder / f"day-{n}")
        return day
    batch.log(f"writing {n} simulated {rate_hz:g} Hz CSV runs to {folder}...")
    batch.generate(folder, n, rate_hz)
    note.write_text(f"{rate_hz:g}")
    return day


def _linked_runs(runs: list[Path], into: Path) -> Path:
    """`into` holding hard links of `runs` (made once)."""
    if not into.is_dir():
        for run in runs:
            shutil.copytree(run, into / run.name, copy_function=os.link)
    return into


def require_space(base: Path, size: int) -> None:
    """Refuse before a back end whose archive (a raw copy of every run, Parquet samples, the
    database) cannot fit: a full disk half-way through would measure nothing."""
    free = shutil.disk_usage(base).free
    if free < 1.5 * size:
        raise SystemExit(
            f"{base}: {free / 1e9:.1f} GB free, an archive of these runs needs about "
            f"{1.5 * size / 1e9:.1f} GB; use fewer --runs or a lower --rate-hz"
        )


def run_backends(
    base: Path, day: Path, profiles: Path, n: int, size: int, backends: list[str]
) -> dict[str, float]:
    from prefect.client.orchestration import get_client

    from calib_testing.pgserver import admin_execute, private_server
    from pipelines.flows import local_batch_settings, process_batch

    seconds: dict[str, tuple[float, float, float]] = {}
    with local_batch_settings():
        with get_client(sync_client=True) as client:
            client.api_healthcheck()
            client.api_version()
        set_profile_version(profiles, "warm-up")
        shutil.copytree(day / "run000", base / "warm" / "run000")
        process_batch(
            [str(base / "warm")], str(base / "warm-archive"), runner="process", workers=WORKERS
        )
        if "sqlite" in backends:
            require_space(base, size)
            seconds["sqlite"] = backend("sqlite", str(base / "sqlite"), day, profiles, "process", n)
            shutil.rmtree(base / "sqlite")  # its raw copies: the disk holds one archive at a time
        if "pg_dask" in backends:
            require_space(base, size)
            with private_server(shared_buffers="256MB") as server:
                admin_execute(server, 'CREATE DATABASE "bench"')
                os.environ["CALIB_FILESTORE"] = str(base / "pg-files")
                url = server.rsplit("/", 1)[0] + "/bench"
                seconds["pg_dask"] = backend("pg_dask", url, day, profiles, "dask", n)
    return {
        key: value
        for name, times in seconds.items()
        for key, value in figures(name, n, *times).items()
    }


def figures(
    backend_: str, n: int, process_s: float, reprocess_s: float, recompute_s: float
) -> dict[str, float]:
    """The figures of one back end (the issues name SQLite's ratios without a suffix)."""
    suffix = "" if backend_ == "sqlite" else f"_{backend_}"
    return {
        f"reprocess_runs_per_min_{backend_}": round(60 * n / reprocess_s, 2),
        f"reprocess_to_process_ratio{suffix}": round(reprocess_s / process_s, 3),
        f"process_runs_per_min_{backend_}": round(60 * n / process_s, 2),
        f"process_s_{backend_}": round(process_s, 2),
        f"recompute_s_{backend_}": round(recompute_s, 2),
        f"recompute_to_process{suffix}": round(recompute_s / process_s, 3),
    }


if __name__ == "__main__":
    main()
