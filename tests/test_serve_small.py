"""`calib serve`: "serving" only once it accepts connections, HEAD answered like GET
without a body, a huge query value not echoed into the error page.

A real (empty, migrated) SQLite archive; the server runs as a real `calib serve` process
for the first test, in-process (TestClient) for the others.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from storage.db import resolve_archive
from storage.queries import open_readonly

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def archive(tmp_path: Path):
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    return arch


@pytest.fixture
def client(archive):
    from pipelines.web.app import create_app

    ro = open_readonly(archive)
    with TestClient(create_app(ro)) as c:
        yield c
    ro.dispose()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.e2e  # a real server in a process of its own
def test_serving_is_said_once_connections_are_accepted(archive) -> None:
    port = _free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DO_NOT_TRACK": "1"}
    code = "from pipelines.cli import app; app()"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "serve", "--archive", str(archive.root), "--port", str(port)],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        line = proc.stderr.readline()  # blocks until the server says something
        assert line.startswith("serving "), line
        # The very next connection is accepted: no retry, no wait.
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/runs", timeout=30) as r:
            assert r.status == 200
    finally:
        proc.terminate()
        proc.wait(timeout=60)


def test_head_is_answered_like_get_without_a_body(client) -> None:
    got = client.get("/runs")
    head = client.head("/runs")
    assert head.status_code == got.status_code == 200
    assert head.content == b""
    assert head.headers["content-type"] == got.headers["content-type"]
    assert client.head("/runs/Rdeadbeef0000").status_code == 404
    assert client.post("/runs").status_code == 405


def test_a_huge_query_value_is_not_echoed(client) -> None:
    value = "x" * 60_000  # httpx refuses a longer query
    r = client.get("/runs", params={"page": value})
    assert r.status_code == 400
    assert value not in r.text and len(r.text) < 20_000
    assert re.search(r"\(600\d\d characters\)", r.text)  # the value, quoted
    r = client.get("/runs", params={value: "1"})  # an unknown parameter's name
    assert r.status_code == 400 and len(r.text) < 20_000
