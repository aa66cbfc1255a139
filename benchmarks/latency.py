"""Latency of everyday commands: `calib process` of one run, `calib --help`.

For the MPU-6000 and the CSV sample of data_samples/, in the same run:

- ``one_run_wall_s``: wall time of ``calib process RUN --json`` in a fresh process
  (a new archive each time), the slower of the two samples, median of `REPEATS`;
- ``help_wall_s``: wall time of ``calib --help`` in a fresh process, median;
- ``one_run_to_solve_ratio``: a run's wall time over the in-process time of its bare
  read + preprocess + solve (`load_run` + `solve_loaded`, imports warm), the larger
  of the two samples.

The command is started as the `calib` entry point of this interpreter's environment.
Progress goes to stderr; the last stdout line is one JSON object with the figures.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = {
    "mpu6000": ROOT / "data_samples" / "mpu6000_MPU0001",
    "csv": ROOT / "data_samples" / "csv_IMU-2026-0042",
}
REPEATS = 5


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _calib() -> list[str]:
    exe = shutil.which("calib", path=str(Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, "-m", "pipelines.cli"]


def _wall(args: list[str], env: dict[str, str]) -> float:
    started = time.perf_counter()
    done = subprocess.run(args, capture_output=True, text=True, env=env, timeout=600)
    took = time.perf_counter() - started
    if done.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(args)} exited {done.returncode}: {done.stderr[-2000:]}")
    return took


def _bare_seconds(folder: Path) -> float:
    """Median in-process time of read + preprocess + solve of one run (imports warm)."""
    from pipelines.ingest import discover_runs, load_run
    from pipelines.process import solve_loaded

    (source,) = discover_runs([folder])
    times = []
    for _ in range(REPEATS + 1):  # the first warms imports and caches
        started = time.perf_counter()
        solve_loaded(load_run(source))
        times.append(time.perf_counter() - started)
    return statistics.median(times[1:])


def main() -> None:
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    env.update(DO_NOT_TRACK="1", PREFECT_SERVER_ANALYTICS_ENABLED="false")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    calib = _calib()
    helps = [_wall([*calib, "--help"], env) for _ in range(REPEATS)]
    log(f"calib --help: median {statistics.median(helps):.3f} s of {helps}")
    figures = {}
    with tempfile.TemporaryDirectory(prefix="calib-latency-") as tmp:
        for name, folder in SAMPLES.items():
            walls = []
            for i in range(REPEATS):
                archive = str(Path(tmp) / f"{name}-{i}")
                walls.append(_wall([*calib, "process", str(folder), "--archive", archive,
                                    "--json", "--no-progress"], env))  # fmt: skip
            bare = _bare_seconds(folder)
            wall = statistics.median(walls)
            figures[name] = {"wall_s": wall, "bare_s": bare, "ratio": wall / bare}
            log(f"{name}: calib process median {wall:.3f} s, bare read + solve {bare:.3f} s")
    print(json.dumps(figures, indent=1))
    print(json.dumps({
        "one_run_wall_s": round(max(f["wall_s"] for f in figures.values()), 3),
        "help_wall_s": round(statistics.median(helps), 3),
        "one_run_to_solve_ratio": round(max(f["ratio"] for f in figures.values()), 2),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
