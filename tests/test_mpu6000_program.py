"""The MPU-6000 program's defaults: local gravity by Helmert's
formula with the height correction from the lab's site, the standard value only with a
warning; stage 1 (six orientations) and stage 2 (six rotations) as runs of their own; the
protocol in the manual's names and signs."""

from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from calib_core import conditions
from calib_core.calibration import Calibration
from calib_core.earth import gravity_helmert, gravity_wgs84
from calib_core.params import MANUAL_NAMES
from calib_core.solvers.six_position import accel_closed_form
from calib_core.tolerances import ToleranceProfile
from calib_core.units import DEG, STANDARD_GRAVITY
from calib_testing.documents import parameter_protocol
from pipelines.ingest import IngestError, discover_runs, load_run
from pipelines.process import process_run
from pipelines.reports.display import shown
from storage.db import resolve_archive

SAMPLE = Path(__file__).resolve().parents[1] / "data_samples" / "mpu6000_MPU0001"
TRUTH = json.loads((SAMPLE / "MPU0001_truth.json").read_text())["parameters"]
STATICS = ("x_up", "x_dn", "y_up", "y_dn", "z_up", "z_dn")
ROTATIONS = ("x_ccw", "x_cw", "y_ccw", "y_cw", "z_ccw", "z_cw")


@pytest.fixture(autouse=True)
def _no_lab_file(monkeypatch, tmp_path):
    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path / "profiles"))  # empty: shipped only


def _folder(tmp_path: Path, labels: tuple[str, ...]) -> Path:
    folder = tmp_path / "run"
    folder.mkdir(parents=True)
    for label in labels:
        shutil.copy(SAMPLE / f"MPU0001_{label}.txt", folder)
    return folder


def _process(folder: Path, tmp_path: Path) -> dict:
    """Process the one run in `folder` into a fresh archive; its `calib process` entry."""
    archive = resolve_archive(str(tmp_path / "archive"))
    archive.upgrade()
    outcome = process_run(discover_runs([folder])[0], archive)
    archive.dispose()
    assert outcome["status"] == "ok", outcome["error"]
    return outcome


def _within_4u(outcome: dict, prefix: tuple[str, ...]) -> list[str]:
    names = [n for n in outcome["parameters"] if n.startswith(prefix) and ".noise." not in n]
    for name in names:
        p = outcome["parameters"][name]
        assert abs(p["value"] - TRUTH[name]) <= 4 * p["std"], (name, p, TRUTH[name])
    return names


def test_stage_1_alone_is_a_six_position_run(tmp_path):
    outcome = _process(_folder(tmp_path, STATICS), tmp_path)
    names = _within_4u(outcome, ("acc.",))
    assert len(names) == 12 and "gyr.bias.x" in outcome["parameters"]
    assert not any(n.startswith(("gyr.scale", "gyr.misalign")) for n in outcome["parameters"])
    gravity = {c["name"]: c for c in outcome["checks"]}["condition:gravity"]
    # no site known: the standard value, with a warning that leaves the verdict alone
    assert gravity["value"] == STANDARD_GRAVITY and gravity["status"] == conditions.WARNING


def test_stage_2_alone_is_an_integral_run(tmp_path):
    outcome = _process(_folder(tmp_path, ROTATIONS), tmp_path)
    names = _within_4u(outcome, ("gyr.",))
    assert sorted(names) == sorted(
        [f"gyr.scale.{a}" for a in "xyz"]
        + [f"gyr.misalign.{r}{c}" for r in "xyz" for c in "xyz" if r != c]
    )
    loaded = load_run(discover_runs([_folder(tmp_path / "again", ROTATIONS)])[0])
    assert loaded.manifest.run.procedure == "integral"


def test_an_incomplete_stage_names_its_missing_files(tmp_path):
    folder = _folder(tmp_path, STATICS[:5] + ROTATIONS[:1])
    with pytest.raises(IngestError, match=r"of stages 1 and 2; missing MPU0001_z_dn.txt"):
        load_run(discover_runs([folder])[0])
    only = _folder(tmp_path / "b", STATICS[1:])
    with pytest.raises(
        IngestError,
        match=r"5 of the 6 .* stage 1 \(orientations\); missing "
        r"MPU0001_x_up.txt$",
    ):
        load_run(discover_runs([only])[0])


def test_helmert_gravity_from_the_lab_file(tmp_path, monkeypatch):
    """The manual: Helmert's formula with the free-air correction -3.086e-6 m/s^2 per metre."""
    profiles = tmp_path / "lab"
    profiles.mkdir()
    (profiles / "lab.toml").write_text("[site]\nlatitude_deg = 55.75\nheight_m = 150.0\n")
    monkeypatch.setenv("CALIB_PROFILES", str(profiles))
    outcome = _process(_folder(tmp_path, STATICS), tmp_path)
    g = gravity_helmert(55.75, 150.0)
    # the formula worked by hand (cos 111.5 deg = -0.366501), and WGS84 within 1e-4 m/s^2
    assert g == pytest.approx(9.815183, abs=1e-6)
    assert abs(g - gravity_wgs84(55.75, 150.0)) < 1e-4
    check = {c["name"]: c for c in outcome["checks"]}["condition:gravity"]
    assert check["value"] == pytest.approx(g, abs=1e-12) and check["status"] == "pass"
    # the archived run says where the site came from
    loaded = load_run(discover_runs([_folder(tmp_path / "x", STATICS)])[0])
    assert loaded.manifest.site.from_file == str(profiles / "lab.toml")
    assert loaded.manifest.gravity() == pytest.approx(g, abs=1e-12)
    (profiles / "lab.toml").write_text("[site]\nlatitude_deg = '55'\nheight_m = 1\n")
    with pytest.raises(IngestError, match=r"site.latitude_deg: expected a number"):
        load_run(discover_runs([_folder(tmp_path / "y", STATICS)])[0])


def test_manifest_latitude_means_helmert_unless_a_model_is_named():
    from pipelines.ingest.manifest import SiteSpec

    assert SiteSpec(latitude_deg=48.0, height_m=500.0).model == "helmert"
    assert SiteSpec().model == "standard" and SiteSpec().source() is None
    assert SiteSpec(latitude_deg=48.0, gravity_model="standard").source() is None
    assert "wgs84" in SiteSpec(latitude_deg=48.0, gravity_model="wgs84").source()


# --- the manual's names and signs in the protocol (item 4) ----------------------------------

# The manual's parameters of one unit (docs/methods.md 1 sign convention), chosen distinct.
MANUAL = {
    "Axx": 0.011,
    "Ayy": -0.021,
    "Azz": 0.015,
    "Axz": 0.004,
    "Axy": 0.003,
    "Ayz": -0.002,
    "Ayx": 0.0012,
    "Azy": 0.005,
    "Azx": -0.006,
}
A0 = np.array([0.12, -0.21, 0.33])  # a0x, a0y, a0z, m/s^2


def _manual_means(g: float) -> dict[str, np.ndarray]:
    """Per-position means from the manual's own model equations (docs/methods.md 1)."""
    m = MANUAL

    def output(f):
        ax, ay, az = f
        return A0 + np.array(
            [
                (1 + m["Axx"]) * ax + m["Axz"] * ay - m["Axy"] * az,
                -m["Ayz"] * ax + (1 + m["Ayy"]) * ay + m["Ayx"] * az,
                m["Azy"] * ax - m["Azx"] * ay + (1 + m["Azz"]) * az,
            ]
        )

    axes = {"x": 0, "y": 1, "z": 2}
    return {
        f"{a}_{s}": output(np.eye(3)[axes[a]] * (g if s == "up" else -g))
        for a in "xyz"
        for s in ("up", "dn")
    }


def _protocol(cal: Calibration, names: str) -> str:
    return parameter_protocol([cal.parameters[n] for n in sorted(cal.parameters)], names)


def test_protocol_prints_the_manuals_names_and_signs():
    """The manual's numbers through its closed form (docs/methods.md 2.1) and back out of the
    protocol under the manual's names: each equal to the number put in, sign included;
    its protocol's noise line `Gstdx = 0,02089` (deg/s) reads back as Gstdx too."""
    g = 9.81
    canonical = accel_closed_form(_manual_means(g), g)
    cal = Calibration("six_position", g)
    for name, value in canonical.items():
        cal.add(name, value, 1e-6)
    cal.add("gyr.noise.x", 0.02089 * DEG, 1e-4 * DEG)
    cal.add("gyr.gsens.xy", 0.0512 * DEG / STANDARD_GRAVITY, 1e-5)  # Gaxy, (deg/s)/g
    text = _protocol(cal, "manual")
    found = {}
    for line in text.splitlines():
        m = re.match(r"(\S+)\s.*\s([AG][a-z0-9]+)\s+([+-]\d+\.\d+)$", line)
        if m:
            found[m.group(2)] = (m.group(1), float(m.group(3)))
    for name, value in MANUAL.items():
        assert found[name][1] == pytest.approx(value, abs=1e-6), name
    # the misalignments whose manual sign differs: Axy = -M[x,z], Ayz = -M[y,x], Azx = -M[z,y]
    assert found["Axy"][0] == "acc.misalign.xz" and canonical["acc.misalign.xz"] < 0 < MANUAL["Axy"]
    assert found["Ayz"][0] == "acc.misalign.yx" and found["Azx"][0] == "acc.misalign.zy"
    assert found["Gstdx"] == ("gyr.noise.x", pytest.approx(0.02089, abs=1e-6))
    assert found["Gaxy"] == ("gyr.gsens.xy", pytest.approx(0.0512))
    # canonical protocol: no manual column; the rest of each line unchanged
    plain = _protocol(cal, "canonical")
    assert "Manual" not in plain and " Axz " not in plain
    for line in plain.splitlines():
        if line.startswith("acc.misalign.xy"):
            assert next(x for x in text.splitlines() if x.startswith(line.rstrip()))
    assert [m for m, _ in MANUAL_NAMES.values()] == PUBLISHED


# The 39 lines of the manual's published protocol, gyro block first, in the order of its
# tolerance list (docs/methods.md 4.3): written out here, not derived from the code.
PUBLISHED = [
    "Gxx",
    "Gyy",
    "Gzz",
    "Gxz",
    "Gxy",
    "Gyz",
    "Gyx",
    "Gzy",
    "Gzx",
    "Gox",
    "Goy",
    "Goz",
    "Gaxx",
    "Gaxy",
    "Gaxz",
    "Gayx",
    "Gayy",
    "Gayz",
    "Gazx",
    "Gazy",
    "Gazz",
    "Gstdx",
    "Gstdy",
    "Gstdz",
    "Axx",
    "Ayy",
    "Azz",
    "Axz",
    "Axy",
    "Ayz",
    "Ayx",
    "Azy",
    "Azx",
    "Aox",
    "Aoy",
    "Aoz",
    "Astdx",
    "Astdy",
    "Astdz",
]


def test_the_programs_unit_prints_the_39_lines_of_the_published_protocol(tmp_path):
    """The program's own unit (raw files as the program writes them) through `calib
    process` with the shipped mpu6000 profile: its protocol prints the 39 names of the
    published protocol in their order, gyro block first, each value in the manual's sign
    within 4 u of the unit's truth, and `+` on every line that has a tolerance."""
    outcome = _process(_folder(tmp_path, STATICS + ROTATIONS), tmp_path)
    text = outcome["protocol"]
    text = Path(text).read_text(encoding="utf-8") if Path(text).is_file() else text
    rows = []
    lines = text.splitlines()
    table = lines[lines.index(next(x for x in lines if x.startswith("Parameter "))) + 1 :]
    for line in table[: table.index("-" * 78)]:
        words = line.split()
        if re.match(r"[a-z]+\.[a-z]+\.[a-z]+$", line[:18].strip()) and len(words) > 4:
            mark = words[-3] if words[-3] in ("+", "-") else ""
            rows.append((words[0], mark, words[-2], words[-1]))
    assert [r[2] for r in rows] == PUBLISHED, text
    for canonical, mark, manual, value in rows:
        sign = -1.0 if manual in ("Axy", "Ayz", "Azx", "Gxy", "Gyz", "Gzx") else 1.0
        p = outcome["parameters"][canonical]
        shown_value = shown(canonical, sign * p["value"], p["std"])
        assert value == shown_value.signed, (manual, value)
        if ".noise." not in canonical:
            assert abs(p["value"] - TRUTH[canonical]) <= 4 * p["std"], (canonical, p)
        if canonical.startswith("acc.noise"):
            assert mark == "", manual  # the paper gives the accelerometer noise no tolerance
        else:
            assert mark == "+", manual


def test_protocol_names_setting_of_the_profile():
    doc = {"name": "p", "version": "1", "device_model": "M"}
    assert ToleranceProfile.from_dict(doc).protocol_names == "canonical"
    manual = ToleranceProfile.from_dict({**doc, "protocol": {"names": "manual"}})
    assert ToleranceProfile.from_dict(manual.to_dict()).protocol_names == "manual"
    with pytest.raises(
        ValueError, match=r"protocol.names must be one of 'canonical', 'manual', got 'russian'"
    ):
        ToleranceProfile.from_dict({**doc, "protocol": {"names": "russian"}})
    assert math.isfinite(STANDARD_GRAVITY)


def test_a_warming_unit_in_tolerance_passes(tmp_path):
    """The program's own unit (the sample's truth and noise) with its sensor warming by
    0.4 deg C over the run's three minutes, as a powered MPU-6000 does: every parameter in
    tolerance, so the verdict is pass (the statics alone span 0.26 deg C, which the 0.2 deg C
    rule failed when it judged the sensor). That rule belongs to the static-bias run's
    chamber temperature; the sensor's trend is shown as information."""
    import dataclasses

    from calib_core.simulate.lab_run import random_errors, six_position_integral_run
    from calib_testing.run_writers import write_mpu6000_run

    rng = np.random.default_rng(20261120)  # scripts/make_data_samples.py's MPU0001
    truth = dataclasses.replace(random_errors(rng), gyr_noise=np.full(3, 0.03 * DEG))
    sim = six_position_integral_run(truth, rng)
    total = sum(rec.duration for rec in sim.segments.values())
    start, warm, warming = 0.0, 0.4, {}  # deg C over the run
    for label, rec in sim.segments.items():  # the records follow one another
        temp = rec.temp + warm * (start + rec.t - rec.t[0]) / total
        warming[label] = dataclasses.replace(rec, temp=temp)
        start += rec.duration
    folder = tmp_path / "run"
    write_mpu6000_run(warming, folder, "MPU0009", truth=sim.truth_dict())
    outcome = _process(folder, tmp_path)
    checks = {c["name"]: c for c in outcome["checks"]}
    trend = checks["condition:sensor_temperature_spread_c"]
    # the 1-s means of the printed 0.1 deg C steps: the ramp within a display step
    assert 0.3 < trend["value"] <= warm + 0.1 and trend["status"] == conditions.INFO
    assert "condition:static_temperature_spread_c" not in checks
    assert outcome["verdict"] == "pass", [c for c in outcome["checks"] if not c["passed"]]
