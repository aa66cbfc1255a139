"""The batch flow on a real Dask cluster with a real PostgreSQL archive.

A Dask scheduler and two single-threaded workers run as separate processes on
127.0.0.1 (the `dask` command lines a lab would use); the file store is a
folder every worker sees. The flow's tasks must run on those workers, report
to the same Prefect API, and archive into PostgreSQL.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import func, select

from calib_core.simulate import random_errors, six_position_integral_run
from calib_testing.run_writers import six_position_manifest, write_csv_run, write_mpu6000_run
from storage import schema
from storage.db import Archive

ROOT = Path(__file__).resolve().parents[1]
START_TIMEOUT_S = 120  # scheduler file + both workers registered, on a busy 2-core machine
STOP_TIMEOUT_S = 20

MANIFEST = six_position_manifest("DASK", started="2026-11-21T08:00:00+00:00", temperature_c=21.0)


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=STOP_TIMEOUT_S)


@pytest.fixture
def dask_cluster(prefect_harness, tmp_path: Path) -> Iterator[str]:
    """A scheduler and two worker processes on loopback; yields the scheduler address."""
    from distributed import Client
    from prefect.settings import PREFECT_API_URL

    dask = shutil.which("dask", path=str(Path(sys.executable).parent))
    assert dask, "the `dask` command (distributed) is not installed: pip install -e .[dask]"
    env = {
        **os.environ,
        # Workers report their task runs to the same Prefect API as the flow.
        "PREFECT_API_URL": PREFECT_API_URL.value(),
        "PYTHONPATH": str(ROOT),
        "DO_NOT_TRACK": "1",
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    }
    sched_file = tmp_path / "scheduler.json"
    logs = tmp_path / "dask-logs"
    logs.mkdir()
    procs: list[subprocess.Popen] = []

    def start(name: str, *args: str) -> None:
        log = (logs / f"{name}.log").open("w")
        procs.append(
            subprocess.Popen([dask, *args], env=env, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        )

    try:
        start(
            "scheduler",
            "scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--dashboard-address",
            "127.0.0.1:0",
            "--scheduler-file",
            str(sched_file),
        )
        deadline = time.monotonic() + START_TIMEOUT_S
        while not sched_file.exists():
            if procs[0].poll() is not None or time.monotonic() > deadline:
                pytest.fail(
                    f"Dask scheduler did not start:\n{(logs / 'scheduler.log').read_text()}"
                )
            time.sleep(0.2)
        for i in range(2):
            start(
                f"worker{i}",
                "worker",
                "--scheduler-file",
                str(sched_file),
                "--host",
                "127.0.0.1",
                "--nthreads",
                "1",
                "--dashboard-address",
                "127.0.0.1:0",
                "--local-directory",
                str(tmp_path / f"worker{i}"),
                "--name",
                f"worker{i}",
            )
        with Client(scheduler_file=str(sched_file), timeout=START_TIMEOUT_S) as client:
            try:
                client.wait_for_workers(2, timeout=START_TIMEOUT_S)
            except TimeoutError:
                text = "\n".join(p.read_text()[-2000:] for p in sorted(logs.iterdir()))
                pytest.fail(f"Dask workers did not register:\n{text}")
            yield client.scheduler.address
    finally:
        _stop(procs[::-1])  # workers first, then the scheduler


def test_batch_on_a_dask_cluster_into_postgresql(
    dask_cluster: str, postgres_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from distributed import Client

    from pipelines.flows import process_batch  # Prefect: imported when run, not when collected

    day = tmp_path / "day"
    truths = {}
    for seed in (31, 32, 33, 34):
        rng = np.random.default_rng(seed)
        sim = six_position_integral_run(random_errors(rng), rng)
        serial = f"DASK{seed}"
        manifest = {**MANIFEST, "unit": {**MANIFEST["unit"], "serial": serial}}
        write_csv_run(sim.segments, day / f"run{seed}", manifest)
        truths[serial] = sim.truth_dict()["parameters"]
    rng = np.random.default_rng(35)
    sim = six_position_integral_run(random_errors(rng), rng)
    write_mpu6000_run(sim.segments, day / "broken", "MPU0035")
    (day / "broken" / "MPU0035_z_cw.txt").unlink()

    store = tmp_path / "shared-store"  # the path every worker sees
    monkeypatch.setenv("CALIB_FILESTORE", str(store))
    outcomes = process_batch([str(day)], postgres_url, runner="dask", scheduler=dask_cluster)

    by_serial = {o["serial"] or Path(o["source"]).name: o for o in outcomes}
    assert set(by_serial) == {*truths, "MPU0035"}
    assert by_serial["MPU0035"]["status"] == "failed"
    assert "MPU0035_z_cw" in by_serial["MPU0035"]["error"]
    for serial, truth in truths.items():
        o = by_serial[serial]
        assert o["status"] == "ok", o["error"]
        # solved on the workers: within 4 reported standard uncertainties of the simulator's truth
        for name in ("acc.bias.x", "acc.scale.z", "gyr.scale.y", "gyr.bias.z"):
            p = o["parameters"][name]
            assert abs(p["value"] - truth[name]) <= 4 * p["std"], (serial, name)
        assert Path(o["protocol"]).is_file() and Path(o["protocol"]).is_relative_to(store)

    # The five tasks ran on the cluster's two worker processes, not in this one.
    with Client(dask_cluster, timeout=30) as client:
        ran = client.run(lambda dask_worker: dask_worker.state.executed_count)
    assert len(ran) == 2 and sum(ran.values()) == 5, ran

    archive = Archive(postgres_url, store)
    try:
        with archive.engine().connect() as conn:
            serials = set(conn.execute(select(schema.Device.serial)).scalars())
            n_runs = conn.execute(select(func.count()).select_from(schema.Run)).scalar_one()
            samples = list(conn.execute(select(schema.Run.samples_path)).scalars())
        assert serials == set(truths) and n_runs == 4
        assert all((store / s).is_file() for s in samples)
        # the same batch again: every good run a duplicate, nothing new archived
        again = process_batch([str(day)], postgres_url, runner="dask", scheduler=dask_cluster)
        assert sorted(o["status"] for o in again) == ["duplicate"] * 4 + ["failed"]
        with archive.engine().connect() as conn:
            assert conn.execute(select(func.count()).select_from(schema.Run)).scalar_one() == 4
    finally:
        archive.dispose()


def test_dask_batch_in_any_order_gives_the_verdicts_of_time_order(
    dask_cluster: str, postgres_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The sample unit's four runs, reversed, on two workers into PostgreSQL: each run
    judged against the runs made before it, as in-process in time order
    (tests/test_verdict_order.py)."""
    from test_verdict_order import IN_TIME_ORDER, check_time_order, judgements, run_folders

    from pipelines.flows import process_batch  # Prefect: imported when run, not when collected

    store = tmp_path / "shared-store"
    monkeypatch.setenv("CALIB_FILESTORE", str(store))
    order = list(IN_TIME_ORDER)[::-1]
    outcomes = process_batch(
        run_folders(order), postgres_url, runner="dask", scheduler=dask_cluster
    )
    assert [o["status"] for o in outcomes] == ["ok"] * 4, outcomes
    archive = Archive(postgres_url, store)
    try:
        seen = judgements(archive)
    finally:
        archive.dispose()
    check_time_order(seen, "dask, reversed")
    assert [o["verdict"] for o in outcomes] == [IN_TIME_ORDER[d] for d in order]

    # Every revision (the runs judged again by run time included) solved again on the
    # cluster from its raw bytes, against what it was judged against: identical.
    from pipelines.flows import recompute_batch

    run_ids = [o["run_id"] for o in outcomes]
    again = recompute_batch(run_ids, postgres_url, runner="dask", scheduler=dask_cluster)
    assert [o["run_id"] for o in again] == run_ids
    revisions = [r for o in again for r in o["revisions"]]
    assert len(revisions) > len(run_ids)  # judged again: more revisions than runs
    assert all(r["status"] == "identical" for r in revisions), again
