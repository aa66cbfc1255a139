"""Batches: runner choice, retries of transient errors, and concurrent batches on one archive.

Runs are simulated at the simulator's default 50 Hz (a few tenths of a second
each to process) so the real Prefect flow, real SQLite / PostgreSQL and real
worker processes fit in a short test.
"""

from __future__ import annotations

import errno
import json
import os
import re
import socket
import sqlite3
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import create_engine, func, select
from sqlalchemy.exc import OperationalError

import pipelines.process as process_module
from calib_core.simulate import random_errors, six_position_integral_run
from calib_testing.calib_command import CALIB, run_calib
from calib_testing.run_writers import six_position_manifest, write_csv_run, write_mpu6000_run
from pipelines.ingest import IngestError
from pipelines.run_task import RETRIES, is_transient
from pipelines.runners import check_runner, make_task_runner
from storage import schema
from storage.db import resolve_archive

pytestmark = pytest.mark.e2e

ROOT = Path(__file__).resolve().parents[1]
SUBPROCESS_TIMEOUT_S = 240  # two spawned batches on a shared 2-core machine

MANIFEST = six_position_manifest("BATCH")


def write_runs(folder: Path, seeds: list[int]) -> list[Path]:
    """One CSV run per seed (its own random errors and noise), serial BATCH<seed>."""
    out = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        sim = six_position_integral_run(random_errors(rng), rng)
        manifest = {**MANIFEST, "unit": {**MANIFEST["unit"], "serial": f"BATCH{seed}"}}
        out.append(write_csv_run(sim.segments, folder / f"run{seed}", manifest).parent)
    return out


# --- runner choice --------------------------------------------------------------


def test_runner_choice_names_the_option_at_fault() -> None:
    from prefect.task_runners import ThreadPoolTaskRunner
    from prefect_dask import DaskTaskRunner

    assert isinstance(make_task_runner("local", 3), ThreadPoolTaskRunner)
    assert make_task_runner("local", 3)._max_workers == 3
    # the process runner's tasks stay in threads and hand their runs to WorkerProcesses
    assert isinstance(make_task_runner("process", 2), ThreadPoolTaskRunner)
    remote = make_task_runner("dask", scheduler="tcp://10.0.0.5:8786")
    assert isinstance(remote, DaskTaskRunner) and remote.address == "tcp://10.0.0.5:8786"
    with pytest.raises(ValueError, match="--runner 'threads': expected one of local, process"):
        check_runner("threads", None, None)
    with pytest.raises(ValueError, match="--workers 0: expected a whole number >= 1"):
        check_runner("local", 0, None)
    with pytest.raises(ValueError, match="only used with --runner dask"):
        check_runner("process", None, "tcp://10.0.0.5:8786")
    with pytest.raises(ValueError, match="expected a Dask scheduler address"):
        check_runner("dask", None, "10.0.0.5")
    with pytest.raises(ValueError, match="cannot be combined with --scheduler"):
        check_runner("dask", 2, "tcp://10.0.0.5:8786")


def _worker_facts(_: int) -> tuple[int, str | None]:
    return os.getpid(), os.environ.get("OMP_NUM_THREADS")


def _die() -> None:
    os._exit(3)  # as an out-of-memory kill or a crash in a native library would


def test_worker_processes_run_single_threaded_and_survive_a_dying_worker() -> None:
    """Calls run in 2 worker processes (forked from a forkserver) with single-threaded
    numerical libraries; a worker that dies fails its call with BrokenProcessPool
    (counted as transient, so the batch retries that run), and the next calls run in
    a fresh pool."""
    from concurrent.futures import ThreadPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    from pipelines.runners import WorkerProcesses

    pool = WorkerProcesses(2)
    try:
        with ThreadPoolExecutor(2) as threads:
            facts = list(threads.map(lambda i: pool.run(_worker_facts, i), range(8)))
        pids = {pid for pid, _ in facts}
        assert os.getpid() not in pids and 1 <= len(pids) <= 2
        assert {omp for _, omp in facts} == {"1"}
        with pytest.raises(BrokenProcessPool) as died:
            pool.run(_die)
        assert is_transient(died.value)
        after = {pool.run(_worker_facts, i)[0] for i in range(4)}
        assert after and not after & pids  # new workers
    finally:
        pool.close()


# --- transient or permanent -------------------------------------------------------


def real_locked_error(tmp_path: Path) -> OperationalError:
    """The error SQLAlchemy raises when another connection holds SQLite's write lock."""
    db = tmp_path / "locked.sqlite"
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("CREATE TABLE t (x)")
    holder.execute("BEGIN EXCLUSIVE")
    engine = create_engine(f"sqlite:///{db}", connect_args={"timeout": 0})
    try:
        with engine.begin() as conn:
            conn.exec_driver_sql("INSERT INTO t VALUES (1)")
    except OperationalError as exc:
        return exc
    finally:
        holder.execute("ROLLBACK")
        holder.close()
        engine.dispose()
    raise AssertionError("the exclusive lock did not block the second writer")


def test_transient_errors_are_told_from_permanent_ones(tmp_path: Path) -> None:
    locked = real_locked_error(tmp_path)
    assert "database is locked" in str(locked) and is_transient(locked)

    # A PostgreSQL server that is not there (a port nobody listens on): connection refused.
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    engine = create_engine(f"postgresql+psycopg://x@127.0.0.1:{port}/x?connect_timeout=5")
    with pytest.raises(OperationalError) as refused:
        engine.connect()
    assert is_transient(refused.value)

    # A stale NFS handle, also when an ingest error was raised from it.
    stale = OSError(errno.ESTALE, "Stale file handle")
    assert is_transient(stale)
    try:
        raise IngestError("cannot read", file="imu.csv") from stale
    except IngestError as wrapped:
        assert is_transient(wrapped)

    # Permanent: a missing file, bad input, a schema problem.
    with pytest.raises(FileNotFoundError) as missing:
        (tmp_path / "nope.csv").open()
    assert not is_transient(missing.value)
    assert not is_transient(IngestError("expected 8 columns, got 7", file="imu.csv", line=3))
    empty = create_engine(f"sqlite:///{tmp_path / 'empty.sqlite'}")
    with pytest.raises(OperationalError) as no_table, empty.connect() as conn:
        conn.exec_driver_sql("SELECT * FROM runs")
    empty.dispose()
    assert not is_transient(no_table.value)


def test_transient_failures_are_retried_and_a_permanent_one_isolated(
    prefect_harness, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Four runs: a locked database once, a share that vanishes once, a locked database
    every time, a missing segment file. The first two are archived on their retry; the
    third fails after all attempts; the fourth is tried once; nothing stops the batch."""
    from pipelines.flows import process_batch, report_progress  # Prefect: when run

    day = tmp_path / "day"
    locked_once, vanishing, locked_always = write_runs(day, [11, 12, 13])
    rng = np.random.default_rng(14)
    sim = six_position_integral_run(random_errors(rng), rng)
    broken = day / "broken"
    write_mpu6000_run(sim.segments, broken, "MPU0014")
    (broken / "MPU0014_y_dn.txt").unlink()
    locked = real_locked_error(tmp_path)

    calls: dict[str, int] = {}
    lock = threading.Lock()
    # An attempt's first touch of its folder is the streamed route's plan (it reads the
    # manifest to decide), so the share vanishes and comes back there.
    real_plan, real_archive = process_module.stream_plan, process_module.archive_run

    def count(folder: Path) -> int:
        with lock:
            calls[folder.name] = calls.get(folder.name, 0) + 1
            return calls[folder.name]

    def stream_plan(source):
        n = count(source.folder)
        if source.folder == vanishing:
            away = vanishing.with_name("away")
            if n == 1:  # the share goes away under the first attempt...
                vanishing.rename(away)
            elif away.exists():  # ...and is back for the retry
                away.rename(vanishing)
        return real_plan(source)

    def archive_run(archive, run, **kwargs):
        if run.serial == "BATCH13" or (run.serial == "BATCH11" and calls["run11"] == 1):
            raise locked
        return real_archive(archive, run, **kwargs)

    monkeypatch.setattr(process_module, "stream_plan", stream_plan)
    monkeypatch.setattr(process_module, "archive_run", archive_run)
    seen: list[tuple[int, int, str]] = []
    with report_progress(lambda done, total, o: seen.append((done, total, o["status"]))):
        outcomes = process_batch([str(day)], str(tmp_path / "archive"), runner="local", workers=2)

    by_source = {Path(o["source"]).name: o for o in outcomes}
    assert by_source["run11"]["status"] == "ok" and calls["run11"] == 2
    assert by_source["run12"]["status"] == "ok" and calls["run12"] == 2
    assert by_source["run13"]["status"] == "failed" and calls["run13"] == RETRIES + 1
    assert f"gave up after {RETRIES + 1} attempts" in by_source["run13"]["error"]
    assert "database is locked" in by_source["run13"]["error"]
    assert by_source["broken"]["status"] == "failed" and calls["broken"] == 1
    assert "MPU0014_y_dn" in by_source["broken"]["error"]
    # the CLI's progress callback saw every run finish, counting up to the total
    assert [d for d, _, _ in seen] == [1, 2, 3, 4] and {t for _, t, _ in seen} == {4}

    arch = resolve_archive(str(tmp_path / "archive"))
    with arch.engine().connect() as conn:
        serials = set(conn.execute(select(schema.Device.serial)).scalars())
        n_runs = conn.execute(select(func.count()).select_from(schema.Run)).scalar_one()
    assert serials == {"BATCH11", "BATCH12"} and n_runs == 2


# --- concurrent batches ---------------------------------------------------------------

BATCH_SCRIPT = """
import json, sys, time
from pathlib import Path
from pipelines.flows import process_batch
if __name__ == "__main__":
    go, out, archive, runner = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], sys.argv[4]
    paths = sys.argv[5:]
    deadline = time.monotonic() + 120
    while not go.exists():  # start line: both batches submit at the same moment
        if time.monotonic() > deadline:
            sys.exit("start signal never came")
        time.sleep(0.05)
    outcomes = process_batch(paths, archive, runner=runner, workers=2)
    out.write_text(json.dumps(outcomes))
"""


def test_overlapping_batches_in_two_processes_archive_each_run_once(
    prefect_harness, archive, tmp_path: Path
) -> None:
    """Two batches, in two processes (one with a process pool, one with threads), submit
    four of their runs at the same time into one archive: every run is archived exactly
    once, the second submission of a run is reported as a duplicate, nothing fails."""
    from prefect.settings import PREFECT_API_URL

    runs = write_runs(tmp_path / "day", [21, 22, 23, 24, 25, 26])
    first, second = runs[:5], runs[1:]
    overlap = {r.name for r in first} & {r.name for r in second}
    assert len(overlap) == 4

    script = tmp_path / "batch.py"
    script.write_text(BATCH_SCRIPT)
    go = tmp_path / "go"
    env = {
        **os.environ,
        "PREFECT_API_URL": PREFECT_API_URL.value(),  # the harness's server, shared by both
        "CALIB_FILESTORE": str(archive.root),
        "PYTHONPATH": str(ROOT),
    }
    target = archive.url if not archive.is_sqlite else str(archive.root)
    procs = []
    for i, (runner, batch) in enumerate((("process", first), ("local", second))):
        args = [str(go), str(tmp_path / f"out{i}.json"), target, runner, *map(str, batch)]
        procs.append(
            subprocess.Popen(
                [sys.executable, str(script), *args],
                env=env,
                cwd=ROOT,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
        )
    go.touch()
    for p in procs:
        _, stderr = p.communicate(timeout=SUBPROCESS_TIMEOUT_S)
        assert p.returncode == 0, stderr[-3000:]

    outcomes = [json.loads((tmp_path / f"out{i}.json").read_text()) for i in range(2)]
    assert [len(o) for o in outcomes] == [5, 5]
    every = outcomes[0] + outcomes[1]
    assert not [o for o in every if o["status"] == "failed"], every
    for name in {r.name for r in runs}:
        statuses = sorted(o["status"] for o in every if Path(o["source"]).name == name)
        assert statuses == (["duplicate", "ok"] if name in overlap else ["ok"]), name
    ids = {o["run_id"] for o in every}
    assert len(ids) == 6 and all(ids)

    with archive.engine().connect() as conn:
        n = {
            t: conn.execute(select(func.count()).select_from(t)).scalar_one()
            for t in (schema.Run, schema.CalibrationRow, schema.Device)
        }
        stored = set(conn.execute(select(schema.Run.run_id)).scalars())
    assert n == {schema.Run: 6, schema.CalibrationRow: 6, schema.Device: 6}
    assert stored == ids
    assert len(list((archive.root / "samples").rglob("*.parquet"))) == 6
    assert not list((archive.root / "samples").rglob(".*")), "temporary files left behind"


# --- the CLI ------------------------------------------------------------------------


def test_cli_progress_goes_to_stderr_and_options_are_checked(prefect_harness, tmp_path: Path):
    """`calib process --json --progress`: stdout is exactly the JSON document, the bar is on
    stderr; inconsistent runner options exit with status 2 and name the option."""

    from prefect.settings import PREFECT_API_URL

    write_runs(tmp_path / "day", [41, 42])
    env = {
        **os.environ,
        "PREFECT_API_URL": PREFECT_API_URL.value(),
        "CALIB_ARCHIVE": str(tmp_path / "archive"),
    }

    def run(*args: str) -> subprocess.CompletedProcess:
        return run_calib("process", *args, env=env, timeout=300)

    done = run(str(tmp_path / "day"), "--json", "--progress", "--workers", "2")
    assert done.returncode == 0, done.stderr[-3000:]
    doc = json.loads(done.stdout)
    assert [r["status"] for r in doc["runs"]] == ["ok", "ok"]
    assert "2/2" in done.stderr  # the bar's final state: 2 of 2 runs

    for args, message in (
        (["--runner", "threads"], "expected one of local, process, dask"),
        (["--runner", "dask", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers"),
        (["--scheduler", "tcp://127.0.0.1:1"], "only used with --runner dask"),
    ):
        bad = run(str(tmp_path / "day"), "--json", *args)
        assert bad.returncode == 2 and message in bad.stderr, (args, bad.stderr[-2000:])
        assert bad.stdout == ""


READ_TASK_RUNS = """
import json
from prefect.client.orchestration import get_client
from prefect.client.schemas.filters import FlowRunFilter, FlowRunFilterId
with get_client(sync_client=True) as client:
    found = []
    for flow_run in client.read_flow_runs():
        tasks = client.read_task_runs(
            flow_run_filter=FlowRunFilter(id=FlowRunFilterId(any_=[flow_run.id]))
        )
        found.append({
            "flow": flow_run.flow_id and client.read_flow(flow_run.flow_id).name,
            "state": flow_run.state_name,
            "tasks": sorted((t.name, t.state_name) for t in tasks),
        })
print(json.dumps(found))
"""


def test_every_task_run_reaches_the_temporary_api_with_batched_recording(tmp_path: Path):
    """On Prefect's temporary API, `calib process` has the server record task runs in
    batches (local_batch_settings). None may be lost or left in an early state: the
    last batch is smaller than the batch size and is written when the server stops
    with the `calib` process. Read back through a new server on the same database."""

    from pipelines.flows import RECORDER_BATCH_SIZE

    folders = write_runs(tmp_path / "day", [81, 82, 83])
    assert len(folders) < RECORDER_BATCH_SIZE  # so only the periodic or final flush writes them
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}  # temporary API
    env["PREFECT_HOME"] = str(tmp_path / "prefect")  # its own Prefect database
    archive = str(tmp_path / "archive")
    done = run_calib(
        *("process", str(tmp_path / "day"), "--archive", archive, "--flow", "--json"),
        "--no-progress",
        env=env,
        timeout=SUBPROCESS_TIMEOUT_S,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert [r["status"] for r in json.loads(done.stdout)["runs"]] == ["ok"] * 3

    read = subprocess.run(
        [sys.executable, "-c", READ_TASK_RUNS],
        capture_output=True,
        text=True,
        env=env,
        timeout=SUBPROCESS_TIMEOUT_S,
    )
    assert read.returncode == 0, read.stderr[-3000:]
    (flow_run,) = json.loads(read.stdout.strip().splitlines()[-1])
    assert flow_run["flow"] == "process-batch" and flow_run["state"] == "Completed"
    assert flow_run["tasks"] == [[f"process {f}", "Completed"] for f in sorted(folders)]


# --- interrupting a batch -----------------------------------------------------------


def _helper_pids(tag: str) -> set[int]:
    """Processes a batch may leave behind: forkservers, their workers, Prefect API servers.

    Only those started under the environment marker CALIB_TEST_TAG=`tag` (children
    inherit it), not those of other test runs on the machine.
    """
    found = set()
    marker = f"CALIB_TEST_TAG={tag}".encode()
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes()
                if marker not in (d / "environ").read_bytes().split(b"\0"):
                    continue
            except OSError:
                continue
            if b"multiprocessing.forkserver" in cmd or b"uvicorn" in cmd:
                found.add(int(d.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def wait_first_run_finished(proc: subprocess.Popen, log: Path) -> None:
    """Wait until Prefect logs the first finished task run into `log`, `proc`'s stderr
    (`calib --verbose`: Prefect logs at warning level otherwise).

    stderr goes to a file, not a pipe: a pipe stays open while any child that inherited
    it lives, so reading it to its end would time a leftover process, not calib's exit
    (the test checks leftovers itself, naming them)."""
    import time

    deadline = time.monotonic() + SUBPROCESS_TIMEOUT_S
    while time.monotonic() < deadline and proc.poll() is None:
        if "Finished in state Completed" in log.read_text(errors="replace"):
            return
        time.sleep(0.1)
    raise AssertionError(f"no run finished: {log.read_text(errors='replace')[-3000:]}")


def test_ctrl_c_stops_a_batch_at_once_and_the_rerun_goes_on(tmp_path: Path) -> None:
    """Ctrl-C (SIGINT) during `calib process --runner process` on Prefect's temporary API:
    exit status 130 within seconds (Prefect alone spent 77-108 s retrying its reports),
    a message saying how far it got, no worker, forkserver or API server left running,
    an archive that verifies, and the same command run again archives the rest."""
    import signal
    import time

    seeds = list(range(60, 76))  # 16 runs: the batch is still going when the first one ends
    write_runs(tmp_path / "day", seeds)
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}  # temporary API
    env["CALIB_TEST_TAG"] = tag = str(uuid.uuid4())
    archive = str(tmp_path / "archive")
    cmd = [CALIB, "--verbose", "process", str(tmp_path / "day"), "--archive", archive]
    cmd.append("--no-progress")
    before = _helper_pids(tag)
    log = tmp_path / "stderr.txt"
    with log.open("w") as stderr:
        proc = subprocess.Popen(
            [*cmd, "--runner", "process", "--workers", "2"],
            stderr=stderr,
            stdout=subprocess.DEVNULL,
            env=env,
        )
    wait_first_run_finished(proc, log)
    proc.send_signal(signal.SIGINT)
    sent = time.monotonic()
    proc.wait(timeout=SUBPROCESS_TIMEOUT_S)
    took = time.monotonic() - sent
    rest = log.read_text(errors="replace")
    assert proc.returncode == 130, rest[-3000:]
    assert took < 15.0, took  # stopping the API server may take a few seconds on a busy machine
    said = " ".join(rest.split())  # the console wraps long lines
    # how far it got: the runs whose outcome the flow had taken in (may be 0 of ? so early)
    assert re.search(rf"interrupted after \d+ of ({len(seeds)}|\?) run\(s\)", said), said
    assert "Run the same command again" in said

    deadline = time.monotonic() + 10.0
    while (
        left := {p for p in _helper_pids(tag) - before if _alive(p)}
    ) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not left, [Path(f"/proc/{p}/cmdline").read_bytes()[:120] for p in left]

    verify = run_calib("verify", "--archive", archive, env=env)
    assert verify.returncode == 0, verify.stdout[-2000:] + verify.stderr[-2000:]
    again = subprocess.run(
        [*cmd, "--json"], capture_output=True, text=True, env=env, timeout=SUBPROCESS_TIMEOUT_S
    )
    assert again.returncode == 0, again.stderr[-3000:]
    statuses = [r["status"] for r in json.loads(again.stdout)["runs"]]
    assert len(statuses) == len(seeds) and set(statuses) <= {"ok", "duplicate"}
    assert 1 <= statuses.count("duplicate") < len(seeds)
