"""Nothing kills a batch, and nothing of `calib` outlives it.

Real `calib process` subprocesses on real files: a MAT v5 file with 8 zeroed
bytes (which makes scipy's reader segfault) is one failed run among good runs,
and `out=$(calib process ...)` returns; `calib` killed by signal 9 in the middle
of a batch leaves no Prefect server and no worker process behind (found by a
marker in the environment every child inherits); a worker killed by signal 9
costs a retry, not the batch.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from test_ingest_formats_e2e import manifest

from calib_core.simulate import random_errors, six_position_integral_run

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
# Zeroing these 8 bytes of the first variable's real part makes the data element's type
# code 0, which scipy 1.17's reader dereferences as a null dtype (signal 11).
V5_TAG_OFFSET = 252


def write_mat5_run(folder: Path, serial: str, seed: int, *, static_s: float = 3.0) -> None:
    """A six-position run, one MATLAB v5 file per segment (scipy.io.savemat, struct `imu`)."""
    rng = np.random.default_rng(seed)
    sim = six_position_integral_run(random_errors(rng), rng, static_s=static_s)
    folder.mkdir(parents=True)
    files = {}
    for label, rec in sim.segments.items():
        imu = {"t": rec.t, "acc": rec.acc / 9.80665, "gyr": np.degrees(rec.gyr)}
        scipy.io.savemat(folder / f"{label}.mat", {"imu": imu})
        files[label] = f"{label}.mat"
    fmt = {
        "kind": "mat",
        "acc_unit": "g",
        "gyr_unit": "deg/s",
        "variables": {"t": "imu.t", "acc": "imu.acc", "gyr": "imu.gyr"},
    }
    (folder / "run.toml").write_text(manifest(serial, fmt, files))


def zero_bytes(path: Path, offset: int, count: int = 8) -> None:
    data = bytearray(path.read_bytes())
    data[offset : offset + count] = bytes(count)
    path.write_bytes(bytes(data))


def segfaults_scipy(path: Path) -> bool:
    """True if scipy's own reader kills a fresh interpreter on this file (the premise)."""
    code = f"import scipy.io; scipy.io.loadmat({str(path)!r}, simplify_cells=True)"
    return subprocess.run([sys.executable, "-c", code], capture_output=True).returncode < 0


def calib_env(tag: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API")}
    env.update(
        PYTHONPATH=str(ROOT),
        CALIB_TEST_TAG=tag,
        DO_NOT_TRACK="1",
        PREFECT_SERVER_ANALYTICS_ENABLED="false",
    )
    env.pop("PREFECT_HOME", None)
    return env


def tagged_processes(tag: str) -> list[tuple[int, str]]:
    """Live processes (pid, command line) whose environment holds CALIB_TEST_TAG=tag."""
    found = []
    marker = f"CALIB_TEST_TAG={tag}".encode()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if marker in (entry / "environ").read_bytes().split(b"\0"):
                state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
                if state != "Z":  # a zombie is already dead (its parent has not reaped it)
                    cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
                    found.append((int(entry.name), cmd))
        except OSError:
            continue
    return found


def forked_workers(tag: str) -> list[int]:
    """Worker processes: children of a forkserver (they share its command line)."""
    procs = dict(tagged_processes(tag))
    ppid = {
        p: int(Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[1])
        for p in procs
        if Path(f"/proc/{p}").exists()
    }
    return [
        p
        for p, c in procs.items()
        if "forkserver" in c and "forkserver" in procs.get(ppid.get(p, 0), "")
    ]


def wait_gone(tag: str, timeout_s: float) -> list[tuple[int, str]]:
    deadline = time.monotonic() + timeout_s
    while (left := tagged_processes(tag)) and time.monotonic() < deadline:
        time.sleep(0.2)
    return left


def kill_tagged(tag: str) -> None:
    for pid, _ in tagged_processes(tag):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def batch_cmd(runs: Path, archive: Path, runner: str = "process") -> list[str]:
    """`calib process RUNS --json` into `archive` on two workers of `runner`, no progress bar."""
    return [
        sys.executable,
        "-m",
        "pipelines.cli",
        "process",
        str(runs),
        "--json",
        "--archive",
        str(archive),
        "--runner",
        runner,
        "--workers",
        "2",
        "--no-progress",
    ]


def long_runs(folder: Path, n: int, prefix: str, seed: int) -> Path:
    """`n` MAT v5 runs ``run<i>`` of 20 s static segments (a batch that lasts), serials prefix-i."""
    for i in range(n):
        write_mat5_run(folder / f"run{i}", f"{prefix}-{i}", seed=seed + i, static_s=20.0)
    return folder


def start_batch(runs: Path, archive: Path, stderr: int) -> tuple[subprocess.Popen, str]:
    """`batch_cmd` started with a fresh tag (to find its processes); stdout piped."""
    tag = uuid.uuid4().hex
    proc = subprocess.Popen(
        batch_cmd(runs, archive), env=calib_env(tag), stdout=subprocess.PIPE, stderr=stderr
    )
    return proc, tag


@pytest.fixture
def batch(tmp_path: Path) -> Path:
    """Three MAT v5 runs; the second has 8 zeroed bytes that segfault scipy."""
    runs = tmp_path / "runs"
    for i in range(3):
        write_mat5_run(runs / f"run{i}", f"SIM-MAT5-{i}", seed=40 + i)
    damaged = runs / "run1" / "x_up.mat"
    zero_bytes(damaged, V5_TAG_OFFSET)
    assert segfaults_scipy(damaged)
    return runs


@pytest.mark.parametrize("runner", ["local", "process"])
def test_segfaulting_file_is_one_failed_run(batch: Path, tmp_path: Path, runner: str) -> None:
    tag = uuid.uuid4().hex
    cmd = batch_cmd(batch, tmp_path / f"archive-{runner}", runner)
    try:
        # communicate() waits for EOF on stdout: a child holding it would hang here.
        done = subprocess.run(cmd, env=calib_env(tag), capture_output=True, timeout=120)
        left = wait_gone(tag, 10)
    finally:
        kill_tagged(tag)
    assert done.returncode == 1, done.stderr.decode()[-3000:]
    outcomes = {Path(o["source"]).name: o for o in json.loads(done.stdout)["runs"]}
    assert [outcomes[f"run{i}"]["status"] for i in range(3)] == ["ok", "failed", "ok"]
    error = outcomes["run1"]["error"]
    assert "run1/x_up.mat" in error and "crashed on this file" in error, error
    assert "internal error" not in error and "Traceback" not in done.stderr.decode()
    assert left == [], f"processes outlived calib: {left}"


def test_calib_killed_leaves_no_server_or_worker(tmp_path: Path) -> None:
    runs = long_runs(tmp_path / "runs", 8, "SIM-KILL", seed=60)
    proc, tag = start_batch(runs, tmp_path / "archive", stderr=subprocess.DEVNULL)
    try:
        # Wait until the batch is under way: the API server and both workers are up.
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            server = any("temporary_api" in c for _, c in tagged_processes(tag))
            if server and forked_workers(tag):
                break
            time.sleep(0.2)
        else:
            pytest.fail(f"batch did not start: {tagged_processes(tag)}")
        time.sleep(1.0)
        proc.kill()
        started = time.monotonic()
        with contextlib.suppress(subprocess.TimeoutExpired):  # EOF: no process holds stdout
            proc.communicate(timeout=30)
        eof_s = time.monotonic() - started
        left = wait_gone(tag, 10)
    finally:
        proc.kill()
        kill_tagged(tag)
    assert left == [], f"processes outlived calib killed by signal 9: {left}"
    assert eof_s < 10, f"stdout held open {eof_s:.1f} s after calib died"


def test_worker_killed_costs_a_retry_not_the_batch(tmp_path: Path) -> None:
    runs = long_runs(tmp_path / "runs", 4, "SIM-WK", seed=80)
    proc, tag = start_batch(runs, tmp_path / "archive", stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        victim = None
        while victim is None and time.monotonic() < deadline:
            victim = next(iter(forked_workers(tag)), None)
            time.sleep(0.1)
        assert victim is not None, "no worker process seen"
        os.kill(victim, signal.SIGKILL)
        out, errs = proc.communicate(timeout=120)
        left = wait_gone(tag, 10)
    finally:
        proc.kill()
        kill_tagged(tag)
    assert proc.returncode == 0, errs.decode()[-3000:]
    assert [o["status"] for o in json.loads(out)["runs"]] == ["ok"] * 4
    assert left == []
