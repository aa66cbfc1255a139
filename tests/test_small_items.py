"""`make demo` (what it installs, that it says what it does and ends without an ignored
error), `calib thermal show` on a fitted campaign, the README's reprocess example; trends
that compare like with like (a thermal campaign is not a drift) and chart labels that
never overprint."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from pipelines import cli_shared
from pipelines.cli import app
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage.db import resolve_archive
from storage.queries import open_readonly

ROOT = Path(__file__).resolve().parent.parent
CAMPAIGN = ROOT / "data_samples" / "thermal_IMU-T-0007"


def test_make_demo_installs_only_what_it_runs_and_says_what_it_does(tmp_path: Path) -> None:
    make = shutil.which("make")
    if make is None:
        pytest.skip("make is not installed")
    done = subprocess.run(
        [make, "-n", "-B", "demo", f"VENV={tmp_path / 'venv'}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
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


# --- trends compare like with like -----------------------------------------------------


def test_pooled_runs_compares_one_condition() -> None:
    from pipelines.trends import pooled_runs

    campaign = pooled_runs([0.0, 20.0, 40.0, 60.0])
    assert len(campaign.conditions) == 4 and len(campaign.indices) == 1
    assert "not fitted as a drift in time" in campaign.note
    quarterly = pooled_runs([20.0, 21.0, 19.5, 20.4])
    assert quarterly.indices == [0, 1, 2, 3] and quarterly.note == ""
    assert quarterly.said(4) == "4 of 4 runs, all at 20 deg C"
    mixed = pooled_runs([20.0, 60.0, 20.2, 19.8, 0.0, None])
    assert mixed.indices == [0, 2, 3] and mixed.condition == "20 deg C"
    assert "temperature not recorded" in mixed.conditions
    assert mixed.said(6) == "3 of 6 runs, at 20 deg C"


def test_a_thermal_campaign_is_not_read_as_a_drift(campaign) -> None:
    """The unit page and `calib trend` of the four-temperature campaign: no drift per year,
    no date of leaving the band; they say the runs are at four conditions."""
    from pipelines.web.app import create_app

    root = str(campaign.root)
    code, text = _invoke("trend", "IMU-T-0007", "acc.bias.x", "--archive", root)
    assert code == 2 and "4 conditions" in text and "not fitted as a drift" in text, text
    ro = open_readonly(campaign)
    page = TestClient(create_app(ro)).get("/units/IMU-T-0007?parameter=acc.bias.x").text
    ro.dispose()
    plain = " ".join(re.sub(r"<[^>]+>", " ", page).split())
    assert "No trend: the runs are at 4 conditions (20 deg C, 0 deg C, 40 deg C, 60 deg C)" in plain
    assert "trend, 95 % band" not in plain  # no fitted line in the chart
    row = re.search(r'<tr[^>]*>\s*<td class="mono"><a [^>]*>acc\.bias\.x</a>.*?</tr>', page, re.S)
    assert row and "by temperature" in row.group()
    assert not re.search(r"\d{4}-\d\d-\d\d", row.group())  # no "leaves band" date


def test_chart_labels_never_overprint() -> None:
    """Two tolerance lines a few pixels apart and a long title: every text line of the
    chart's top and its limit labels keep LABEL_GAP between baselines."""
    from datetime import UTC, datetime

    from pipelines.web import svg

    points = [
        svg.TrendPoint(datetime(2026, m, 1, tzinfo=UTC), 0.01 * m, 0.001, f"p{m}", "#", False)
        for m in (1, 4, 7, 10)
    ]
    chart = str(
        svg.trend_chart(
            points,
            title="acc.bias.x of A-LONG-SERIAL-NAME (4 of 4 runs, all at 20 deg C) " + "x" * 40,
            unit="m/s^2",
            limits=(0.049, 0.0505),
        )
    )
    ys = sorted(
        float(y)
        for y in re.findall(
            r'<text x="[^"]+" y="([^"]+)"[^>]*class="'
            r'(?:title|tick limit-text)"',
            chart,
        )
    )
    assert len(ys) >= 3, chart
    assert all(b - a >= svg.LABEL_GAP for a, b in zip(ys, ys[1:], strict=False)), ys
    far = str(svg.trend_chart(points, title="t" * 120, unit="m/s^2", limits=(-50.0, 50.0)))
    assert re.search(r'y="29\.0" text-anchor="end" class="tick limit-text"', far), far


def test_thermal_show_speaks_the_display_unit(campaign) -> None:
    """`calib thermal show`: each curve's coefficients in the unit `calib show` uses for
    the parameter (deg/s for a gyro bias), SI in --json."""
    from pipelines.reports.display import quantity

    root = str(campaign.root)
    code, text = _invoke("thermal", "show", "IMU-T-0007", "--archive", root)
    if code == 2:  # none fitted yet in this module's campaign
        assert _invoke("thermal", "fit", "IMU-T-0007", "--archive", root)[0] == 0
        code, text = _invoke("thermal", "show", "IMU-T-0007", "--archive", root)
    assert code == 0, text
    code, raw = _invoke("thermal", "show", "IMU-T-0007", "--archive", root, "--json")
    curve = json.loads(raw)["document"]["curves"]["gyr.bias.x"]
    assert curve["unit"] == "rad/s"
    flat = " ".join(text.split())
    assert quantity("gyr.bias.x", curve["coef"][0], 4) in flat and "(deg/s)" in flat
    assert "rad/s" not in text
