"""Drift trends and fleet statistics: the numerics, then the commands on a 300-run archive."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from typer.testing import CliRunner

from calib_core import params
from calib_core.calibration import Parameter
from calib_core.drift import fit_trend, fleet_statistics, forecast_exit
from calib_core.simulate.lab_run import random_errors
from calib_core.simulate.thermal import recalibration_history
from calib_testing.archives import new_archive, parameter_run
from storage.archive import archive_run
from storage.run_input import RunIn

# --- numerics ---------------------------------------------------------------------------


def test_trend_matches_an_independent_weighted_fit():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 700, 15))
    s = rng.uniform(1e-5, 3e-5, t.size)
    y = 0.02 + 1e-5 * t + rng.normal(0, s)
    tr = fit_trend(t, y, s)
    # Closed form of weighted least squares for a line, written out independently.
    w = 1 / s**2
    tbar = np.sum(w * t) / np.sum(w)
    sxx = np.sum(w * (t - tbar) ** 2)
    b = np.sum(w * (t - tbar) * y) / sxx
    a = np.sum(w * y) / np.sum(w)
    s2 = np.sum(w * (y - a - b * (t - tbar)) ** 2) / (t.size - 2)
    assert tr.t0 == pytest.approx(tbar)
    assert tr.slope == pytest.approx(b, rel=1e-10)
    assert tr.intercept == pytest.approx(a, rel=1e-10)
    assert tr.slope_std == pytest.approx(math.sqrt(s2 / sxx), rel=1e-8)


def test_trend_slope_within_uncertainty_over_seeds():
    """Simulated monthly re-calibrations with a known drift: |slope - truth| <= t_0.975 std
    in >= 17 of 20 seeds (expected 19; binomial P(<= 16) ~ 1.6 %)."""
    drift = 2e-6  # rad/s per day on gyr.bias.z
    hits = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        hist = recalibration_history(
            random_errors(rng), rng, n_runs=12, drift_per_day={"gyr.bias.z": drift}
        )
        days = np.array([h.day for h in hist])
        true = np.array([h.errors.parameters()["gyr.bias.z"] for h in hist])
        std = np.full(days.size, 1e-5)
        tr = fit_trend(days, true + rng.normal(0, std), std)
        hits += abs(tr.slope - drift) <= stats.t.ppf(0.975, tr.dof) * tr.slope_std
    assert hits >= 17, hits


def test_forecast_of_a_known_line():
    t = np.arange(0.0, 300.0, 30.0)
    y = 0.01 + 2e-5 * t  # exactly on the line; tiny noise keeps the fit regular
    y = y + np.random.default_rng(0).normal(0, 1e-7, t.size)
    tr = fit_trend(t, y, np.full(t.size, 1e-7))
    fc = forecast_exit(tr, -0.03, 0.03)
    assert fc.crossing == pytest.approx(1000.0, abs=2.0)  # 0.01 + 2e-5 t = 0.03
    assert fc.earliest is not None and fc.earliest <= fc.crossing
    assert not fc.out_now
    inward = forecast_exit(fit_trend(t, -y + 0.02, np.full(t.size, 1e-7)), -1.0, 1.0)
    assert inward.crossing is None and inward.earliest is None
    assert forecast_exit(tr, -0.03, 0.01).out_now


def test_trend_needs_three_points():
    with pytest.raises(ValueError, match="at least 3 calibrations"):
        fit_trend([0.0, 10.0], [1.0, 2.0])


def test_fleet_statistics_per_bin():
    rng = np.random.default_rng(1)
    temps = rng.choice([0.0, 20.4, 39.0], 300)
    values = rng.normal(0, 1, 300) + temps / 10
    units = [f"U{i % 25}" for i in range(300)]
    bins = fleet_statistics(values, temps, units, bin_c=5.0)
    assert [b.temperature for b in bins] == [0.0, 20.0, 40.0]
    for b, t in zip(bins, (0.0, 20.4, 39.0), strict=True):
        x = values[temps == t]
        assert b.n == x.size and b.units == len({units[i] for i in np.flatnonzero(temps == t)})
        assert b.mean == pytest.approx(x.mean()) and b.std == pytest.approx(x.std(ddof=1))
        assert b.p95 == pytest.approx(np.percentile(x, 95))


# --- the commands on an archive with a few hundred runs ------------------------------------

N_UNITS, N_RUNS = 20, 15  # 300 runs
START = datetime(2025, 1, 6, 9, 0, tzinfo=UTC)
GYR_SCALE_DRIFT = 1.5e-5  # per day, unit U00 only: leaves the 0.03 tolerance within the horizon
FLEET_TEMPS = (0.0, 20.0, 40.0)
ACC_BIAS_TC = 2e-3  # m/s^2 per deg C of acc.bias.x, all units


def _run_in(serial: str, started: datetime, temp: float, values: dict, folder: Path) -> RunIn:
    plist = [Parameter(n, v, s, params.unit_of(n)) for n, (v, s) in values.items()]
    return parameter_run(folder, serial, started, plist, temperature_c=temp, profile_version="2")


@pytest.fixture(scope="module")
def fleet_archive(tmp_path_factory):
    """300 parameter-level simulated runs: U00 at 20 deg C with a drifting gyro scale,
    the others cycling through 0 / 20 / 40 deg C with a thermal acc bias."""
    root = tmp_path_factory.mktemp("fleet")
    arch = new_archive(root)
    rng = np.random.default_rng(11)
    truth = {}
    for u in range(N_UNITS):
        serial = f"U{u:02d}"
        base = random_errors(rng)
        base.gyr_M[0, 0] = 0.02 if u == 0 else base.gyr_M[0, 0]
        drift = {"gyr.scale.x": GYR_SCALE_DRIFT} if u == 0 else {}
        hist = recalibration_history(base, rng, n_runs=N_RUNS, drift_per_day=drift)
        for k, h in enumerate(hist):
            temp = 20.0 if u == 0 else FLEET_TEMPS[k % 3]
            p = h.errors.parameters()
            acc_bias = p["acc.bias.x"] + ACC_BIAS_TC * (temp - 20)
            values = {
                "gyr.scale.x": (p["gyr.scale.x"] + rng.normal(0, 4e-5), 4e-5),
                "acc.bias.x": (acc_bias + rng.normal(0, 1.5e-4), 1.5e-4),
            }
            started = START + timedelta(days=h.day)
            archive_run(arch, _run_in(serial, started, temp, values, root))
            truth[(serial, k)] = (h.day, p)
    return arch, truth


@pytest.mark.slow
def test_trend_command_on_the_archive(fleet_archive, tmp_path):
    from pipelines.cli import app
    from pipelines.trends import trend_report

    arch, truth = fleet_archive
    png = tmp_path / "trend.png"
    res = CliRunner().invoke(
        app, ["trend", "U00", "gyr.scale.x", "--plot", str(png), "--archive", str(arch.root)]
    )
    assert res.exit_code == 0, res.output
    assert "gyr.scale.x of U00" in res.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000

    rep = trend_report(arch, "U00", "gyr.scale.x")
    tr, fc = rep["trend"], rep["forecast"]
    k = stats.t.ppf(0.995, tr.dof)
    assert abs(tr.slope - GYR_SCALE_DRIFT) <= k * tr.slope_std
    # The true line reaches the profile's 0.03 at day (0.03 - 0.02) / drift from the first run.
    first = datetime.fromisoformat(str(rep["table"]["started_at"].iloc[0])).astimezone(UTC)
    true_cross = (first - datetime(1970, 1, 1, tzinfo=UTC)).total_seconds() / 86400 + (
        0.01 / GYR_SCALE_DRIFT
    )
    # Its uncertainty from the slope's: d(cross) = (limit - value) / slope^2 * d(slope).
    spread = (0.03 - tr.value(tr.t_last)) / tr.slope**2 * tr.slope_std + 1.0
    assert abs(fc.crossing - true_cross) <= k * spread
    assert fc.earliest <= fc.crossing
    assert rep["summary"]["tolerance"] == [-0.03, 0.03]


@pytest.mark.slow  # 300 archived runs; fast: test_fleet_statistics_per_bin, test_cli_width's fleet
def test_fleet_command_on_the_archive(fleet_archive, tmp_path):
    import json

    from pipelines.cli import app

    arch, truth = fleet_archive
    png = tmp_path / "fleet.png"
    res = CliRunner().invoke(
        app,
        [
            "fleet",
            "SIM-IMU",
            "acc.bias.x",
            "--plot",
            str(png),
            "--json",
            "--archive",
            str(arch.root),
        ],
    )
    assert res.exit_code == 0, res.output
    rows = {r["temperature"]: r for r in json.loads(res.stdout)}
    assert sum(r["n"] for r in rows.values()) == N_UNITS * N_RUNS
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # Independent computation from the truth: the simulated value of every run by bin.
    for temp in FLEET_TEMPS:
        runs = [
            p["acc.bias.x"] + ACC_BIAS_TC * (temp - 20)
            for (serial, k), (_, p) in truth.items()
            if (20.0 if serial == "U00" else FLEET_TEMPS[k % 3]) == temp
        ]
        r = rows[temp]
        assert r["n"] == len(runs)
        # Archived values carry 1.5e-4 of simulated estimation noise: the bin mean moves
        # by at most ~4 * 1.5e-4 / sqrt(n) from the truth's mean.
        assert abs(r["mean"] - np.mean(runs)) < 4 * 1.5e-4 / math.sqrt(len(runs))
    # The thermal slope shows across bins: 2e-3 per deg C between 0 and 40 deg C.
    # Same units in every bin, so their offsets cancel; noise sd 1.5e-4 * sqrt(2 / 95) ~ 2e-5.
    assert rows[40.0]["mean"] - rows[0.0]["mean"] == pytest.approx(80e-3, abs=1e-4)


def test_trend_of_an_unknown_serial_is_a_clear_error(tmp_path):
    from pipelines.cli import app

    arch = new_archive(tmp_path)
    res = CliRunner().invoke(app, ["trend", "NOPE", "gyr.scale.x", "--archive", str(arch.root)])
    assert res.exit_code == 2
    assert "no archived values of gyr.scale.x for serial 'NOPE'" in res.output
