"""Latency of everyday commands: `calib process` of one run, `calib --help`.

For the MPU-6000 and the CSV sample of data_samples/, in the same run:

- ``one_run_wall_s``: wall time of ``calib process RUN --json`` in a fresh process
  (a new archive each time, its certificate issued), the slower of the two samples,
  median of `REPEATS`;
- ``certificate_wall_ratio``: that run's wall time over the same run's with
  ``CALIB_ISSUE_CERTIFICATES=0`` (run right after it: each pair sees the same load),
  median of the pairs' ratios, the larger of the two samples (target <= 1.5);
- ``mpu6000_to_bare_science_ratio``: the MPU-6000 run (certificate included) over a
  bare ``python -c "import numpy, scipy.linalg, pandas, sqlalchemy"`` run right after it,
  median of the pairs' ratios (target <= 3);
- ``certificate_cpu_s``: CPU seconds (every thread) of one certificate of the CSV sample
  in a process that has issued one already: HTML and PDF issued into the archive
  (`pipelines.reports.issue.issue`, a re-issue) and the DCC XML built, median of
  `REPEATS` (target <= 0.3); ``certificate_first_cpu_s``: the first one, imports
  included;
- ``help_wall_s``: wall time of ``calib --help`` in a fresh process, median;
- ``one_run_to_solve_ratio``: a run's wall time over the in-process time of its bare
  read + preprocess + solve (`load_run` + `solve_loaded`, imports warm), the larger
  of the two samples (a run's wall time includes typesetting its certificate);
- ``history_wall_s``: wall time of ``calib history MPU0001`` on an archive of the
  MPU-6000 sample, median of `PAIRS`;
- ``bare_imports_wall_s``: wall time of ``python -c "import sqlalchemy.orm, typer,
  rich"`` (what any read-only command needs), median of `PAIRS`, each run right after
  a history run (paired: both see the same load);
- ``history_to_bare_ratio``: the median of the pairs' ratios (target <= 1.5).

``--history-only`` measures the last three alone, ``--certificate-only`` the certificate's
CPU alone, each with the load average at its start and end.

``--flow-only``: what a small batch would cost as the Prefect flow (`--flow`, the local
runner, one worker) instead of in this process (`pipelines.direct`), `calib process` of
each sample without its certificate, in pairs (`FLOW_PAIRS`, the order alternating):
``flow_overhead_wall_s`` / ``flow_overhead_cpu_s``, the median of the pairs' differences
(the larger sample), and ``flow_to_direct_ratio``, the median of their wall ratios (the
smaller sample).

``--batch-only``: ``calib process data_samples --workers 1`` (every sample run: the Prefect
flow on one worker thread, certificates issued beside the next runs) against the same
batch with ``CALIB_ISSUE_CERTIFICATES=0``, each into a new archive, in `BATCH_PAIRS` pairs
(the order alternating): ``batch_cert_ratio``, the median of the pairs' wall-time ratios
(target <= 1.3), with each side's median wall and CPU time.

The command is started as the `calib` entry point of this interpreter's environment,
after the project's packages are byte-compiled (`compile_project`) as an installation
leaves them: with ``PYTHONDONTWRITEBYTECODE`` set and no ``__pycache__`` (an editable
install run so), every start would compile them again, ~0.45 s of CPU that no
installed `calib` spends.
Progress goes to stderr; the last stdout line is one JSON object with the figures.
On a shared machine the wall times follow the load: the per-sample figures also give
each command's CPU time (user + system of the child, median) and the load average.
"""

from __future__ import annotations

import compileall
import json
import os
import resource
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
PAIRS = 9
FLOW_PAIRS = 3
BATCH_PAIRS = 3
BARE_IMPORTS = "import sqlalchemy.orm, typer, rich"
SCIENCE_IMPORTS = "import numpy, scipy.linalg, pandas, sqlalchemy"


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _calib() -> list[str]:
    exe = shutil.which("calib", path=str(Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, "-m", "pipelines.cli"]


def compile_project() -> None:
    """Byte-compile calib_core, storage and pipelines (__pycache__, as pip install does)."""
    for package in ("calib_core", "storage", "pipelines"):
        if not compileall.compile_dir(ROOT / package, quiet=1):
            raise RuntimeError(f"{package} does not compile")


def _timed(args: list[str], env: dict[str, str]) -> tuple[float, float]:
    """(wall, CPU) seconds of the command in a new process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run(args, capture_output=True, text=True, env=env, timeout=600)
    took = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(args)} exited {done.returncode}: {done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return took, cpu


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


# A lab profile with what the DCC requires (the laboratory's and the customer's location).
LAB_TOML = """
[laboratory]
name = "Benchmark Lab"
address = "1 Bench Street, 10115 Berlin, Germany"
country = "DE"

[customer]
name = "Benchmark Customer"
address = "2 Bench Street, 10115 Berlin, Germany"
"""


def certificate_cpu(folder: Path, tmp: Path) -> dict[str, float]:
    """CPU seconds (all threads) of issuing one certificate (HTML + PDF) and its DCC,
    in this process: the first (imports included), then the median of `REPEATS` more.
    A lab profile (`LAB_TOML`) is put first on the profile path: the DCC needs one."""
    os.environ["CALIB_ISSUE_CERTIFICATES"] = "0"
    (tmp / "profiles").mkdir()
    (tmp / "profiles" / "lab.toml").write_text(LAB_TOML)
    os.environ["CALIB_PROFILES"] = str(tmp / "profiles")
    from pipelines.direct import process_in_process
    from pipelines.ingest import discover_runs
    from pipelines.reports.dcc import dcc_xml
    from pipelines.reports.issue import issue
    from pipelines.reports.run_reports import archived_run
    from storage.db import resolve_archive

    (outcome,) = process_in_process(discover_runs([folder]), str(tmp / "certificate"))
    arch = resolve_archive(str(tmp / "certificate"))
    times = []
    for i in range(REPEATS + 1):
        started = time.process_time()
        issue(arch, outcome["run_id"], reason=None if i == 0 else f"benchmark {i}")
        dcc_xml(archived_run(arch, outcome["run_id"]))
        times.append(time.process_time() - started)
    log(f"certificate CPU: first {times[0]:.3f} s, then {[round(t, 3) for t in times[1:]]}")
    return {
        "certificate_cpu_s": round(statistics.median(times[1:]), 3),
        "certificate_first_cpu_s": round(times[0], 3),
    }


def history_latency(calib: list[str], env: dict[str, str], tmp: Path) -> dict[str, float]:
    """`calib history` against the bare imports of a read-only command, in pairs."""
    archive = str(tmp / "history")
    _timed(
        [
            *calib,
            "process",
            str(SAMPLES["mpu6000"]),
            "--archive",
            archive,
            "--json",
            "--no-progress",
        ],
        env,
    )
    history, bare = [], []
    for _ in range(PAIRS):
        history.append(_timed([*calib, "history", "MPU0001", "--archive", archive], env)[0])
        bare.append(_timed([sys.executable, "-c", BARE_IMPORTS], env)[0])
    ratios = [h / b for h, b in zip(history, bare, strict=True)]
    log(
        f"calib history: median {statistics.median(history):.3f} s of "
        f"{[round(h, 3) for h in history]}; bare imports: median "
        f"{statistics.median(bare):.3f} s of {[round(b, 3) for b in bare]}"
    )
    return {
        "history_wall_s": round(statistics.median(history), 3),
        "bare_imports_wall_s": round(statistics.median(bare), 3),
        "history_to_bare_ratio": round(statistics.median(ratios), 2),
    }


def flow_overhead(calib: list[str], env: dict[str, str], tmp: Path) -> dict[str, float]:
    """A small batch through the Prefect flow against the same batch in process (`--flow-only`)."""
    env = {**env, "CALIB_ISSUE_CERTIFICATES": "0"}
    walls, cpus, ratios = [], [], []
    for name, folder in SAMPLES.items():
        pairs = []
        for i in range(FLOW_PAIRS):
            args = [*calib, "process", str(folder), "--json", "--no-progress", "--archive"]
            direct = [*args, str(tmp / f"{name}-direct-{i}")]
            flow = [*args, str(tmp / f"{name}-flow-{i}"), "--flow", "--workers", "1"]
            if i % 2:
                f, d = _timed(flow, env), _timed(direct, env)
            else:
                d, f = _timed(direct, env), _timed(flow, env)
            pairs.append((d, f))
            log(
                f"{name}: in process {d[0]:.2f} s CPU {d[1]:.2f}, flow {f[0]:.2f} s, CPU {f[1]:.2f}"
            )
        walls.append(statistics.median(f[0] - d[0] for d, f in pairs))
        cpus.append(statistics.median(f[1] - d[1] for d, f in pairs))
        ratios.append(statistics.median(f[0] / d[0] for d, f in pairs))
    return {
        "flow_overhead_wall_s": round(max(walls), 3),
        "flow_overhead_cpu_s": round(max(cpus), 3),
        "flow_to_direct_ratio": round(min(ratios), 2),
    }


def batch_certificates(calib: list[str], env: dict[str, str], tmp: Path) -> dict[str, float]:
    """`calib process data_samples --workers 1`, with certificates and without (`--batch-only`)."""
    without_env = {**env, "CALIB_ISSUE_CERTIFICATES": "0"}
    pairs = []
    for i in range(BATCH_PAIRS):
        args = [*calib, "process", str(ROOT / "data_samples"), "--workers", "1", "--json"]
        args += ["--no-progress", "--archive"]
        with_cert = ([*args, str(tmp / f"with-{i}")], env)
        without = ([*args, str(tmp / f"without-{i}")], without_env)
        if i % 2:
            w0, w1 = _timed(*without), _timed(*with_cert)
        else:
            w1, w0 = _timed(*with_cert), _timed(*without)
        pairs.append((w1, w0))
        log(
            f"pair {i + 1}: with certificates {w1[0]:.2f} s (CPU {w1[1]:.2f}), without "
            f"{w0[0]:.2f} s (CPU {w0[1]:.2f}); load {os.getloadavg()[0]:.2f}"
        )
    issued = len(list(tmp.glob("with-0/**/*_certificate.pdf")))
    runs = len(list(tmp.glob("without-0/**/*_result.txt")))
    if issued != runs or not runs:
        raise RuntimeError(f"{issued} certificates issued for {runs} runs")
    return {
        "batch_cert_ratio": round(statistics.median(a[0] / b[0] for a, b in pairs), 3),
        "batch_runs": runs,
        "batch_with_certificates_wall_s": round(statistics.median(a[0] for a, _ in pairs), 2),
        "batch_without_certificates_wall_s": round(statistics.median(b[0] for _, b in pairs), 2),
        "batch_with_certificates_cpu_s": round(statistics.median(a[1] for a, _ in pairs), 2),
        "batch_without_certificates_cpu_s": round(statistics.median(b[1] for _, b in pairs), 2),
    }


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    env.update(DO_NOT_TRACK="1", PREFECT_SERVER_ANALYTICS_ENABLED="false")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return env


def main() -> None:
    env, calib = _env(), _calib()
    compile_project()
    alone = {
        "--certificate-only": lambda tmp: certificate_cpu(SAMPLES["csv"], tmp),
        "--batch-only": lambda tmp: batch_certificates(calib, env, tmp),
        "--flow-only": lambda tmp: flow_overhead(calib, env, tmp),
        "--history-only": lambda tmp: history_latency(calib, env, tmp),
    }
    for option, measure in alone.items():
        if option in sys.argv[1:]:
            load = os.getloadavg()[0]
            with tempfile.TemporaryDirectory(prefix="calib-latency-") as tmp:
                figures = measure(Path(tmp))
            end = os.getloadavg()[0]
            log(f"load average (1 min): {load:.2f} at the start, {end:.2f} at the end")
            print(json.dumps(figures))
            return
    load = os.getloadavg()[0]
    helps = [_timed([*calib, "--help"], env)[0] for _ in range(REPEATS)]
    log(f"calib --help: median {statistics.median(helps):.3f} s of {helps}")
    figures: dict[str, dict[str, float]] = {}
    bare_env = {**env, "CALIB_ISSUE_CERTIFICATES": "0"}
    with tempfile.TemporaryDirectory(prefix="calib-latency-") as tmp:
        for name, folder in SAMPLES.items():
            timed, bare_runs, science = [], [], []
            for i in range(REPEATS):
                args = [*calib, "process", str(folder), "--json", "--no-progress", "--archive"]
                timed.append(_timed([*args, str(Path(tmp) / f"{name}-{i}")], env))
                bare_runs.append(_timed([*args, str(Path(tmp) / f"{name}-bare-{i}")], bare_env))
                science.append(_timed([sys.executable, "-c", SCIENCE_IMPORTS], env)[0])
            bare = _bare_seconds(folder)
            wall = statistics.median(w for w, _ in timed)
            cpu = statistics.median(c for _, c in timed)
            figures[name] = {
                "wall_s": wall,
                "cpu_s": cpu,
                "without_certificate_wall_s": statistics.median(w for w, _ in bare_runs),
                "without_certificate_cpu_s": statistics.median(c for _, c in bare_runs),
                "certificate_ratio": statistics.median(
                    w / b for (w, _), (b, _) in zip(timed, bare_runs, strict=True)
                ),
                "science_imports_wall_s": statistics.median(science),
                "to_science_imports_ratio": statistics.median(
                    w / b for (w, _), b in zip(timed, science, strict=True)
                ),
                "bare_s": bare,
                "ratio": wall / bare,
            }
            log(
                f"{name}: calib process median {wall:.3f} s (CPU {cpu:.3f} s), without the "
                f"certificate {figures[name]['without_certificate_wall_s']:.3f} s (CPU "
                f"{figures[name]['without_certificate_cpu_s']:.3f} s), bare read + solve "
                f"{bare:.3f} s, science imports {figures[name]['science_imports_wall_s']:.3f} s"
            )
        history = history_latency(calib, env, Path(tmp))
        certificate = certificate_cpu(SAMPLES["csv"], Path(tmp))
    figures["load_average"] = {"start": load, "end": os.getloadavg()[0]}
    print(json.dumps(figures, indent=1))
    print(
        json.dumps(
            {
                "one_run_wall_s": round(max(figures[n]["wall_s"] for n in SAMPLES), 3),
                "certificate_wall_ratio": round(
                    max(figures[n]["certificate_ratio"] for n in SAMPLES), 2
                ),
                "mpu6000_to_bare_science_ratio": round(
                    figures["mpu6000"]["to_science_imports_ratio"], 2
                ),
                **certificate,
                "help_wall_s": round(statistics.median(helps), 3),
                "one_run_to_solve_ratio": round(max(figures[n]["ratio"] for n in SAMPLES), 2),
                **history,
            }
        )
    )


if __name__ == "__main__":
    main()
