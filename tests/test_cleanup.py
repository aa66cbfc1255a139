"""A test run leaves nothing behind however it ends: its private PostgreSQL server is
stopped and its temporary folder removed on SIGTERM (fixtures torn down, tests/conftest.py)
and on SIGKILL (the watchdog, calib_testing/watchdog.py).

The test starts pytest on `test_holds_the_server` (which only runs so driven: it reports its
session folder and its server's process id, then waits), kills that run, and looks.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.postgres, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
HOLD_ENV = "CALIB_TEST_HOLD_SERVER"  # read by test_holds_the_server only
WAIT_S = 60.0


def test_holds_the_server(request: pytest.FixtureRequest) -> None:
    """Driven by the test below: report the session folder and the server, then wait."""
    report = os.environ.get(HOLD_ENV)
    if not report:
        pytest.skip("runs only inside test_a_killed_run_leaves_no_server_and_no_folder")
    request.getfixturevalue("postgres_server")
    folder = Path(tempfile.gettempdir())
    pids = [int(p.read_text().split()[0]) for p in folder.glob("calib-pg-*/data/postmaster.pid")]
    Path(report).write_text(json.dumps({"folder": str(folder), "pids": pids}))
    time.sleep(600)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (ended, not yet reaped by its parent) counts as gone
    stat = Path(f"/proc/{pid}/stat")
    return stat.exists() and stat.read_text().split(")")[-1].split()[0] != "Z"


@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_killed_run_leaves_no_server_and_no_folder(tmp_path: Path, how: signal.Signals) -> None:
    report = tmp_path / "report.json"
    run = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            f"{Path(__file__).name}::test_holds_the_server",
        ],
        cwd=Path(__file__).parent,
        env={**os.environ, HOLD_ENV: str(report)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + WAIT_S
    while not report.exists():
        assert run.poll() is None, "the inner run ended before it held the server"
        assert time.monotonic() < deadline, "the inner run never held the server"
        time.sleep(0.1)
    time.sleep(0.2)  # the report is written whole
    held = json.loads(report.read_text())
    assert held["pids"] and all(_alive(p) for p in held["pids"])
    assert Path(held["folder"]).is_dir()

    run.send_signal(how)
    run.wait(timeout=WAIT_S)
    deadline = time.monotonic() + WAIT_S
    while any(_alive(p) for p in held["pids"]) or Path(held["folder"]).exists():
        assert time.monotonic() < deadline, f"left behind: {held}"
        time.sleep(0.1)
