"""`make demo` (what it installs, that it says what it does and ends without an ignored
error), one environment for every make target, `calib thermal show` on a fitted campaign
(by run id), `calib due`, command help folded by sentence, the certificate's units and
deviations, the README's reprocess example; trends
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


def _make_n(target: str, venv: Path) -> list[str]:
    """The commands `make -n TARGET` would run with the environment `venv`."""
    make = shutil.which("make")
    if make is None:
        pytest.skip("make is not installed")
    done = subprocess.run(
        [make, "-n", target, f"VENV={venv}"], cwd=ROOT, capture_output=True, text=True, check=True
    )
    return done.stdout.splitlines()


def _installs(lines: list[str]) -> list[str]:
    """What each `pip install` of the commands installs (the -e argument)."""
    return [
        line.split("pip install -q -e ", 1)[1].split()[0]
        for line in lines
        if "pip install -q -e " in line
    ]


def test_make_demo_installs_only_what_it_runs_and_says_what_it_does(tmp_path: Path) -> None:
    assert _installs(_make_n("demo", tmp_path / "venv")) == ['"."']
    script = ROOT.joinpath("scripts", "demo.sh").read_text()
    steps = re.findall(r"^step (\d)/5 ", script, re.M)
    assert steps == ["1", "2", "3", "4", "5"], steps
    assert "took $(( SECONDS - started )) s" in script  # and how long it took
    # A failing step is said, not ignored ("Error 1 (ignored)"), nor fatal where expected.
    recipe = ROOT.joinpath("Makefile").read_text().split("\ndemo:", 1)[1].split("\n\n", 1)[0]
    assert not re.search(r"^\t-", recipe, re.M), recipe
    assert '"$BIN/calib" repeatability IMU-R-0003 \\\n        || echo' in script


def test_every_make_target_shares_one_environment(tmp_path: Path) -> None:
    """The extras each target needs are installed once and recorded: after `make demo`,
    `make test-fast` installs only the test extras; after those, `make demo` nothing."""
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "bin" / "python").touch()
    assert _installs(_make_n("test-fast", venv)) == ['".[test,dask]"']
    (venv / ".installed-base").touch()  # as `make demo` leaves it
    assert _installs(_make_n("demo", venv)) == []
    assert _installs(_make_n("test-fast", venv)) == ['".[test,dask]"']
    (venv / ".installed-test-dask").touch()  # as `make test-fast` leaves it
    for target in ("demo", "test-fast", "test", "bench"):
        assert _installs(_make_n(target, venv)) == [], target


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory):
    arch = resolve_archive(str(tmp_path_factory.mktemp("thermal") / "archive"))
    arch.upgrade()
    for source in discover_runs([CAMPAIGN]):
        assert process_run(source, arch)["status"] == "ok"
    return arch


def _campaign_runs(arch) -> list[str]:
    from storage.queries.unit_history import history_rows

    return [r["run_id"] for r in history_rows(arch, "IMU-T-0007")]


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
    shown = set(re.findall(r"R[0-9a-f]{12}", text))  # the runs fitted, by run id
    assert shown == set(_campaign_runs(campaign)) and len(shown) == 4, text
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


# --- small things a new user met ---------------------------------------------------------


def test_calib_due_is_a_command_and_query_lists_it(campaign) -> None:
    code, text = _invoke("due", "--archive", str(campaign.root))
    assert code == 0 and "Units due" in text and "IMU-T-0007" in text, text
    code, text = _invoke("query", "--help")
    assert code == 0 and re.search(r"^\W*due\b", text, re.M), text


def test_command_help_is_folded_by_sentence_not_by_source_line() -> None:
    """The docstring's paragraphs reach the terminal as paragraphs: the terminal folds
    them, not the source's line breaks (which left half-empty lines at 80 columns)."""
    assert cli_shared.reflowed("One two\nthree.\n\nFour\nfive.\n\n- a\n- b") == [
        "One two three.",
        "Four five.",
        "- a\n- b",
    ]
    code, text = _invoke("report", "--help")
    assert code == 0
    assert "(`calib verify` rehashes them)" in " ".join(text.split())
    lines = [line.strip(" │") for line in text.splitlines()]
    body = lines[lines.index(next(x for x in lines if x.startswith("The files are"))) :][:5]
    assert all(len(x) > 60 for x in body[:3]), body  # full lines, not one word each


def test_certificate_units_and_deviations(tmp_path) -> None:
    """The environment's temperature drift with its unit; a setting at the method's own
    value is no deviation from it, a changed one is."""
    from pipelines.reports.iso17025 import deviations
    from pipelines.reports.run_reports import certificate_of

    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    (source,) = discover_runs([ROOT / "data_samples" / "csv_IMU-2026-0042"])
    run_id = process_run(source, arch)["run_id"]
    _, cert = certificate_of(arch, run_id)
    pairs = {k: v for s in cert.sections for k, v in s.pairs}
    assert pairs["Temperature drift"] == "0.2 deg C/h" and pairs["Temperature"] == "20.4 deg C"
    assert pairs["Deviations from the method"] == "none"  # gyro_range_dps=2000.0, the default
    assert deviations("six_position_integral", {"gyro_range_dps": 500.0}) == "gyro_range_dps=500.0"
    assert deviations("six_position_integral", {"gyro_range_dps": 2000.0}) == "none"
