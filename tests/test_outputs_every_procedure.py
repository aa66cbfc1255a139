"""Every procedure's outputs, as a lab hands them out: one archived run of each of the nine
procedures (the samples of data_samples/ and simulated runs of the other procedures, written as
lab files and archived by the real pipeline into a real SQLite file) gets its certificate
issued (HTML and PDF, read back with pdftotext) and a DCC that PTB's DCC 3.3.0 schema accepts
(lxml against the schema set vendored in tests/schemas)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calib_core.procedures import BY_NAME
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.simulate.array import array_session
from calib_core.simulate.attitudes import multi_position_run, scheme_angles
from calib_core.simulate.centrifuge import CentrifugeNoise, CentrifugeSchedule, simulate_centrifuge
from calib_core.simulate.handheld import accelerometer_frame, handheld_run
from calib_core.simulate.rate_table import GyroTruth, simulate_rate_table
from calib_core.solvers.sensor_array import cube_mounts
from calib_core.units import DEG
from calib_testing.documents import dcc_schema_errors, html_words, pdf_pages
from calib_testing.lab_profile import CUBE, LABORATORY, lab_toml
from calib_testing.run_writers import (
    six_position_manifest,
    write_centrifuge_run,
    write_csv_run,
)
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage.db import resolve_archive

pytestmark = pytest.mark.slow  # eleven sample runs and six simulated, certificates typeset

DATA_SAMPLES = Path(__file__).resolve().parent.parent / "data_samples"
LAB_TOML = lab_toml(
    laboratory=LABORATORY | {"country": "DE"},
    equipment=[CUBE | {"model": "Precision cube PC-100"}],
)


def _lab_run(folder: Path, serial: str, procedure: str, settings: dict, segments: dict) -> Path:
    manifest = six_position_manifest(serial)
    manifest["run"] |= {"procedure": procedure, "settings": settings}
    write_csv_run(segments, folder, manifest)
    return folder


def _simulated_runs(root: Path) -> list[Path]:
    """A run of each procedure data_samples/ has none of, small but inside its rules."""
    rng = np.random.default_rng(4747)
    truth = random_errors(rng)
    truth.gyr_noise = np.full(3, 0.03 * DEG)
    sim = six_position_integral_run(truth, rng, rate_hz=50.0, static_s=10.5)
    turns = {k: v for k, v in sim.segments.items() if not k.endswith(("_up", "_dn"))}
    multi = multi_position_run(truth, scheme_angles(12), rng, rate_hz=50.0, static_s=10.5)
    hand = handheld_run(accelerometer_frame(truth), rng, poses=20)
    gyro = GyroTruth(bias=np.array([1e-3, -2e-3, 5e-4]), M=np.diag([2e-3, -1e-3, 1.5e-3]))
    table = simulate_rate_table(
        gyro, rate_hz=100.0, settle_s=20.0, record_s=12.0, gyro_noise_density=1e-4, rng=rng
    )
    runs = [
        _lab_run(root / "integral", "P-INT", "integral", {}, turns),
        _lab_run(
            root / "multi",
            "P-MULTI",
            "multi_position",
            {"attitudes": multi.attitudes_setting()},
            multi.segments,
        ),
        _lab_run(root / "free", "P-FREE", "equipment_free", {}, {"session": hand.recording}),
        _lab_run(
            root / "rate",
            "P-RATE",
            "rate_table",
            {"settle_s": 20.0},
            {r.label: r for r in table.recordings},
        ),
    ]
    cube = array_session(truth, cube_mounts(), rng, rate_hz=100.0, static_s=40.0)
    runs.append(
        _lab_run(
            root / "array",
            "P-ARRAY",
            "sensor_array",
            {"mounts": "cube6", "segmentation": {"labels": "array"}},
            cube,
        )
    )
    centrifuge = simulate_centrifuge(
        {a: {"const": 0.1, f"a_{a}": 1e-3} for a in "xyz"},
        rng=rng,
        noise=CentrifugeNoise(scale_instability=2e-4, run_offset_std=0.02),
        schedule=CentrifugeSchedule(
            sample_rate=50.0, zero_duration=4.0, one_g_duration=20.0, step_duration=4.0
        ),
    )
    manifest = six_position_manifest("P-CENT")
    # a high-g unit (no MPU-6000 range to clip at), as tests/test_centrifuge_pipeline.py's
    manifest["unit"] = {"serial": "P-CENT", "model": "MEMS-HG", "manufacturer": "ACME"}
    manifest["run"] |= {
        "procedure": "centrifuge",
        "settings": {"latitude_deg": 50.0, "scale_1g": {a: 1e-3 for a in "xyz"}},
    }
    manifest["site"] = {"latitude_deg": 50.0, "gravity_model": "standard"}
    write_centrifuge_run(centrifuge, root / "centrifuge", manifest)
    runs.append(root / "centrifuge")
    return runs


@pytest.fixture(scope="module")
def archived(tmp_path_factory, issuing_certificates):
    """{run_id: (procedure, source folder)} of data_samples/ and the simulated runs."""
    root = tmp_path_factory.mktemp("every")
    profiles = root / "profiles"
    profiles.mkdir()
    (profiles / "lab.toml").write_text(LAB_TOML)
    archive = resolve_archive(str(root / "archive"))
    archive.upgrade()
    out = {}
    for source in discover_runs([DATA_SAMPLES, *_simulated_runs(root / "lab")]):
        outcome = process_run(source, archive)
        assert outcome["status"] == "ok", (source, outcome["error"])
        out[outcome["run_id"]] = source
    return archive, out, profiles


def test_every_procedure_has_a_run(archived):
    from storage import queries

    archive, runs, _ = archived
    done = {queries.run_summary(archive, r).procedure for r in runs}
    assert done == set(BY_NAME), set(BY_NAME) - done


def test_every_run_has_its_certificate_issued(archived):
    """HTML and PDF issued at archive time, the static-bias run's included; a noise term
    without a standard uncertainty says so."""
    from pipelines.reports.display import NO_STANDARD_U
    from pipelines.reports.issue import issued
    from storage import queries

    archive, runs, _ = archived
    for run_id in runs:
        cert = issued(archive, run_id)
        assert cert is not None, run_id
        words = " ".join(html_words(cert.files["html"].read_text(encoding="utf-8")))
        pages = pdf_pages(cert.files["pdf"])
        assert cert.number in words and all(cert.number in p for p in pages), run_id
        if queries.run_summary(archive, run_id).procedure == "static_bias":
            assert "acc.noise.x" in words and NO_STANDARD_U in words


def test_every_dcc_is_valid_against_dcc_3_3_0(archived, monkeypatch):
    from pipelines.reports.dcc import dcc_xml
    from pipelines.reports.run_reports import archived_run

    archive, runs, profiles = archived
    monkeypatch.setenv("CALIB_PROFILES", str(profiles))
    for run_id in runs:
        xml = dcc_xml(archived_run(archive, run_id))
        assert dcc_schema_errors(xml) == [], run_id


def test_the_schema_check_can_fail(archived, monkeypatch):
    """The validation the tests rely on catches each of the three faults of DCCs before 3.3.0."""
    from pipelines.reports.dcc import dcc_xml
    from pipelines.reports.run_reports import archived_run

    archive, runs, profiles = archived
    monkeypatch.setenv("CALIB_PROFILES", str(profiles))
    xml = dcc_xml(archived_run(archive, next(iter(runs)))).decode()
    assert dcc_schema_errors(xml.encode()) == []
    dangling = xml.replace('refId="method', 'refId="nowhere', 1)
    empty = (
        xml.split("<dcc:measuringEquipments>")[0]
        + "<dcc:measuringEquipments/>"
        + (xml.split("</dcc:measuringEquipments>")[1])
    )
    start = xml.index("<dcc:customer")
    loc = xml.index("<dcc:location>", start)
    nowhere = xml[:loc] + xml[xml.index("</dcc:location>", loc) + len("</dcc:location>") :]
    for broken in (dangling, empty, nowhere):
        assert broken != xml and dcc_schema_errors(broken.encode())


def test_a_dcc_without_what_the_schema_needs_is_refused(archived, monkeypatch, tmp_path):
    from pipelines.reports.dcc import DccRefusedError, dcc_xml
    from pipelines.reports.run_reports import archived_run

    archive, runs, _ = archived
    (tmp_path / "lab.toml").write_text('[customer]\nname = "X"\n')
    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path))
    with pytest.raises(DccRefusedError, match=r"add address = .* to \[customer\] of the lab"):
        dcc_xml(archived_run(archive, next(iter(runs))))
    archived = archived_run(archive, next(iter(runs)))
    archived.lab["customer"]["address"] = "here"
    with pytest.raises(DccRefusedError, match=r"\[\[equipment\]\] of run.toml\) and the lab"):
        dcc_xml(replace(archived, run=replace(archived.run, equipment=[])))
