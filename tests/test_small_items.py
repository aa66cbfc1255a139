"""`make demo` (what it installs, that it says what it does and ends without an ignored
error), `calib thermal show` on a fitted campaign, the README's reprocess example."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipelines import cli_shared
from pipelines.cli import app
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage.db import resolve_archive

ROOT = Path(__file__).resolve().parent.parent
CAMPAIGN = ROOT / "data_samples" / "thermal_IMU-T-0007"


def test_make_demo_installs_only_what_it_runs_and_says_what_it_does(tmp_path: Path) -> None:
    make = shutil.which("make")
    if make is None:
        pytest.skip("make is not installed")
    done = subprocess.run([make, "-n", "-B", "demo", f"VENV={tmp_path / 'venv'}"], cwd=ROOT,
                          capture_output=True, text=True, check=True)  # fmt: skip
    lines = done.stdout.splitlines()
    installs = [line for line in lines if "pip install" in line and "--upgrade pip" not in line]
    assert installs and all(line.rstrip().endswith("-e .") for line in installs), installs
    what = [line.split("pip install", 1)[1] for line in installs]
    assert not any("test" in w or "dask" in w for w in what), what
    steps = [line for line in lines if line.startswith('echo "== ')]
    assert len(steps) >= 5, steps
    recipe = ROOT.joinpath("Makefile").read_text().split("\ndemo:", 1)[1].split("\n\n", 1)[0]
    # A leading "-" makes make print "Error 1 (ignored)"; a failing step is said instead.
    assert not re.search(r"^\t-", recipe, re.M), recipe
    assert "calib repeatability IMU-R-0003 ||" in recipe


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory):
    arch = resolve_archive(str(tmp_path_factory.mktemp("thermal") / "archive"))
    arch.upgrade()
    for source in discover_runs([CAMPAIGN]):
        assert process_run(source, arch)["status"] == "ok"
    return arch


def _invoke(*args: str) -> tuple[int, str]:
    cli_shared.out.width = 80
    done = CliRunner().invoke(app, list(args))
    return done.exit_code, done.output


def test_thermal_show(campaign) -> None:
    root = str(campaign.root)
    code, text = _invoke("thermal", "show", "IMU-T-0007", "--archive", root)
    assert code == 2 and "calib thermal fit IMU-T-0007" in text  # none fitted yet
    code, text = _invoke("thermal", "fit", "IMU-T-0007", "--archive", root)
    assert code == 0, text
    code, text = _invoke("thermal", "show", "IMU-T-0007", "--archive", root)
    assert code == 0, text
    assert "0 .. 60 deg C" in text and "acc.bias.x" in text and "gyr.scale.z" in text
    assert "None" not in text and "nan" not in text
    code, text = _invoke("thermal", "show", "IMU-T-0007", "--archive", root, "--json")
    doc = json.loads(text)
    assert (doc["t_min"], doc["t_max"]) == (0.0, 60.0)
    assert "acc.bias.x" in doc["document"]["curves"]


def test_readme_reprocess_example_says_when_it_revises() -> None:
    """`calib reprocess --all` makes new revisions only where this version of calib has
    not made one with the same settings: the README says so beside the example."""
    readme = ROOT.joinpath("README.md").read_text()
    line = next(line for line in readme.splitlines() if "calib reprocess --all" in line)
    assert "update" in line
    assert "already made is skipped" in readme
