"""`calib trend SERIAL PARAM`'s table and summary carry the display unit
(pipelines.reports.display): values, slope and tolerance converted from SI and named.

The archive of tests/serve_sample.py (real pipeline, real SQLite file): DRIFT-01's
gyroscope bias, archived in rad/s, shown in deg/s.
"""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from pipelines import cli_shared
from pipelines.cli import app
from pipelines.reports.display import shown
from pipelines.trends import trend_report

PARAM = "gyr.bias.x"  # SI rad/s, displayed in deg/s: a missing conversion cannot hide


def _rows(text: str) -> dict[str, str]:
    """The summary's rows (label -> value) of a two-column facts table."""
    out = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip("│ ").split("│")]
        if len(cells) == 2 and cells[0]:
            out[cells[0]] = cells[1]
    return out


def test_trend_values_slope_and_tolerance_carry_the_display_unit(
    serve_sample, monkeypatch: pytest.MonkeyPatch
) -> None:
    arch = serve_sample.archive
    rep = trend_report(arch, "DRIFT-01", PARAM)
    summary = rep["summary"]
    assert summary["unit"] == "rad/s"  # the document stays SI, its unit named
    monkeypatch.setattr(cli_shared.out, "width", 200)  # every row on one line
    argv = ["--wide", "trend", "DRIFT-01", PARAM, "--archive", str(arch.root)]
    done = CliRunner().invoke(app, argv)
    assert done.exit_code == 0, done.output
    rows = _rows(done.stdout.split(f"Trend of {PARAM}", 1)[1])
    slope = shown(PARAM, summary["slope_per_year"], summary["slope_std_per_year"])
    assert slope.unit == "deg/s"
    assert rows["unit"] == "deg/s"
    assert rows["slope per year"] == f"{slope.value} deg/s", rows
    assert rows["slope std per year"] == f"{slope.u} deg/s", rows
    assert rows["tolerance"].endswith(" deg/s"), rows
    table = done.stdout.split(f"Trend of {PARAM}", 1)[0]
    for value, std in zip(rep["table"]["value"], rep["table"]["std"], strict=True):
        assert shown(PARAM, value, std).value in table, (value, table)
    assert "deg/s" in table and "rad/s" not in done.stdout
