"""Nothing human-facing shows None, nan, a Python repr or raw JSON.

The samples of data_samples/ are processed into a real SQLite archive (the thermal
campaign fitted); every read-only command's table output (80 columns) and every page
of `calib serve` reachable from its front page (crawled, downloads aside) are searched.
"""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import urljoin, urlsplit

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from pipelines import cli_shared
from pipelines.cli import app
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage.db import Archive, resolve_archive
from storage.queries import open_readonly

SAMPLES = Path(__file__).resolve().parent.parent / "data_samples"
# What a person must never read: Python's None / nan, a repr, a JSON object.
RAW = re.compile(
    r"\bNone\b|\bnan\b|\bNaN\b|\bNaT\b|PosixPath\(|Timestamp\(|datetime\.|"
    r"\{'|\{\"|\['|\bTrue\b|\bFalse\b"
)
MAX_PAGES = 250
DOWNLOADS = (".pdf", ".html", ".txt", ".json", ".csv", ".mat", ".px4", ".ardupilot", ".xml")


@pytest.fixture(scope="module")
def sample_archive(tmp_path_factory: pytest.TempPathFactory) -> Archive:
    arch = resolve_archive(str(tmp_path_factory.mktemp("raw") / "archive"))
    arch.upgrade()
    for source in discover_runs([SAMPLES]):
        assert process_run(source, arch)["status"] == "ok"
    cli_shared.out.width = 80
    done = CliRunner().invoke(app, ["thermal", "fit", "IMU-T-0007", "--archive", str(arch.root)])
    assert done.exit_code == 0, done.output
    return arch


def _raw(text: str) -> list[str]:
    return sorted({text[max(0, m.start() - 40) : m.end() + 40] for m in RAW.finditer(text)})


def _commands(arch: Archive) -> list[list[str]]:
    a = ["--archive", str(arch.root)]
    runs = browse_runs(arch)
    assert len(runs) == 10, runs
    cmds = [["history", s, *a] for s in ("IMU-R-0003", "MPU0001", "IMU-T-0007")]
    cmds += [["show", r, *a] for r in runs]
    cmds += [
        ["query", "lineage", runs[0], "acc.bias.x", *a],
        ["query", "latest", "MPU0001", *a],
        ["query", "units", *a],
        ["query", "lapsed", "CUBE-7", *a],
        ["query", "history", "IMU-R-0003", "acc.bias.z", *a],
        ["query", "fleet", "MPU-6000", "acc.bias.z", *a],
        ["fleet", "MPU-6000", "acc.bias.z", *a],
        ["trend", "IMU-R-0003", "acc.bias.z", *a],
        ["repeatability", "IMU-R-0003", *a],
        ["thermal", "show", "IMU-T-0007", *a],
        ["query", "lineage", runs[-1], "gyr.bias.z", *a],
        ["query", "due", *a],
        ["procedures"],
        ["procedures", "six_position"],
        # a dry look-back: the one run of the sample archive on DAQ-12 in that week
        ["impact", "DAQ-12", "--from", "2026-11-01", "--to", "2026-11-07"]
        + ["--error", "clock_error_ppm=50", *a],
        ["audit", *a],
        ["audit", "--format", "table", *a],
        ["verify", *a],
    ]
    return cmds


def browse_runs(arch: Archive) -> list[str]:
    """Every archived run id of the samples."""
    from storage import queries

    serials = ("IMU-R-0003", "MPU0001", "IMU-T-0007", "IMU-2026-0042")
    return sorted(r["run_id"] for s in serials for r in queries.history_rows(arch, s))


@pytest.mark.slow  # every sample processed, every command run; fast: test_cli_width's commands
def test_no_command_shows_raw_values(sample_archive: Archive) -> None:
    cli_shared.out.width = cli_shared.err.width = 80
    found = {}
    for args in _commands(sample_archive):
        done = CliRunner().invoke(app, args)
        assert done.exit_code in (0, 1), f"calib {' '.join(args)}: {done.output}"
        if bad := _raw(done.stdout + done.stderr):
            found[" ".join(args[:3])] = bad
    assert not found, found


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.links: list[str] = []
        self.text: list[str] = []
        self._skip = 0

    def handle_starttag(self, tag: str, attrs: list) -> None:
        self._skip += tag in ("script", "style")
        self.links += [v for k, v in attrs if k == "href" and v]

    def handle_endtag(self, tag: str) -> None:
        self._skip -= tag in ("script", "style")

    def handle_data(self, data: str) -> None:
        if not self._skip:
            self.text.append(data)


@pytest.mark.slow  # crawls every page of the sample archive
def test_no_page_shows_raw_values(sample_archive: Archive) -> None:
    ro = open_readonly(sample_archive)
    found: dict[str, list[str]] = {}
    seen: set[str] = set()
    todo = ["/", "/runs", "/models", "/equipment", "/due", "/units/IMU-T-0007", "/units/IMU-R-0003"]
    with TestClient(create_app_for(ro)) as client:
        while todo and len(seen) < MAX_PAGES:
            url = todo.pop(0)
            if url in seen:
                continue
            seen.add(url)
            r = client.get(url)
            assert r.status_code == 200, (url, r.status_code)
            if not r.headers["content-type"].startswith("text/html"):
                continue
            page = _Page()
            page.feed(r.text)
            if bad := _raw(" ".join(page.text)):
                found[url] = bad
            for href in page.links:
                nxt = urljoin(url, href)
                parts = urlsplit(nxt)
                if parts.netloc or parts.path.endswith(DOWNLOADS) or "/raw/" in parts.path:
                    continue
                if "page=" in parts.query or "sort=" in parts.query:
                    continue  # the list's other orders and pages: the same rows again
                todo.append(parts.path + (f"?{parts.query}" if parts.query else ""))
    ro.dispose()
    assert len(seen) > 20, seen
    assert not found, found


def create_app_for(ro: Archive):  # noqa: ANN201 - FastAPI
    from pipelines.web.app import create_app

    return create_app(ro)
