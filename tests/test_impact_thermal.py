"""`calib impact` for a thermal chamber whose reading was offset (docs/impact.md): a unit's
thermal campaign run in a chamber that read TEMP_OFFSET high, archived by the real
pipeline into a real SQLite file and fitted; the same runs with the true temperatures
archived and fitted in a second archive (the direct solve with the true reference)."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from typer.testing import CliRunner

from calib_core.reference_errors import parse_error
from calib_core.simulate.thermal import random_thermal_truth, thermal_campaign
from calib_core.thermal import ThermalModel
from calib_testing.run_writers import six_position_manifest, write_csv_run
from pipelines.cli import app
from pipelines.impact import impact
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from pipelines.thermal_campaign import thermal_fit
from storage import queries
from storage.db import resolve_archive
from storage.verify import verify

SERIAL = "TH-7"
TEMP_OFFSET = 3.0  # the chamber read 3 degC high: 23 degC read at a true 20
TRUE_TEMPS = (0.0, 20.0, 40.0, 60.0)
START = datetime(2026, 5, 4, 8, 0, tzinfo=UTC)


def _manifest(temp: float, started: datetime) -> dict:
    m = six_position_manifest(SERIAL, started=started.isoformat(), temperature_c=temp)
    m["equipment"] = [
        {"kind": "thermal_chamber", "model": "TC-1", "serial": "TC-5",
         "calibration_due": "2027-01-01"}
    ]  # fmt: skip
    return m


def _archive(root, name: str, offset: float) -> tuple:
    arch = resolve_archive(str(root / name))
    arch.upgrade()
    ids = []
    for i, (temp, run) in enumerate(zip(TRUE_TEMPS, _RUNS, strict=True)):
        folder = root / f"{name}-run{i}"
        write_csv_run(run.run.segments, folder, _manifest(temp + offset, START + timedelta(days=i)))
        (source,) = discover_runs([folder])
        outcome = process_run(source, arch)
        assert outcome["status"] == "ok", outcome["error"]
        ids.append(outcome["run_id"])
    return arch, ids, thermal_fit(arch, SERIAL)


_RUNS: list = []


@pytest.fixture(scope="module")
def chamber(tmp_path_factory):
    root = tmp_path_factory.mktemp("impact_thermal")
    rng = np.random.default_rng(77)
    _RUNS[:] = thermal_campaign(random_thermal_truth(rng), rng, TRUE_TEMPS, static_s=6.0)
    arch, ids, fit = _archive(root, "read", TEMP_OFFSET)
    true_arch, true_ids, true_fit = _archive(root, "true", 0.0)
    return {
        "archive": arch, "ids": ids, "fit": fit,
        "true_archive": true_arch, "true_ids": true_ids, "true_fit": true_fit,
    }  # fmt: skip


def _model(arch) -> ThermalModel:
    return ThermalModel.from_dict(queries.latest_thermal_model(arch, SERIAL)["document"])


def test_chamber_offset_moves_temperatures_and_the_thermal_model(chamber):
    arch, ids = chamber["archive"], chamber["ids"]
    error = parse_error(f"temperature_offset_c={TEMP_OFFSET}")
    doc = impact(arch, "TC-5", error, "2026-05-01")
    assert [r["run_id"] for r in doc["runs"]] == ids
    true_verdicts = {
        queries.run_summary(chamber["true_archive"], i).calibration.verdict
        for i in chamber["true_ids"]
    }
    for r, temp, true_id in zip(doc["runs"], TRUE_TEMPS, chamber["true_ids"], strict=True):
        assert r["affected"]
        assert r["temperature_c"] == {"before": temp + TEMP_OFFSET, "after": temp}
        assert not r["moved"]  # the solve does not read the chamber's temperature
        # The lab condition read at the true temperature: 23 degC read was outside the
        # profile's 18 .. 22, the true 20 is inside, as the run archived at 20 says.
        true_checks = {
            c.name: c.passed
            for c in queries.run_summary(chamber["true_archive"], true_id).calibration.checks
        }
        for c in r["checks_changed"]:
            assert c["passed_after"] == true_checks[c["name"]], c
        changed = [c["name"] for c in r["checks_changed"]]
        assert changed == (["condition:ambient_temperature_c"] if temp == 20.0 else []), changed
        true = queries.run_summary(chamber["true_archive"], true_id).calibration.verdict
        assert r["verdict_after"] == true, (r, true_verdicts)
    (c,) = doc["campaigns"]
    assert c["serial"] == SERIAL and c["corrected"] == ids
    assert c["range_before"]["t_min"] == TRUE_TEMPS[0] + TEMP_OFFSET
    assert (c["range_after"]["t_min"], c["range_after"]["t_max"]) == (TRUE_TEMPS[0], TRUE_TEMPS[-1])
    # The refit is the direct fit over the true temperatures (the same calibrations).
    direct, before = _model(chamber["true_archive"]), _model(arch)
    assert c["range_after"]["t_ref"] == direct.t_ref
    for m in c["moved"]:
        U = 2 * direct.std(m["name"], m["temperature_c"])
        want = direct.value(m["name"], m["temperature_c"])
        assert m["after"] == pytest.approx(want, abs=1e-9 * U)
        assert m["change_in_U"] == pytest.approx((m["after"] - m["before"]) / m["U_after"])
    # What the offset does: the archived model is the true one shifted by the offset,
    # before(T + E) = after(T) (a polynomial fit and its order tests are shift-invariant).
    grid = np.linspace(TRUE_TEMPS[0], TRUE_TEMPS[-1], 15)
    for name in direct.curves:
        U = 2 * direct.std(name, grid)
        np.testing.assert_allclose(
            before.value(name, grid + TEMP_OFFSET),
            direct.value(name, grid),
            rtol=0,
            atol=1e-6 * U.min(),
        )
    # The biases' thermal slopes are many times their uncertainty over 2 degC: they move.
    biggest = c["moved"][0]
    assert abs(biggest["change_in_U"]) > 1, biggest


def test_chamber_offset_reported_in_words(chamber, tmp_path):
    """The dry run's table, its HTML page: corrected temperatures and the refitted model."""
    page = tmp_path / "impact.html"
    res = CliRunner().invoke(
        app,
        ["impact", "TC-5", "--from", "2026-05-01", "--error", f"temperature_offset_c={TEMP_OFFSET}",
         "--html", str(page), "--archive", str(chamber["archive"].root)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    flat = " ".join(res.output.split())
    assert f"thermal model of {SERIAL} fitted again (4 of 4 runs corrected)" in flat
    assert f"{TRUE_TEMPS[0] + TEMP_OFFSET:g} .. {TRUE_TEMPS[-1] + TEMP_OFFSET:g} -> " in flat
    html = page.read_text()
    assert "Thermal models fitted again" in html and "temperature 23 -&gt; 20 degC" in html


@pytest.mark.slow  # fast: the dry impact above, test_impact's apply
def test_chamber_offset_apply_revises_runs_and_refits(chamber):
    arch, ids = chamber["archive"], chamber["ids"]
    error = f"temperature_offset_c={TEMP_OFFSET:g}"
    res = CliRunner().invoke(
        app, ["impact", "TC-5", "--from", "2026-05-01", "--error", error, "--apply", "--json",
              "--archive", str(arch.root)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert [(r["run_id"], r["status"]) for r in doc["runs"]] == [(i, "revised") for i in ids]
    reason = f"out-of-tolerance reference TC-5: {error}"
    for run_id, temp in zip(ids, TRUE_TEMPS, strict=True):
        summary = queries.run_summary(arch, run_id)
        assert {p.temperature_c for p in summary.calibration.parameters} == {temp}
        lin = queries.lineage(arch, run_id, "acc.bias.x")
        assert {s["name"]: s for s in lin["steps"]}["reprocess"]["settings"]["reason"] == reason
    (c,) = doc["campaigns"]
    held = queries.latest_thermal_model(arch, SERIAL)
    assert held["id"] == c["model_id_after"] and held["document"]["info"]["reason"] == reason
    assert (held["t_min"], held["t_max"]) == (TRUE_TEMPS[0], TRUE_TEMPS[-1])
    direct, after = _model(chamber["true_archive"]), _model(arch)
    grid = np.linspace(TRUE_TEMPS[0], TRUE_TEMPS[-1], 15)
    for name in direct.curves:
        U = 2 * direct.std(name, grid)
        np.testing.assert_allclose(
            after.value(name, grid), direct.value(name, grid), rtol=0, atol=1e-6 * U.min()
        )
    assert c["status"] == "refitted"
    assert verify(arch).ok
    # Applied again: revisions and model are duplicates, nothing new is archived.
    again = impact(arch, "TC-5", parse_error(error), "2026-05-01", apply=True)
    assert {r["status"] for r in again["runs"]} == {"duplicate"}
    assert again["campaigns"][0]["status"] == "duplicate"
    assert queries.latest_thermal_model(arch, SERIAL)["id"] == held["id"]
    assert max(abs(m["change_in_U"]) for m in again["campaigns"][0]["moved"]) < 1e-6
