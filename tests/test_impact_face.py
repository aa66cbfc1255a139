"""`calib impact` for a cube face that is not square (docs/impact.md): a unit simulated on a
cube whose -x face's normal is tilted, archived by the real pipeline into a real SQLite
file with the nominal (square) reference, then re-solved from its raw bytes with the
face's true direction."""

from __future__ import annotations

import copy
import json
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from calib_core.procedures.six_position import solve_six_position_integral
from calib_core.reference_errors import correct_segments, parse_error
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.solvers.six_position import UP_CHANNEL, nominal_up
from calib_core.units import ARCSEC, STANDARD_GRAVITY
from calib_testing.run_writers import six_position_manifest, write_csv_run
from pipelines.cli import app
from pipelines.impact import impact
from pipelines.ingest import discover_runs
from pipelines.ingest.run_loader import read_run
from pipelines.process import calibrate, process_run
from storage import queries
from storage.db import resolve_archive
from storage.verify import verify

E_ARCSEC = 60.0
THETA = E_ARCSEC * ARCSEC  # the -x face's normal, rotated about y
G = STANDARD_GRAVITY
STATIC_S, RATE_HZ = 20.0, 50.0
N_STATIC = STATIC_S * RATE_HZ  # samples per static position


def _rot_y(a: float) -> np.ndarray:
    """Right-handed rotation about y, written out here (not the module's) on purpose."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


# Face -x rests down in x_up and in the rotations about x (made with x up).
TRUE_UP = {k: _rot_y(THETA) @ nominal_up(k) for k in ("x_up", "x_ccw", "x_cw")}


def _manifest(serial: str, started: str, cube: str) -> dict:
    m = six_position_manifest(serial, started=started)
    m["equipment"] = [
        {"kind": "cube", "model": "CUBE-90", "serial": cube, "calibration_due": "2027-01-01"}
    ]
    return m


def _with_true_up(segments: dict) -> dict:
    """The segments with the true reference direction, set here from the truth."""
    return {
        k: replace(r, reference={**r.reference, UP_CHANNEL: np.tile(TRUE_UP[k], (len(r), 1))})
        if k in TRUE_UP
        else r
        for k, r in segments.items()
    }


@pytest.fixture(scope="module")
def cube_lab(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("impact_face")
    arch = resolve_archive(str(tmp / "archive"))
    arch.upgrade()
    rng = np.random.default_rng(11)
    truth = copy.deepcopy(random_errors(rng))
    sim = six_position_integral_run(truth, rng, static_s=STATIC_S, rate_hz=RATE_HZ, true_up=TRUE_UP)
    manifest = _manifest("U-CUBE", "2026-04-02T09:00:00+00:00", "CB-1")
    write_csv_run(dict(sim.segments), tmp / "F", manifest)
    (source,) = discover_runs([tmp / "F"])
    outcome = process_run(source, arch)
    assert outcome["status"] == "ok", outcome["error"]
    return {"archive": arch, "run_id": outcome["run_id"], "tmp": tmp, "truth": truth, "sim": sim}


def test_face_error_syntax_is_one_well_defined_error():
    e = parse_error("face_angle_error_arcsec[-x,y]=60")
    assert (e.quantity, e.value, e.face, e.about) == ("face_angle_error_arcsec", 60.0, "-x", "y")
    assert str(e) == "face_angle_error_arcsec[-x,y]=60"
    for text, message in (
        ("face_angle_error_arcsec=60", "needs the face and the axis"),
        ("face_angle_error_arcsec[+x]=60", "needs the face and the axis"),
        ("face_angle_error_arcsec[x,y]=60", "face 'x'"),
        ("face_angle_error_arcsec[+x,w]=60", "axis 'w'"),
        ("face_angle_error_arcsec[+x,x]=60", "about its own normal"),
        ("face_angle_error_arcsec[+x,y]=7200", "beyond"),
        ("rate_error_ppm[+x,y]=5", "takes no"),
    ):
        with pytest.raises(ValueError, match=message.replace("[", r"\[")):
            parse_error(text)


def test_face_positions_and_unlabelled_runs():
    rng = np.random.default_rng(0)
    sim = six_position_integral_run(random_errors(rng), rng, static_s=2.0)
    out, stats = correct_segments(sim.segments, parse_error("face_angle_error_arcsec[+z,x]=30"))
    assert stats["affected"] and "z_dn" in stats["what"]
    assert [k for k in out if UP_CHANNEL in out[k].reference] == ["z_dn"]
    up = out["z_dn"].reference[UP_CHANNEL][0]
    # +z face's normal rotated by +30" about x: z_dn's up (0, 0, -1) tilts towards +y.
    assert up == pytest.approx([0.0, np.sin(30 * ARCSEC), -np.cos(30 * ARCSEC)], abs=1e-15)
    whole = {"log": replace(sim.segments["x_up"], label=None)}
    with pytest.raises(ValueError, match="automatic segmentation"):
        correct_segments(whole, parse_error("face_angle_error_arcsec[+z,x]=30"))


def test_multi_position_reads_the_true_face_direction():
    """multi_position's face-labelled positions take the corrected direction too."""
    from calib_core.solvers.multi_position import SETTINGS, reference_force

    rng = np.random.default_rng(2)
    sim = six_position_integral_run(random_errors(rng), rng, static_s=2.0)
    error = parse_error(f"face_angle_error_arcsec[-x,y]={E_ARCSEC}")
    out, _ = correct_segments(sim.segments, error)
    s = SETTINGS.parse({})
    got = reference_force("x_up", out["x_up"], G, s)
    assert got == pytest.approx(G * TRUE_UP["x_up"], abs=1e-12)
    assert reference_force("y_up", out["y_up"], G, s) == pytest.approx([0.0, G, 0.0], abs=0)


def test_closed_form_refuses_a_tilted_face():
    rng = np.random.default_rng(1)
    sim = six_position_integral_run(random_errors(rng), rng, static_s=2.0, true_up=TRUE_UP)
    with pytest.raises(ValueError, match="closed_form assumes square cube faces"):
        solve_six_position_integral(
            _with_true_up(dict(sim.segments)), G, {"accel_solver": "closed_form"}
        )


def test_face_error_re_solve_matches_the_true_reference(cube_lab):
    """The re-solve from the archived bytes equals a direct solve with the true reference;
    the nominal solve differs from it by what a tilted reference predicts; the truth is
    within the noise of the corrected solve."""
    arch, run_id = cube_lab["archive"], cube_lab["run_id"]
    error = parse_error(f"face_angle_error_arcsec[-x,y]={E_ARCSEC}")
    doc = impact(arch, "CB-1", error, "2026-04-01")
    (r,) = doc["runs"]
    assert r["run_id"] == run_id and r["affected"]
    assert "x_up, x_ccw, x_cw" in r["what"]
    loaded = read_run(cube_lab["tmp"] / "F")
    direct = calibrate(replace(loaded, segments=_with_true_up(loaded.segments)))
    nominal = calibrate(loaded)
    moved = {m["name"]: m for m in r["moved"]}
    truth = cube_lab["truth"].parameters()
    M_zz = truth["acc.scale.z"]
    # What the tilt does to a fit that assumed a square face (first order in THETA):
    # x_up's z reading carries -(1 + M_zz) g THETA, which the six-position least squares
    # splits into acc.misalign.zx (half of it over the x pair) and acc.bias.z (a sixth:
    # one of three pairs); the x rotations turn about the tilted normal, so the integral
    # method's column x of the gyro carries -THETA in z.
    expected = {
        "acc.misalign.zx": (1 + M_zz) * THETA / 2,
        "acc.bias.z": (1 + M_zz) * G * THETA / 6,
        "gyr.misalign.zx": (1 + truth["gyr.scale.z"]) * THETA,
    }
    for name, shift in expected.items():
        std = direct.parameters[name].std
        assert moved[name]["before"] == pytest.approx(nominal.value(name), abs=1e-6 * std)
        # the re-solve from the archive is the direct solve with the true reference
        assert abs(moved[name]["after"] - direct.value(name)) <= 1e-3 * std, name
        # The fit weighs each position by 1 / sem, estimated from N_STATIC samples: the
        # split departs from equal weights by their relative sampling error.
        got = moved[name]["after"] - moved[name]["before"]
        assert abs(got - shift) <= 4 * abs(shift) / np.sqrt(2 * N_STATIC), (name, got, shift)
        assert abs(moved[name]["after"] - truth[name]) <= 4 * std, name  # the noise's bound
        # The shift is beyond the noise (this test tells a corrected solve from a nominal
        # one), and is reported in units of the archived U (with the cube's Type B).
        assert abs(shift) > 2 * std, (name, shift, std)
        m = moved[name]
        assert m["change_in_U"] == pytest.approx((m["after"] - m["before"]) / m["U_before"])
    for name in ("acc.scale.x", "acc.scale.y", "gyr.scale.y", "acc.bias.y"):
        assert name not in moved or abs(moved[name]["change_in_U"]) < 0.5, moved.get(name)


def test_face_error_apply_and_json(cube_lab):
    arch, run_id = cube_lab["archive"], cube_lab["run_id"]
    error = f"face_angle_error_arcsec[-x,y]={E_ARCSEC:g}"
    res = CliRunner().invoke(
        app,
        ["impact", "CB-1", "--from", "2026-04-01", "--error", error, "--apply", "--json",
         "--archive", str(arch.root)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert [(r["run_id"], r["verdict_before"], r["status"]) for r in doc["runs"]] == [
        (run_id, doc["runs"][0]["verdict_before"], "revised")
    ]
    assert doc["error"]["face"] == "-x" and doc["error"]["about"] == "y"
    lin = queries.lineage(arch, run_id, "acc.misalign.zx")
    steps = {s["name"]: s for s in lin["steps"]}
    assert steps["reprocess"]["settings"]["reason"] == f"out-of-tolerance reference CB-1: {error}"
    corr = steps["reference_correction"]["settings"]
    assert (corr["quantity"], corr["face"], corr["about"]) == ("face_angle_error_arcsec", "-x", "y")
    assert verify(arch).ok
