"""Runs on the same reference share its Type B error (calib_core.drift.fit_trend_shared,
calib_core.verification.repeatability with shared references): simulated drifting units
whose runs were made on two references in turn."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calib_core.distributions import norm_ppf, t_ppf
from calib_core.drift import fit_trend, fit_trend_shared, shared_covariance
from calib_core.tolerances import ToleranceProfile
from calib_core.verification import RunValues, repeatability

T_DAYS = np.array([0.0, 120.0, 240.0, 365.0, 480.0, 600.0])
TABLES = ["RT-A", "RT-A", "RT-A", "RT-B", "RT-B", "RT-B"]  # the lab changed tables
U_A, U_B, SLOPE = 1.0e-4, 3.0e-4, 2.0e-7  # SI, SI, SI per day
SEEDS = 1000
# Binomial: the share of SEEDS intervals that cover, at 95 %, has std 0.0069; 3 std.
BAND = 3.0 * math.sqrt(0.95 * 0.05 / SEEDS)


def _draw(rng: np.random.Generator, tables: list[str]) -> np.ndarray:
    offset = {name: rng.normal(0.0, U_B) for name in sorted(set(tables))}
    return (
        0.01
        + SLOPE * T_DAYS
        + np.array([offset[n] for n in tables])
        + rng.normal(0.0, U_A, T_DAYS.size)
    )


def test_shared_reference_slope_intervals_cover_95_percent():
    """Over 1,000 seeds the GLS slope interval covers the true slope 95 % of the time; the
    fit that treats the runs as independent (today's `fit_trend`, weights 1/u_c) does not."""
    rng = np.random.default_rng(2026)
    z = norm_ppf(0.975)
    shared = independent = 0
    for _ in range(SEEDS):
        y = _draw(rng, TABLES)
        gls = fit_trend_shared(T_DAYS, y, [U_A] * 6, [U_B] * 6, TABLES)
        shared += abs(gls.slope - SLOPE) <= z * gls.slope_std
        ind = fit_trend(T_DAYS, y, [math.hypot(U_A, U_B)] * 6)
        independent += abs(ind.slope - SLOPE) <= t_ppf(0.975, ind.dof) * ind.slope_std
    assert abs(shared / SEEDS - 0.95) <= BAND, shared / SEEDS
    assert independent / SEEDS < 0.95 - BAND, independent / SEEDS  # measured 0.56


def test_a_common_reference_cancels_in_the_slope_and_stays_in_the_intercept():
    one = ["RT-A"] * 6
    y = _draw(np.random.default_rng(1), one)
    gls = fit_trend_shared(T_DAYS, y, [U_A] * 6, [U_B] * 6, one)
    type_a = fit_trend_shared(T_DAYS, y, [U_A] * 6, [0.0] * 6, one)
    assert gls.slope_std == pytest.approx(type_a.slope_std, rel=1e-9)  # cancels in a slope
    assert gls.slope == pytest.approx(type_a.slope, rel=1e-9)
    # The intercept keeps the whole shared u_B: it does not shrink with more runs.
    assert math.sqrt(gls.cov[0, 0]) == pytest.approx(math.hypot(U_B, U_A / math.sqrt(6)))
    many = np.linspace(0.0, 600.0, 60)
    big = fit_trend_shared(many, 0.01 + SLOPE * many, [U_A] * 60, [U_B] * 60, ["RT-A"] * 60)
    assert math.sqrt(big.cov[0, 0]) > U_B


def test_shared_covariance_blocks():
    V = shared_covariance([1.0, 1.0, 2.0], [3.0, 3.0, 1.0], ["a", "a", None])
    assert np.allclose(V, [[10.0, 9.0, 0.0], [9.0, 10.0, 0.0], [0.0, 0.0, 5.0]])
    with pytest.raises(ValueError, match="equal length"):
        shared_covariance([1.0], [1.0, 2.0], ["a"])


def _profile() -> ToleranceProfile:
    return ToleranceProfile.from_dict(
        {
            "name": "t",
            "version": "1",
            "device_model": "test",
            "limits": [],
            "repeatability": {
                "cv_max": 0.01,
                "alpha": 0.05,
                "min_runs": 3,
                "max_runs": 6,
                "temperature_tol_c": 2.0,
            },
        }
    )


def test_repeatability_scatter_with_shared_references():
    """A repeatable unit measured on two references in turn: judged with the references'
    shared Type B, the scatter rule's false alarms stay at its alpha; on Type A alone (as
    if the runs shared nothing systematic) they do not."""
    profile = _profile()
    rng = np.random.default_rng(11)
    alarms_shared = alarms_type_a = 0
    n = 400
    for _ in range(n):
        y = _draw(rng, TABLES) - SLOPE * T_DAYS  # repeatable: no drift
        shared = [
            RunValues(
                f"r{i}", 20.0, {"gyr.bias.x": (float(v), U_A)}, {"gyr.bias.x": (TABLES[i], U_B)}
            )
            for i, v in enumerate(y)
        ]
        alone = [RunValues(f"r{i}", 20.0, {"gyr.bias.x": (float(v), U_A)}) for i, v in enumerate(y)]
        alarms_shared += not repeatability(shared, profile)[0].passed
        alarms_type_a += not repeatability(alone, profile)[0].passed
    # alpha = 0.05 over 400 repeatable units: 3 binomial std = 0.033
    assert alarms_shared / n <= 0.05 + 3 * math.sqrt(0.05 * 0.95 / n), alarms_shared / n
    assert alarms_type_a / n > 0.5, alarms_type_a / n


# --- through the archive: `calib trend` and `calib repeatability` ------------------------


def _budget(name: str, value: float) -> dict:
    rows = [
        {
            "source": "noise",
            "kind": "A",
            "distribution": "normal",
            "std_input": U_A,
            "sensitivity": 1.0,
            "contribution": U_A,
            "dof": 10.0,
            "unit": "rad/s",
        },
        {
            "source": "table rate",
            "kind": "B",
            "distribution": "rectangular",
            "std_input": U_B,
            "sensitivity": 1.0,
            "contribution": U_B,
            "dof": None,
            "unit": "rad/s",
        },
    ]
    uc = math.hypot(U_A, U_B)
    return {
        "parameter": name,
        "value": value,
        "unit": "rad/s",
        "rows": rows,
        "uc": uc,
        "nu_eff": None,
        "k": 2.0,
        "U": 2 * uc,
        "coverage": 0.95,
    }


def _archive_runs(arch, root, y) -> None:
    """Six runs of U-SH on table RT-A then RT-B, gyr.bias.x = y, each with a budget."""
    from datetime import UTC, datetime, timedelta

    from calib_core.calibration import Parameter, StepRecord
    from calib_testing.archives import parameter_run
    from storage.archive import archive_run

    start = datetime(2025, 1, 6, 9, tzinfo=UTC)
    name = "gyr.bias.x"
    for day, table, value in zip(T_DAYS, TABLES, y, strict=True):
        budget = {"budgets": {name: _budget(name, float(value))}}
        run = parameter_run(
            root,
            "U-SH",
            start + timedelta(days=float(day)),
            [Parameter(name, float(value), U_A, "rad/s")],
            procedure="rate_table",
            equipment=[
                {
                    "kind": "rate_table",
                    "model": "T",
                    "serial": table,
                    "calibration_due": "2030-01-01",
                }
            ],
            steps=[StepRecord("uncertainty", {}, budget, "test")],
        )
        archive_run(arch, run)


@pytest.fixture(scope="module")
def shared_archive(tmp_path_factory):
    from calib_testing.archives import new_archive

    root = tmp_path_factory.mktemp("shared")
    arch = new_archive(root)
    y = _draw(np.random.default_rng(5), TABLES)
    _archive_runs(arch, root, y)
    return arch, y


def test_equipment_queries_on_both_back_ends(archive, tmp_path):
    """storage.queries.equipment_runs and run_references on SQLite and PostgreSQL."""
    from storage import queries

    _archive_runs(archive, tmp_path, _draw(np.random.default_rng(1), TABLES))
    runs = queries.equipment_runs(archive, "RT-B", "2026-01-01", "2026-06-30")
    assert [r["equipment_kind"] for r in runs] == ["rate_table"] * 2  # days 365, 480 (not 600)
    assert all(r["serial"] == "U-SH" and r["verdict"] == "pass" for r in runs)
    assert queries.equipment_runs(archive, "RT-B", "2026-01-01", kind="daq") == []
    with pytest.raises(ValueError, match="from"):
        queries.equipment_runs(archive, "RT-B", "next year")
    refs = queries.run_references(archive, [r["run_id"] for r in runs] + ["R000000000000"])
    assert set(refs) == {r["run_id"] for r in runs}
    for ref in refs.values():
        assert ref["equipment"] == [("rate_table", "RT-B")]
        assert ref["budgets"]["gyr.bias.x"]["rows"][1]["kind"] == "B"


def test_trend_of_the_archive_uses_the_shared_reference(shared_archive):
    from pipelines.trends import trend_report

    arch, y = shared_archive
    rep = trend_report(arch, "U-SH", "gyr.bias.x")
    direct = fit_trend_shared(T_DAYS, y, [U_A] * 6, [U_B] * 6, TABLES)
    assert rep["summary"]["fit"] == "shared reference (GLS)" and rep["summary"]["references"] == 2
    assert rep["trend"].slope == pytest.approx(direct.slope, rel=1e-9)
    assert rep["trend"].slope_std == pytest.approx(direct.slope_std, rel=1e-9)


def test_repeatability_of_the_archive_names_the_references(shared_archive):
    from pipelines.shared_reference import with_shared
    from storage import queries

    arch, _ = shared_archive
    cands = queries.repeatability_candidates(arch, "U-SH", "rate_table")
    values = [RunValues(c["run_id"], 20.0, c["parameters"]) for c in cands]
    shared = with_shared(arch, values)
    refs = {r.shared["gyr.bias.x"][0].split(" @ ")[0] for r in shared}
    assert refs == {"rate_table:RT-A", "rate_table:RT-B"}
    assert all(r.shared["gyr.bias.x"][1] == pytest.approx(U_B) for r in shared)
