"""`calib navfit RUN --profile ...` (docs/navigation.md): a simulated static-bias run archived
by the real pipeline into a real SQLite file, its navigation performance printed by the CLI;
mission-profile files and trajectory CSVs read as a lab would write them."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from calib_core.navigation import Z95
from calib_core.simulate.noise import NoiseSpec, simulate_static
from calib_testing.archives import new_archive, processed_run, static_bias_archive
from pipelines import navigation
from pipelines.cli import app

GYR_N, GYR_B, GYR_K = 2.0e-4, 2.0e-5, 2.0e-6  # rad/s/sqrt(Hz), rad/s, rad/s^2/sqrt(Hz)
ACC_N, ACC_B, ACC_K = 2.0e-3, 1.0e-4, 3.0e-5  # m/s^2/sqrt(Hz), m/s^2, m/s^3/sqrt(Hz)


@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    rec = simulate_static(
        1800.0,
        50.0,
        gyro_bias=np.array([1e-3, -2e-3, 5e-4]),
        gyro_noise=NoiseSpec(GYR_N, GYR_B, GYR_K),
        acc_noise=NoiseSpec(ACC_N, ACC_B, ACC_K),
        rng=np.random.default_rng(50),
    )
    return static_bias_archive(tmp_path_factory.mktemp("navfit"), rec, "NAV-0050")


def _navfit(archive, *args: str):
    return CliRunner().invoke(app, ["navfit", *args, "--archive", str(archive.root)])


def test_navfit_json_on_a_static_bias_run(static_run, tmp_path):
    archive, run_id = static_run
    plot = tmp_path / "nav.png"
    res = _navfit(
        archive, run_id[:8], "--profile", "land-vehicle-outage-60s", "--json", "--plot", str(plot)
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["run_id"] == run_id and doc["procedure"] == "static_bias"
    assert doc["profile"]["outage_start_s"] == 300.0 and doc["profile"]["duration_s"] == 360.0
    end = doc["end"]
    for key in ("heading_deg", "roll_deg", "pitch_deg", "vertical_position_m"):
        assert end[key]["p95"] == pytest.approx(Z95 * end[key]["sigma"], rel=1e-9)
    # the 2-D 95 % radius lies between a line's 1.96 and a circle's 2.45 sigma-per-axis
    h = end["horizontal_position_m"]
    assert Z95 * h["sigma"] / math.sqrt(2) < h["p95"] <= 2.4478 * h["sigma"] / math.sqrt(2) * 1.0001
    # the static-bias run's sources: bias uncertainties and the Allan terms
    assert {"gyr.bias", "acc.bias", "gyr.arw", "acc.vrw", "gyr.rrw"} <= set(doc["error_sources"])
    for key, shares in doc["shares"].items():
        assert sum(shares.values()) == pytest.approx(1.0, abs=1e-5), key
        assert doc["dominant"][key] == max(shares, key=shares.get)
    # a 60 s outage of a MEMS unit: the horizontal error grows past 10 m within the outage
    t = doc["time_to_limit_s"]
    assert t is not None and 0 < t < 60
    series = doc["series"]
    assert series["t_s"][-1] == 360.0 and len(series["heading_deg"]["sigma"]) == len(series["t_s"])
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not any("noise" in n for n in doc["notes"])  # the sample stds are the Allan terms'


def test_navfit_table_names_the_dominant_source(static_run):
    archive, run_id = static_run
    res = _navfit(archive, run_id, "--profile", "static-alignment", "--limit", "50")
    assert res.exit_code == 0, res.output
    assert "dominant:" in res.stdout and "time to 50 m horizontal" in res.stdout


def test_unknown_profile_and_bad_file_are_refused(static_run, tmp_path):
    archive, run_id = static_run
    res = _navfit(archive, run_id, "--profile", "boat")
    assert res.exit_code == 2 and "land-vehicle-outage-60s" in res.output
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nduration_s = 10\n[trajectory]\nsegments = [{duration_s = -1}]\n')
    res = _navfit(archive, run_id, "--profile", str(bad))
    assert res.exit_code == 2
    assert (
        "bad.toml" in res.output
        and "trajectory.segments[0].duration_s: expected a positive number, got -1.0" in res.output
    )


def test_trajectory_csv_gives_the_segments_result(tmp_path):
    """A straight drive given as a CSV (the lab's own trajectory) and as segments: one
    motion, so one covariance (finite differences of the sampled positions against the
    integrated segments: agreement to 1e-3)."""
    seg = tmp_path / "seg.toml"
    common = (
        "duration_s = 120.0\nstep_s = 0.5\n[initial]\nattitude_deg = [0.5, 0.5, 2.0]\n"
        '[aiding]\nkind = "none"\n'
    )
    seg.write_text(
        'name = "seg"\n' + common + "[trajectory]\nheading_deg = 90.0\n"
        "segments = [{duration_s = 10.0, forward_accel_mps2 = 1.0}, {duration_s = 110.0}]\n"
    )
    ts = np.arange(0.0, 120.05, 0.05)
    east = np.where(ts < 10, 0.5 * ts**2, 50.0 + 10.0 * (ts - 10))
    rows = ["t_s,north_m,east_m,down_m,roll_deg,pitch_deg,yaw_deg"]
    rows += [f"{t:.2f},0,{e:.6f},0,0,0,90" for t, e in zip(ts, east, strict=True)]
    (tmp_path / "track.csv").write_text("\n".join(rows) + "\n")
    csv_file = tmp_path / "csv.toml"
    csv_file.write_text('name = "csv"\n' + common + '[trajectory]\nfile = "track.csv"\n')
    from calib_core.navigation import error_model, propagate

    model = error_model({"acc.bias.x": 1e-2, "gyr.scale.z": 1e-3, "acc.scale.y": 1e-3})
    a = propagate(navigation.load_profile(str(seg)), model).sigma()[-1]
    b = propagate(navigation.load_profile(str(csv_file)), model).sigma()[-1]
    assert np.allclose(a, b, rtol=1e-3, atol=1e-9)
    (tmp_path / "track.csv").write_text(rows[0] + "\n0,0,0,0,0,0,x\n")
    with pytest.raises(ValueError, match=r"track.csv, line 2: expected 7 numbers"):
        navigation.load_profile(str(csv_file))


def test_every_builtin_profile_loads():
    assert navigation.builtin_names() == [
        "land-vehicle",
        "land-vehicle-outage-60s",
        "multicopter-flight",
        "static-alignment",
    ]
    for name in navigation.builtin_names():
        prof = navigation.load_profile(name)
        assert prof.name == name and prof.trajectory.duration >= prof.duration


def test_thermal_residual_over_the_profile(tmp_path):
    """The residual of a thermal model: its curve's uncertainty, the largest over the
    profile's temperatures (at an end of the range); a profile beyond the model's range noted."""
    from calib_core.thermal import ThermalPoint, fit_model

    temps = np.linspace(-10.0, 50.0, 7)
    rng = np.random.default_rng(5)
    pts = {
        "gyr.bias.x": [
            ThermalPoint(float(t), 1e-3 + 2e-5 * (t - 25) + 1e-5 * rng.standard_normal())
            for t in temps
        ]
    }
    tm = fit_model(pts, t_ref=25.0)
    prof = navigation.load_profile("land-vehicle")  # 0..40 deg C: inside
    res, notes = navigation.thermal_residuals(tm.to_dict(), prof)
    ends = [float(tm.std("gyr.bias.x", t)) for t in (0.0, 40.0)]
    assert res["gyr.bias.x"] == pytest.approx(max(ends), rel=1e-12) and not notes
    hot = tmp_path / "hot.toml"
    text = navigation.find_profile("land-vehicle").read_text()
    hot.write_text(text.replace("temperature_c = [0.0, 40.0]", "temperature_c = [20.0, 70.0]"))
    res, notes = navigation.thermal_residuals(tm.to_dict(), navigation.load_profile(str(hot)))
    assert notes and "-10..50 deg C" in notes[0]


def test_the_sample_static_bias_run(tmp_path):
    """The acceptance command on data_samples/static_bias_IMU-N-0011: the figures and the
    dominant source printed as JSON."""
    from serve_sample import DATA_SAMPLES

    archive = new_archive(tmp_path)
    run_id = processed_run(DATA_SAMPLES / "static_bias_IMU-N-0011", archive)
    res = _navfit(archive, run_id, "--profile", "land-vehicle-outage-60s", "--json")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    h = doc["end"]["horizontal_position_m"]
    assert h["sigma"] > 0 and h["p95"] > h["sigma"]
    assert doc["dominant"]["horizontal_position_m"] in doc["error_sources"]


LAB = """
[laboratory]
name = "Nav Lab"
address = "Somewhere 1"

[navigation]
profiles = [{names}]
"""


def test_certificate_section_when_the_lab_names_profiles(static_run, tmp_path, monkeypatch):
    from calib_testing.documents import html_words, pdf_pages
    from pipelines.reports.render import render_html
    from pipelines.reports.run_reports import certificate_of
    from pipelines.reports.typeset import render_pdf

    archive, run_id = static_run
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    monkeypatch.setenv("CALIB_PROFILES", str(profiles))
    _, cert = certificate_of(archive, run_id)  # no lab.toml: no section
    assert not [s for s in cert.sections if s.title.startswith("Navigation performance")]
    (profiles / "lab.toml").write_text(LAB.format(names='"land-vehicle-outage-60s"'))
    summary, cert = certificate_of(archive, run_id)
    (section,) = [s for s in cert.sections if s.title.startswith("Navigation performance")]
    assert section.title == "Navigation performance: land-vehicle-outage-60s"
    (data,) = summary.navigation
    heading = next(r for r in section.rows if r[0] == "heading")
    assert heading[1] == f"{data['end']['heading_deg']['sigma']:.3g}"
    assert data["dominant"]["heading_deg"] in heading[4]
    words = " ".join(html_words(render_html(cert)))
    assert "Navigation performance: land-vehicle-outage-60s" in words
    pdf = render_pdf(cert, tmp_path / "cert.pdf")
    assert any("Navigation performance" in page for page in pdf_pages(pdf))
    (profiles / "lab.toml").write_text(LAB.format(names='"boat"'))
    with pytest.raises(ValueError, match=r"navigation.profiles\[0\]: no mission profile 'boat'"):
        certificate_of(archive, run_id)
