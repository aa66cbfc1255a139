"""`calib process` of a few runs in this process, without Prefect: the same
outcomes and archive as the Prefect flow, and Prefect not even imported."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from test_pipeline import _row_counts, lab_day  # noqa: F401 - the fixture
from typer.testing import CliRunner

from pipelines.cli import app
from pipelines.direct import discover, prefect_api_configured, process_in_process
from storage.db import resolve_archive

ROOT = Path(__file__).resolve().parents[1]


def _comparable(outcomes: list[dict]) -> list[dict]:
    """What must not depend on the path taken (the protocol path names the archive)."""
    keys = ("run_id", "serial", "status", "verdict", "parameters", "checks", "error")
    return sorted(({k: o[k] for k in keys} for o in outcomes), key=lambda o: o["run_id"])


def test_in_process_and_flow_give_the_same_outcomes_and_archive(
    prefect_harness,
    lab_day,  # noqa: F811 - the fixture
    tmp_path,
) -> None:
    from pipelines.flows import process_batch  # Prefect: imported when run, not when collected

    sources, failed = discover([str(lab_day["day"])])
    direct = failed + process_in_process(sources, str(tmp_path / "a"))
    flow = process_batch([str(lab_day["day"])], str(tmp_path / "b"))
    assert len(direct) == len(flow) == 4
    assert _comparable(direct) == _comparable(flow)
    assert _row_counts(resolve_archive(str(tmp_path / "a"))) == _row_counts(
        resolve_archive(str(tmp_path / "b"))
    )


@pytest.mark.e2e
def test_calib_process_of_one_run_never_imports_prefect(tmp_path: Path) -> None:
    run = str(ROOT / "data_samples" / "mpu6000_MPU0001")
    code = (
        "import sys, json\n"
        "from typer.testing import CliRunner\n"
        "from pipelines.cli import app\n"
        f"r = CliRunner().invoke(app, ['process', {run!r},"
        f" '--archive', {str(tmp_path / 'a')!r}, '--json'])\n"
        "print(json.dumps({'code': r.exit_code, 'prefect': 'prefect' in sys.modules,"
        " 'doc': json.loads(r.stdout)}))\n"
    )
    env_free = {"PREFECT_API_URL": "", "PREFECT_HOME": str(tmp_path / "prefect-home")}
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=600,
        env={**__import__("os").environ, **env_free},
        cwd=ROOT,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["code"] == 0 and got["doc"]["runs"][0]["status"] == "ok"
    assert got["prefect"] is False


def test_flow_option_takes_the_prefect_flow(
    prefect_harness,
    lab_day,  # noqa: F811 - the fixture
    tmp_path,
) -> None:
    # --flow: the batch runs as a Prefect flow, whose run the API then lists.
    from prefect import get_client

    res = CliRunner().invoke(
        app, ["process", str(lab_day["mpu"]), "--archive", str(tmp_path / "a"), "--json", "--flow"]
    )
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["runs"][0]["status"] == "ok"
    with get_client(sync_client=True) as client:
        runs = client.read_flow_runs()
    assert any(r.name and r.parameters.get("paths") == [str(lab_day["mpu"])] for r in runs)


def test_prefect_api_configured_reads_the_environment_and_the_active_profile(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    monkeypatch.delenv("PREFECT_PROFILE", raising=False)
    monkeypatch.setenv("PREFECT_HOME", str(tmp_path))
    assert not prefect_api_configured()  # no profiles file
    (tmp_path / "profiles.toml").write_text(
        'active = "lab"\n[profiles.lab]\nPREFECT_API_URL = "http://127.0.0.1:4200/api"\n'
        '[profiles.local]\nPREFECT_LOGGING_LEVEL = "INFO"\n'
    )
    assert prefect_api_configured()
    monkeypatch.setenv("PREFECT_PROFILE", "local")
    assert not prefect_api_configured()
    monkeypatch.setenv("PREFECT_API_URL", "http://127.0.0.1:4200/api")
    assert prefect_api_configured()
    (tmp_path / "profiles.toml").write_text("not [toml")
    monkeypatch.delenv("PREFECT_API_URL")
    assert not prefect_api_configured()  # an unreadable file is no configured API


def _open_archive_count() -> int:
    from pipelines import run_task

    return len(run_task._open_archives)


def test_a_batch_worker_keeps_one_engine_per_archive_file(lab_day, tmp_path) -> None:  # noqa: F811
    """Runs of a batch in one process share the archive's engine (batch_archive); a database
    file deleted and made again is reached afresh, not through the old connection (which
    would still see the deleted file's rows and call the run a duplicate); a forked child
    starts with no open archive."""
    import multiprocessing
    import shutil

    from pipelines.ingest import discover_runs
    from pipelines.run_task import batch_archive, process_run_for_batch

    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    csv, mpu = discover_runs([lab_day["csv"]])[0], discover_runs([lab_day["mpu"]])[0]
    first = process_run_for_batch(csv, arch.url, str(arch.root))
    shared = batch_archive(arch.url, str(arch.root))
    engine = shared.engine()
    second = process_run_for_batch(mpu, arch.url, str(arch.root))
    assert [first["status"], second["status"]] == ["ok", "ok"]
    assert batch_archive(arch.url, str(arch.root)) is shared and shared.engine() is engine

    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply(_open_archive_count) == 0
    assert _open_archive_count() >= 1

    shutil.rmtree(arch.root)
    arch.dispose()
    arch.upgrade()  # a new, empty archive at the same place
    again = process_run_for_batch(csv, arch.url, str(arch.root))
    assert again["status"] == "ok", again
    assert batch_archive(arch.url, str(arch.root)) is not shared
