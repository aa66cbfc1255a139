"""Recalibration intervals from measured drift (calib_core.interval, pipelines/recall.py,
`calib query due`; docs/interval.md): simulated drifting units get intervals whose
in-tolerance rate at the interval's end matches the reliability target within its sampling
error."""

from __future__ import annotations

import json
import math
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from typer.testing import CliRunner

from calib_core.calibration import Parameter
from calib_core.drift import fit_trend_shared
from calib_core.interval import (
    Prediction,
    fleet_drift,
    in_tolerance_probability,
    interval,
    predict_line,
)
from calib_core.tolerances import ToleranceProfile
from calib_testing.archives import new_archive, parameter_run
from pipelines.cli import app
from storage.archive import archive_run

LIMIT = 0.03  # gyr.scale.x of the mpu6000 profile
MEAN_RATE, SPREAD_RATE = 2e-5, 1e-5  # per day: the fleet's drift rates
U_MEAS = 2e-4  # each calibration's standard uncertainty
CAL_DAYS = np.array([0.0, 365.0, 730.0])


def _fleet(rng: np.random.Generator, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True start values, true rates and measured values (k, 3) of k units."""
    x0 = rng.normal(0.005, 0.002, k)
    rate = rng.normal(MEAN_RATE, SPREAD_RATE, k)
    measured = x0[:, None] + rate[:, None] * CAL_DAYS + rng.normal(0.0, U_MEAS, (k, 3))
    return x0, rate, measured


def _sampling_band(reliability: float, n: int) -> float:
    return 3.0 * math.sqrt(reliability * (1.0 - reliability) / n)


@pytest.mark.parametrize("reliability", [0.9, 0.95])
def test_in_tolerance_rate_at_the_interval_end_matches_the_target(reliability):
    """1,000 units, three calibrations each: the share of units in tolerance at the end of
    their own interval (those the interval is not capped for or zero) is the target."""
    rng = np.random.default_rng(24)
    x0, rate, measured = _fleet(rng, 1000)
    trends = [fit_trend_shared(CAL_DAYS, m, [U_MEAS] * 3, [0.0] * 3, [None] * 3) for m in measured]
    fleet = fleet_drift([t.slope for t in trends], [t.cov[1, 1] for t in trends])
    assert abs(fleet.mean - MEAN_RATE) <= 3 * math.sqrt(fleet.mean_var)
    hits = n = 0
    for i in range(len(trends)):
        line = predict_line(CAL_DAYS, measured[i], [U_MEAS] * 3, fleet)
        iv = interval(line, -LIMIT, LIMIT, reliability)
        if iv.capped or iv.days == 0:
            continue
        assert iv.probability == pytest.approx(reliability, abs=1e-3)
        n += 1
        hits += abs(x0[i] + rate[i] * (CAL_DAYS[-1] + iv.days)) <= LIMIT
    assert n > 500, n
    assert abs(hits / n - reliability) <= _sampling_band(reliability, n), (hits / n, n)


def test_a_unit_without_history_takes_the_fleet():
    """One calibration only: the fleet's rate and spread set its interval, and the
    in-tolerance rate of such units is the target too."""
    rng = np.random.default_rng(5)
    _, _, measured = _fleet(rng, 400)
    trends = [fit_trend_shared(CAL_DAYS, m, [U_MEAS] * 3, [0.0] * 3, [None] * 3) for m in measured]
    fleet = fleet_drift([t.slope for t in trends], [t.cov[1, 1] for t in trends])
    x0, rate, _ = _fleet(np.random.default_rng(6), 800)  # new units, calibrated once at day 0
    first = x0 + rng.normal(0.0, U_MEAS, x0.size)
    hits = n = 0
    for i in range(x0.size):
        line = predict_line([0.0], [first[i]], [U_MEAS], fleet)
        assert line.rate == pytest.approx(fleet.mean)
        assert line.rate_var == pytest.approx(fleet.between_var + fleet.mean_var)
        iv = interval(line, -LIMIT, LIMIT, 0.9)
        if iv.capped or iv.days == 0:
            continue
        n += 1
        hits += abs(x0[i] + rate[i] * iv.days) <= LIMIT
    assert abs(hits / n - 0.9) <= _sampling_band(0.9, n), (hits / n, n)


def test_interval_edges():
    still = Prediction(0.0, 1e-8, 0.0, 0.0, 0.0, 0.0)
    assert interval(still, -LIMIT, LIMIT, 0.95, max_days=100).capped
    now_out = interval(Prediction(0.0299, 1e-6, 1e-5, 0.0, 0.0, 0.0), -LIMIT, LIMIT, 0.95)
    assert now_out.days == 0 and not now_out.capped
    unit = Prediction(0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    assert in_tolerance_probability(unit, 0.0, -1.96, 1.96) == pytest.approx(0.95, abs=1e-3)
    with pytest.raises(ValueError, match="reliability target"):
        interval(unit, -1.0, 1.0, 1.5)
    with pytest.raises(ValueError, match="no drift rate"):
        predict_line([0.0], [0.01], [1e-4], None)


def test_recall_section_of_the_profile():
    doc = {
        "name": "t",
        "version": "1",
        "device_model": "X",
        "limits": [],
        "recall": {"method": "fixed", "fixed_months": 6},
    }
    prof = ToleranceProfile.from_dict(doc)
    assert prof.recall["method"] == "fixed" and prof.recall["fixed_months"] == 6.0
    assert prof.recall["reliability"] == 0.95  # default
    assert ToleranceProfile.from_dict(prof.to_dict()).recall == prof.recall
    for bad, message in (
        ({"reliability": 1.2}, r"recall.reliability: expected a number in \(0, 1\), got 1.2"),
        ({"method": "attributes"}, "recall.method must be one of 'variables', 'fixed'"),
        ({"months": 3}, r"recall.months: unknown setting of \[recall\]"),
    ):
        with pytest.raises(ValueError, match=message):
            ToleranceProfile.from_dict({**doc, "recall": bad})


# --- through the archive: `calib query due` ------------------------------------------------


@pytest.fixture(scope="module")
def fleet_archive(tmp_path_factory):
    """60 MPU-6000 units, three calibrations a year apart, gyr.scale.x drifting."""
    root = tmp_path_factory.mktemp("recall")
    arch = new_archive(root)
    x0, rate, measured = _fleet(np.random.default_rng(8), 60)
    start = datetime(2024, 1, 8, 9, tzinfo=UTC)
    for u in range(60):
        for k, day in enumerate(CAL_DAYS):
            scale = Parameter("gyr.scale.x", float(measured[u, k]), U_MEAS, "1")
            started = start + timedelta(days=float(day))
            run = parameter_run(root, f"U{u:02d}", started, [scale], device_model="MPU-6000")
            archive_run(arch, run)
    return arch, start, x0, rate


def test_query_due_lists_the_units_with_their_intervals(fleet_archive):
    arch, start, x0, rate = fleet_archive
    res = CliRunner().invoke(app, ["query", "due", "--archive", str(arch.root), "--format", "json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.stdout)
    assert len(rows) == 60 and [r["due"] for r in rows] == sorted(r["due"] for r in rows)
    hits = n = 0
    last = start + timedelta(days=float(CAL_DAYS[-1]))
    for r in rows:
        assert r["limiting_parameter"] == "gyr.scale.x" and r["reliability"] == 0.95
        assert r["method"].startswith("variables")
        due = datetime.fromisoformat(r["due"]).date()  # interval_days is rounded to 0.1 day
        assert abs((due - (last + timedelta(days=r["interval_days"])).date()).days) <= 1
        if "capped" in r["method"] or r["interval_days"] == 0:  # not limited / due at once
            continue
        u = int(r["serial"][1:])
        days = r["interval_days"]
        n += 1
        hits += abs(x0[u] + rate[u] * (CAL_DAYS[-1] + days)) <= LIMIT
    assert n >= 40 and abs(hits / n - 0.95) <= _sampling_band(0.95, n), (hits / n, n)
    before = min(r["due"] for r in rows[5:])
    res = CliRunner().invoke(
        app, ["query", "due", "--before", before, "--archive", str(arch.root), "--format", "json"]
    )
    assert [r["serial"] for r in json.loads(res.stdout)] == [
        r["serial"] for r in rows if r["due"] <= before
    ]


def test_query_due_table_at_80_columns(fleet_archive, monkeypatch):
    """The recall at a glance on an 80-column terminal: unit, last calibration, its day,
    the due date and the interval, dates whole; the rest named as left out."""
    from pipelines import cli_shared

    for console in (cli_shared.out, cli_shared.err):
        monkeypatch.setattr(console, "width", 80)
    monkeypatch.setitem(cli_shared.DISPLAY, "wide", False)
    arch = fleet_archive[0]
    res = CliRunner().invoke(app, ["query", "due", "--archive", str(arch.root)])
    assert res.exit_code == 0, res.output
    rows = json.loads(
        CliRunner()
        .invoke(app, ["query", "due", "--archive", str(arch.root), "--format", "json"])
        .stdout
    )
    lines = res.stdout.splitlines()
    # the table's lines (the facts under it are soft-wrapped text)
    assert all(len(line) <= 80 for line in lines if line[:1] in "┏┃┡│└"), res.stdout
    header = " ".join(line for line in lines if line.startswith("┃"))  # wrapped names
    for name in ("run id", "due", "interval", "months"):
        assert name in header, header
    for r in rows:
        row = next(line for line in lines if r["run_id"] in line)
        assert r["serial"] in row and r["due"] in row, row
    # one day for every unit here: said once under the table
    assert f"calibrated: {rows[0]['started_at'][:10]}" in res.stdout, res.stdout
    assert "owner: not recorded" in res.stdout


def test_due_page_of_calib_serve(fleet_archive):
    from fastapi.testclient import TestClient

    from pipelines.web.app import create_app
    from storage import queries

    arch = fleet_archive[0]
    with TestClient(create_app(queries.open_readonly(arch))) as client:
        page = client.get("/due")
        assert page.status_code == 200
        assert page.text.count('<tr><td class="when">') == 60
        assert "gyr.scale.x" in page.text and "variables, R = 0.95" in page.text
        first = page.text.split('<td class="when">')[1][:10]
        some = client.get(f"/due?before={first}")
        assert some.status_code == 200 and 0 < some.text.count('<td class="when">') < 60
        bad = client.get("/due?before=next-week")
        assert bad.status_code == 400 and "expected a date YYYY-MM-DD" in bad.text


def test_certificate_names_the_interval_and_its_method(fleet_archive):
    from pipelines.recall import unit_recall
    from pipelines.reports.recommendations import interval_text
    from storage import queries

    arch = fleet_archive[0]
    runs = queries.history(arch, "U00")["run_id"].tolist()
    found = unit_recall(arch, "U00", runs[-1])
    assert found is not None and found["serial"] == "U00"
    text = interval_text(found)
    assert text.startswith(f"{found['interval_months']:g} months, by {found['due']}")
    if not found["capped"]:
        assert "variables-data method (NCSL RP-1 / ILAC-G24)" in text
        assert "probability 95% of gyr.scale.x being in tolerance at its end" in text
    assert unit_recall(arch, "U00", runs[0]) is None  # an earlier run: not judged by later data
    assert interval_text(None) == "12 months"


def test_a_thermal_campaign_is_not_read_as_drift(tmp_path):
    """A unit calibrated at 0, 20, 40 and 60 deg C on four days differs by its temperature
    effect (here 200 times the fleet's drift a day), not by drift: the fleet's rate and the
    interval of a unit calibrated once stay what they are without that unit."""
    from pipelines.recall import recall_list

    arch = new_archive(tmp_path)
    _, _, measured = _fleet(np.random.default_rng(3), 8)
    start = datetime(2024, 1, 8, 9, tzinfo=UTC)

    def add(serial: str, day: float, value: float, temperature_c: float) -> None:
        scale = Parameter("gyr.scale.x", value, U_MEAS, "1")
        run = parameter_run(
            tmp_path, serial, start + timedelta(days=day), [scale],
            temperature_c=temperature_c, device_model="MPU-6000",
        )  # fmt: skip
        archive_run(arch, run)

    for u in range(8):
        for k, day in enumerate(CAL_DAYS):
            add(f"U{u}", float(day), float(measured[u, k]), 20.0)
    add("NEW", 740.0, 0.005, 20.0)
    alone = {r["serial"]: r for r in recall_list(arch)}["NEW"]
    assert alone["method"].startswith("variables") and alone["interval_days"] > 0
    for k, temp in enumerate([0.0, 20.0, 40.0, 60.0]):  # 2e-4 per deg C: 4e-3 a day
        add("THERMAL", 700.0 + k, 0.005 + 2e-4 * (temp - 20.0), temp)
    rows = {r["serial"]: r for r in recall_list(arch)}
    assert rows["NEW"]["interval_days"] == alone["interval_days"], (rows["NEW"], alone)
    # its own 20 deg C calibration and the fleet's rate: a unit calibrated once
    assert rows["THERMAL"]["interval_days"] > 0.5 * alone["interval_days"], rows["THERMAL"]


def test_a_unit_whose_last_calibration_failed_is_due_now(tmp_path):
    """A failed calibration releases nothing: no interval runs from it, whatever the
    method (here the fixed fallback: one calibration, no fleet)."""
    from pipelines.recall import recall_list

    arch = new_archive(tmp_path)
    started = datetime(2026, 3, 2, 9, tzinfo=UTC)
    for serial, verdict in (("OK-1", "pass"), ("BAD-1", "fail")):
        scale = Parameter("gyr.scale.x", 0.001, U_MEAS, "1")
        run = parameter_run(
            tmp_path, serial, started, [scale], device_model="MPU-6000", verdict=verdict
        )
        archive_run(arch, run)
    rows = {r["serial"]: r for r in recall_list(arch)}
    assert rows["BAD-1"]["interval_days"] == 0 and rows["BAD-1"]["due"] == "2026-03-02"
    assert rows["BAD-1"]["method"] == "due now: its last calibration failed"
    assert rows["OK-1"]["method"] == "fixed 12 months (no drift to judge by)"


def test_a_bad_lab_profile_is_refused_not_read_as_no_owner(tmp_path, monkeypatch):
    from pipelines.recall import recall_list

    arch = new_archive(tmp_path)
    scale = Parameter("gyr.scale.x", 0.001, U_MEAS, "1")
    run = parameter_run(tmp_path, "OK-1", datetime(2026, 3, 2, tzinfo=UTC), [scale])
    archive_run(arch, run)
    lab = tmp_path / "profiles"
    lab.mkdir()
    (lab / "lab.toml").write_text("[customer\nname = 'x'\n")
    monkeypatch.setenv("CALIB_PROFILES", str(lab))
    with pytest.raises(ValueError, match="lab profile .*lab.toml"):
        recall_list(arch)
