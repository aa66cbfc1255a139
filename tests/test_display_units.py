"""Every parameter family a solver can emit has a display unit, and a centrifuge run
(high-g terms acc.k2 / acc.k3 / acc.kp) renders its certificate end to end."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_centrifuge_pipeline import SIM, TRUTH, _manifest
from typer.testing import CliRunner

from calib_core import params
from calib_core.simulate.centrifuge import simulate_centrifuge
from calib_testing.run_writers import write_centrifuge_run
from pipelines.cli import app
from pipelines.ingest import RunSource
from pipelines.process import process_run
from pipelines.reports.display import DISPLAY_UNITS, display
from pipelines.reports.run_reports import ArchivedRun, write_reports
from storage import queries
from storage.db import Archive, resolve_archive
from storage.queries.records import ParameterValue

pytestmark = pytest.mark.slow

# Every family the name grammar of calib_core.params admits, spelled out: a family
# added to the grammar without a unit, or a unit without a display, fails here.
EVERY_FAMILY = {
    f"{sensor}.{kind}"
    for sensor, kinds in (
        ("acc", ("bias", "scale", "misalign", "k2", "k3", "kp", "noise")),
        ("gyr", ("bias", "scale", "misalign", "gsens", "noise")),
    )
    for kind in kinds
}


def test_every_family_has_an_si_unit_and_a_display_unit() -> None:
    assert set(params.UNITS) == EVERY_FAMILY
    assert set(DISPLAY_UNITS) == set(params.UNITS)
    for family in EVERY_FAMILY:
        unit, factor = DISPLAY_UNITS[family]
        assert unit and factor > 0, family
    assert display("acc.kp.x_yz", 2.0) == (2.0, "1/(m/s^2)")
    assert display("gyr.bias.x", np.pi / 180) == (1.0, "deg/s")


@pytest.fixture(scope="module")
def centrifuge_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Archive, dict]:
    """A simulated centrifuge run processed into a real SQLite archive: (archive, outcome)."""
    # The products (acc.kp) are not identifiable with these mountings (the solver's
    # docstring): the run emits bias, scale, misalignment and the k2 squares.
    tmp = tmp_path_factory.mktemp("centrifuge-cert")
    sim = simulate_centrifuge(TRUTH, rng=np.random.default_rng(21), **SIM)
    write_centrifuge_run(sim, tmp / "run", _manifest(alpha=0.001))
    arch = resolve_archive(str(tmp / "archive"))
    arch.upgrade()
    outcome = process_run(RunSource(tmp / "run", "manifest"), arch)
    assert outcome["status"] == "ok", outcome["error"]
    return arch, outcome


def test_centrifuge_run_certificate_end_to_end(centrifuge_run, tmp_path: Path) -> None:
    arch, outcome = centrifuge_run
    families = {n.rsplit(".", 1)[0] for n in outcome["parameters"]}
    assert {"acc.k2", "acc.bias"} <= families, families
    out = tmp_path / "report"
    args = ["report", outcome["run_id"], "--archive", str(arch.root), "--output", str(out)]
    res = CliRunner().invoke(app, [*args, "--json"])
    assert res.exit_code == 0, res.output
    written = json.loads(res.stdout)
    html = Path(written["html"]).read_text()
    assert "acc.k2.x" in html
    assert Path(written["pdf"]).read_bytes()[:5] == b"%PDF-"


def test_certificate_shows_every_family(centrifuge_run, tmp_path: Path) -> None:
    # The centrifuge solver never identifies the products acc.kp with its six mountings,
    # so the archived run above cannot hold one; its archived summary, given one
    # parameter of every family of the name grammar (acc.kp.x_yz among them), must
    # still render (a family missing from the display table raised KeyError here).
    arch, outcome = centrifuge_run
    summary = queries.run_summary(arch, outcome["run_id"])
    example = {"acc.kp": "acc.kp.x_yz", "acc.misalign": "acc.misalign.xy"}
    example |= {"gyr.misalign": "gyr.misalign.xy", "gyr.gsens": "gyr.gsens.xy"}
    names = [example.get(family, f"{family}.x") for family in sorted(params.UNITS)]
    values = [ParameterValue(params.validate(n), 1e-3, 1e-4, "", None) for n in names]
    given = replace(summary, calibration=replace(summary.calibration, parameters=values))
    samples = queries.run_samples(arch, outcome["run_id"])
    written = write_reports(ArchivedRun(given), samples, tmp_path / "r")
    html = written["html"].read_text()
    for name in names:
        unit = DISPLAY_UNITS[name.rsplit(".", 1)[0]][0]
        assert f"<td>{name}</td>" in html and unit.replace("^", "") in html.replace("^", ""), name
    assert written["pdf"].read_bytes()[:5] == b"%PDF-"
