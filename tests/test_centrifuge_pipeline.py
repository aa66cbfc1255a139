"""The centrifuge from run folders: `calib centrifuge`, the `centrifuge` procedure, the archive."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from calib_core import params, procedures
from calib_core.simulate.centrifuge import CentrifugeNoise, CentrifugeSchedule, simulate_centrifuge
from calib_core.solvers.centrifuge_model import canonical_name
from calib_core.solvers.centrifuge_segments import step_label
from calib_testing.run_writers import write_centrifuge_run
from pipelines.centrifuge import REPORT_NAME
from pipelines.cli import app
from pipelines.ingest import RunSource
from pipelines.process import process_run
from storage.db import resolve_archive

# Paper-like: RMS error 0.3-0.4 m/s^2 per axis over 2..20 g before compensation.
TRUTH = {
    "x": {"const": 0.2, "a_x": 1.5e-3, "a_x^2": 1e-5, "a_y^2": 5e-6},
    "y": {"const": -0.25, "a_y": 1.2e-3, "a_z": 2e-3},
    "z": {"const": 0.3, "a_z": -1e-3, "a_z^2": 6e-6, "a_x^2": 3e-6},
}
PHI = {"x+": 0.01, "x-": -0.006, "y+": 0.004, "y-": 0.012, "z+": -0.008, "z-": 0.003}
# Short records at 50 Hz keep the CSV small (~23k rows); >= 2 table turns per step.
SIM = dict(
    phi_h=PHI,
    noise=CentrifugeNoise(scale_instability=2e-4, run_offset_std=0.02),
    schedule=CentrifugeSchedule(
        sample_rate=50.0, zero_duration=4.0, one_g_duration=20.0, step_duration=4.0
    ),
)


def _manifest(**settings) -> dict:
    return {
        "unit": {"serial": "HG-7", "model": "MEMS-HG", "manufacturer": "ACME"},
        "run": {
            "started": "2026-03-02T09:00:00",
            "operator": "lab",
            "tolerance_profile": "mpu6000",
            "settings": {
                "latitude_deg": 50.0,
                "scale_1g": {a: TRUTH[a][f"a_{a}"] for a in "xyz"},
                **settings,
            },
        },
        # the simulation's gravity (standard); a latitude alone would mean Helmert's
        "site": {"latitude_deg": 50.0, "gravity_model": "standard"},
        "equipment": [
            {"kind": "centrifuge", "model": "C-20", "serial": "C1", "calibration_due": "2027-01-31"}
        ],
    }


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("centrifuge")
    out = {}
    for name, seed in (("run", 11), ("repeat", 12)):
        sim = simulate_centrifuge(TRUTH, rng=np.random.default_rng(seed), **SIM)
        write_centrifuge_run(sim, root / name, _manifest(alpha=0.001))
        out[name] = (root / name, sim)
    return out


def test_cli_report_prints_statistics_and_validation(runs, tmp_path):
    """Acceptance: compensation cuts the repeat run's RMS error by >= 65 % per axis.

    What compensation cannot remove is the turn-on bias change between the two
    runs (std 0.02 * sqrt(2) = 0.03 m/s^2) plus the step scale instability
    (2e-4 x ~100 m/s^2 RMS input = 0.02 m/s^2): ~0.04 m/s^2 against 0.3 m/s^2
    before, an 85 % cut; 65 % would need 3 times that.
    """
    (run, _), (repeat, _) = runs["run"], runs["repeat"]
    report = tmp_path / "report.txt"
    res = CliRunner().invoke(
        app, ["centrifuge", str(run), "--repeat", str(repeat), "--report", str(report)]
    )
    assert res.exit_code == 0, res.output
    text = report.read_text()
    assert text in res.output.replace("\r", "")
    for needle in ("F crit", "R^2", "removal sequence", "t crit", "RMS before", "max after"):
        assert needle in text
    for axis in "xyz":
        assert f"AXIS {axis}" in text

    res = CliRunner().invoke(app, ["centrifuge", str(run), "--repeat", str(repeat), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["report_path"] == str(run / REPORT_NAME) and Path(doc["report_path"]).exists()
    for axis, v in doc["validation"].items():
        assert 0.2 < v["rms_before"] < 0.6, axis  # paper-like before compensation
        assert v["rms_reduction"] >= 0.65, (axis, v)
        assert v["max_after"] < v["max_before"]
        # the report's row carries the same numbers
        row = next(line for line in text.splitlines() if line.startswith(f"{axis} "))
        assert f"{v['rms_before']:.4f}" in row and f"{v['rms_after']:.4f}" in row
    for axis, m in doc["model"]["axes"].items():
        assert set(m["terms"]) == set(TRUTH[axis]), axis  # alpha 0.001 from the manifest
        assert m["F"] > m["F_crit"]
    for name in doc["parameters"]:
        params.validate(name)


def test_procedure_archives_the_high_g_terms(runs, tmp_path):
    """`calib process` path: the registered procedure solves and the archive keeps
    the cross-axis terms under their canonical names, within 4 sigma of truth."""
    run, sim = runs["run"]
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    outcome = process_run(RunSource(run, "manifest"), arch)
    assert outcome["status"] == "ok", outcome["error"]
    got = outcome["parameters"]
    assert set(got) == {canonical_name(a, t) for a, terms in TRUTH.items() for t in terms}
    for i, (axis, terms) in enumerate(TRUTH.items()):
        for term, value in terms.items():
            # the bias of this run is the model's constant plus its turn-on offset
            value = value + sim.truth.run_offset[i] if term == "const" else value
            p = got[canonical_name(axis, term)]
            assert abs(p["value"] - value) < 4 * p["std"], (axis, term, p, value)


def test_bad_centrifuge_input_is_named(runs):
    _, sim = runs["run"]
    segments = {step_label(s): s.recording for s in sim.steps}
    g = 9.80665
    with pytest.raises(ValueError, match="settings.latitude_deg is required"):
        procedures.solve("centrifuge", segments, g, {})
    bad = dict(segments)
    bad["xq_step_4g"] = bad.pop("xp_step_4g")
    with pytest.raises(ValueError, match="segment 'xq_step_4g': not a centrifuge label"):
        procedures.solve("centrifuge", bad, g, {"latitude_deg": 50.0})
    rec = segments["zm_1g"]
    no_ref = dict(segments, zm_1g=type(rec)(t=rec.t, acc=rec.acc, gyr=rec.gyr, source="f.csv"))
    with pytest.raises(ValueError, match="f.csv: reference channel 'table_angle' is missing"):
        procedures.solve("centrifuge", no_ref, g, {"latitude_deg": 50.0})
    with pytest.raises(ValueError, match="scale_1g must map axes"):
        procedures.solve("centrifuge", segments, g, {"latitude_deg": 50.0, "scale_1g": {"w": 1}})


def test_one_sided_t_and_f_steering_are_settings(runs, tmp_path):
    """--t-test one-sided: t crit is t(1 - alpha, n - p), not t(1 - alpha/2); both settings
    are recorded and printed; a bad value is refused naming the allowed ones."""
    from calib_core.distributions import t_ppf

    run, _ = runs["run"]
    args = ["centrifuge", str(run), "--report", str(tmp_path / "r.txt"), "--json"]
    res = CliRunner().invoke(app, [*args, "--t-test", "one-sided", "--steer", "F"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["settings"]["t_test"] == "one-sided" and doc["settings"]["steer"] == "F"
    for m in doc["model"]["axes"].values():
        # alpha 0.001 from the manifest; p = the kept columns (constant, terms, phi_h)
        assert m["t_crit"] == pytest.approx(float(t_ppf(1 - 0.001, m["n"] - len(m["t"]))))
    assert "one-sided t test, reduction steered by F" in (tmp_path / "r.txt").read_text()
    bad = CliRunner().invoke(app, [*args, "--t-test", "one"])
    assert bad.exit_code == 2 and "t_test must be one of" in bad.output
