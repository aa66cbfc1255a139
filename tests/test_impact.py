"""`calib impact` (docs/impact.md): simulated runs made on a rate table that read fast and a
DAQ whose clock ran fast, archived by the real pipeline into a real SQLite file, looked back
on, and re-solved from their archived raw bytes with the reference as it truly was."""

from __future__ import annotations

import copy
import csv
import io
import json
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from calib_core.reference_errors import ReferenceError, correct_segments, parse_error
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.simulate.rate_table import GyroTruth, simulate_rate_table
from calib_testing.run_writers import six_position_manifest, write_csv_run
from pipelines.cli import app
from pipelines.impact import impact
from pipelines.ingest import discover_runs
from pipelines.ingest.run_loader import read_run
from pipelines.process import calibrate, process_run
from storage import queries
from storage.db import resolve_archive
from storage.verify import verify

RATE_PPM = 120.0  # the table read 120 ppm fast
CLOCK_PPM = 2000.0  # the logger's clock ran 0.2 % fast
TRUE_SCALE = 0.03 + 60e-6  # gyr.scale.x just beyond the mpu6000 profile's 0.03


def _equipment(table: str) -> list[dict]:
    return [
        {"kind": "rate_table", "model": "RT-100", "serial": table, "calibration_due": "2027-01-01"},
        {"kind": "daq", "model": "LOG-1", "serial": "DAQ-3", "calibration_due": "2027-01-01"},
    ]


def _rate_table_segments(seed: int, read_fast_ppm: float) -> dict:
    """Plateaus of a unit whose gyr.scale.x is TRUE_SCALE; the table's rate reading is
    (1 + read_fast_ppm) x the true rate."""
    M = np.zeros((3, 3))
    M[0, 0] = TRUE_SCALE
    run = simulate_rate_table(
        GyroTruth(bias=np.array([1e-3, -2e-3, 5e-4]), M=M),
        rate_hz=100.0,
        settle_s=20.0,
        record_s=12.0,
        gyro_noise_density=1e-4,
        rng=np.random.default_rng(seed),
    )
    factor = 1.0 + read_fast_ppm * 1e-6
    return {
        r.label: replace(r, reference={"table_rate": r.reference["table_rate"] * factor})
        for r in run.recordings
    }


def _rate_manifest(serial: str, started: str, table: str) -> dict:
    m = six_position_manifest(serial, started=started)
    m["run"] |= {"procedure": "rate_table", "settings": {"settle_s": 20.0}}
    m["equipment"] = _equipment(table)
    return m


# The rate-table runs of the tests: name -> (serial, start, the table's serial). RT-7 is
# found RATE_PPM fast for March 2026.
RATE_TABLE_RUNS = {
    "A": ("U-RT1", "2026-03-10T09:00:00+00:00", "RT-7"),
    "B": ("U-RT2", "2026-01-10T09:00:00+00:00", "RT-7"),
    "C": ("U-RT3", "2026-03-11T09:00:00+00:00", "RT-8"),
    "E": ("U-RT5", "2026-03-20T09:00:00+00:00", "RT-7"),
}


def archive_rate_table_runs(arch, tmp, names: str) -> dict[str, str]:
    """Archive the RATE_TABLE_RUNS of `names`, their table reading RATE_PPM fast, each from
    the folder ``tmp / name``; name -> run id."""
    runs = {}
    for name in names:
        serial, started, table = RATE_TABLE_RUNS[name]
        folder = tmp / name
        write_csv_run(
            _rate_table_segments(ord(name), RATE_PPM),
            folder,
            _rate_manifest(serial, started, table),
        )
        runs[name] = _archive(arch, folder)
    return runs


def apply_rate_error(arch) -> dict:
    """`impact` applied: RT-7 read RATE_PPM fast in March 2026."""
    error = parse_error(f"rate_error_ppm={RATE_PPM}")
    return impact(arch, "RT-7", error, "2026-03-01", "2026-03-31", apply=True)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """RT-A (table RT-7, in the period), RT-B (RT-7, before it), RT-C (table RT-8), and an
    integral run I-D on DAQ-3 whose time stamps ran CLOCK_PPM fast."""
    tmp = tmp_path_factory.mktemp("impact")
    arch = resolve_archive(str(tmp / "archive"))
    arch.upgrade()
    runs = archive_rate_table_runs(arch, tmp, "ABC")
    # The same plateaus with the true table rate: what a direct solve would have given.
    write_csv_run(
        _rate_table_segments(ord("A"), 0.0),
        tmp / "A-true",
        _rate_manifest("U-RT1", "2026-03-10T09:00:00+00:00", "RT-7"),
    )

    rng = np.random.default_rng(4)
    truth = copy.deepcopy(random_errors(rng))
    truth.gyr_noise[:] = np.radians(0.01)
    sim = six_position_integral_run(truth, rng, static_s=5.0)
    fast = {k: replace(r, t=r.t * (1 + CLOCK_PPM * 1e-6)) for k, r in sim.segments.items()}
    m = six_position_manifest("U-DAQ", started="2026-03-12T09:00:00+00:00")
    m["equipment"] = _equipment("RT-7")[1:]
    write_csv_run(fast, tmp / "D", m)
    write_csv_run(dict(sim.segments), tmp / "D-true", m)
    runs["D"] = _archive(arch, tmp / "D")
    return {"archive": arch, "runs": runs, "tmp": tmp}


def _archive(arch, folder) -> str:
    (source,) = discover_runs([folder])
    outcome = process_run(source, arch)
    assert outcome["status"] == "ok", outcome["error"]
    return outcome["run_id"]


def _params(arch, run_id: str) -> dict[str, float]:
    return {p.name: p.value for p in queries.run_summary(arch, run_id).calibration.parameters}


def test_parse_error_refuses_what_it_cannot_do():
    assert parse_error("rate_error_ppm=120") == ReferenceError("rate_error_ppm", 120.0)
    for text, message in (
        ("rate_error=120", "unknown quantity 'rate_error'"),
        ("rate_error_ppm", "expected QUANTITY=VALUE"),
        ("rate_error_ppm=1e9", "beyond"),
        ("temperature_offset_c=80", "beyond"),
        ("face_angle_error_arcsec=20", "needs the face and the axis"),
    ):
        with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
            parse_error(text)


def test_rate_error_re_solve_matches_the_true_reference(lab):
    """The table read RATE_PPM fast: the corrected re-solve gives what the true reference
    gives, the scale factor moves by the error, and the verdict flips to fail."""
    arch, runs = lab["archive"], lab["runs"]
    doc = impact(
        arch, "RT-7", parse_error(f"rate_error_ppm={RATE_PPM}"), "2026-03-01", "2026-03-31"
    )
    assert [r["run_id"] for r in doc["runs"]] == [runs["A"]]  # not B (before), not C (RT-8)
    (r,) = doc["runs"]
    direct = calibrate(read_run(lab["tmp"] / "A-true"))
    before = _params(arch, runs["A"])
    moved = {m["name"]: m for m in r["moved"]}
    after_x = moved["gyr.scale.x"]["after"]
    # The two solves differ only by the CSV's rounding of the table rate (9 decimals of
    # rad/s on rates >= 0.87 rad/s: < 1e-9 relative), far below the scale's noise.
    std = direct.parameters["gyr.scale.x"].std
    assert abs(after_x - direct.value("gyr.scale.x")) <= 1e-3 * std
    # (1 + s) / (1 + E) was what the fast table gave: the correction restores (1 + s).
    expected_shift = (1 + before["gyr.scale.x"]) * RATE_PPM * 1e-6
    assert abs(after_x - before["gyr.scale.x"] - expected_shift) <= 1e-3 * std
    m = moved["gyr.scale.x"]  # reported in units of the archived revision's U (Type B too)
    assert m["change_in_U"] == pytest.approx((after_x - m["before"]) / m["U_before"])
    assert m["change_in_U"] > 1
    assert abs(after_x - TRUE_SCALE) <= 3 * std  # and the truth, within the noise
    assert r["verdict_before"] == "pass" and r["verdict_after"] == "fail"
    assert r["affected"] and "table_rate" in r["what"]
    assert not doc["applied"] and r.get("status") is None  # a dry run writes nothing
    assert queries.run_summary(arch, runs["A"]).revisions == 1


def test_clock_error_re_solve_matches_the_true_time(lab):
    """The DAQ's clock ran CLOCK_PPM fast: the integral method's gyro scales come back to
    what the true time stamps give; the rate-table runs on that DAQ do not move."""
    arch, runs = lab["archive"], lab["runs"]
    doc = impact(arch, "DAQ-3", parse_error(f"clock_error_ppm={CLOCK_PPM}"), "2026-03-01")
    by_run = {r["run_id"]: r for r in doc["runs"]}
    assert set(by_run) == {runs["A"], runs["C"], runs["D"]}  # B is before the period
    direct = calibrate(read_run(lab["tmp"] / "D-true"))
    moved = {m["name"]: m for m in by_run[runs["D"]]["moved"]}
    for axis in "xyz":
        name = f"gyr.scale.{axis}"
        std = direct.parameters[name].std
        # time printed to 1 us: a rounding of <= 0.5 us on ~4 s rotations, << the noise
        assert abs(moved[name]["after"] - direct.value(name)) <= 0.05 * std, name
        assert moved[name]["change_in_U"] < -2, moved[name]  # the fast clock read high
    for key in ("A", "C"):  # plateau means do not depend on the clock
        assert not by_run[runs[key]]["moved"], by_run[runs[key]]["moved"]


def test_the_text_report_at_80_columns_shows_verdicts_and_what_moved(lab, monkeypatch):
    """What a look-back is read for (each run's verdict before and after, the parameters
    that moved) stays in the table on an 80-column terminal; only extras are left out."""
    from pipelines import cli_shared

    for console in (cli_shared.out, cli_shared.err):
        monkeypatch.setattr(console, "width", 80)
    monkeypatch.setitem(cli_shared.DISPLAY, "wide", False)
    arch, runs = lab["archive"], lab["runs"]
    args = ["impact", "DAQ-3", "--from", "2026-03-01", "--error", f"clock_error_ppm={CLOCK_PPM}"]
    res = CliRunner().invoke(app, [*args, "--archive", str(arch.root)])
    assert res.exit_code == 0, res.output
    hidden = res.output.split("not shown at this width: ")[-1] if "not shown" in res.output else ""
    assert "moved" not in hidden and "after" not in hidden, res.output
    assert all(len(line) <= 80 for line in res.stdout.splitlines()), res.stdout
    row = next(line for line in res.stdout.splitlines() if runs["D"] in line)
    assert " -> " in row and "gyr.scale." in row, res.stdout


def test_apply_archives_verified_revisions_with_the_reason(lab):
    arch, runs = lab["archive"], lab["runs"]
    out = lab["tmp"] / "impact.csv"
    res = CliRunner().invoke(
        app,
        [
            "impact",
            "RT-7",
            "--from",
            "2026-03-01",
            "--to",
            "2026-03-31",
            "--error",
            f"rate_error_ppm={RATE_PPM}",
            "--apply",
            "--json",
            "--csv",
            str(out),
            "--html",
            str(lab["tmp"] / "impact.html"),
            "--archive",
            str(arch.root),
        ],
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert [(r["run_id"], r["verdict_before"], r["verdict_after"]) for r in doc["runs"]] == [
        (runs["A"], "pass", "fail")
    ]
    (r,) = doc["runs"]
    assert r["status"] == "revised" and r["revision_after"] == 2
    reason = f"out-of-tolerance reference RT-7: rate_error_ppm={RATE_PPM:g}"
    assert doc["reason"] == reason
    cal = queries.run_summary(arch, runs["A"]).calibration
    assert cal.revision == 2 and cal.verdict == "fail"
    lin = queries.lineage(arch, runs["A"], "gyr.scale.x")
    steps = {s["name"]: s for s in lin["steps"]}
    assert steps["reprocess"]["settings"]["reason"] == reason
    corr = steps["reference_correction"]
    assert corr["settings"]["quantity"] == "rate_error_ppm"
    assert corr["settings"]["value"] == RATE_PPM
    assert corr["settings"]["equipment_kind"] == "rate_table"
    assert corr["statistics"]["impact"]["verdict_before"] == "pass"
    assert lin["calibration"]["settings"]["reference_correction"]["equipment_serial"] == "RT-7"
    assert lin["parameter"]["values"][0]["value"] == pytest.approx(r["moved"][0]["after"])
    report = verify(arch)
    assert report.ok, report.problems
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert [(w["run_id"], w["verdict_before"], w["verdict_after"], w["status"]) for w in rows] == [
        (runs["A"], "pass", "fail", "revised")
    ]
    assert "gyr.scale.x" in rows[0]["moved"]
    page = (lab["tmp"] / "impact.html").read_text()
    assert reason in page and runs["A"] in page and "1 verdict(s) changed" in page
    assert "1 revision(s) archived" in page and "gyr.scale.x" in page
    # Applied again: the same correction is a duplicate, not a third revision.
    again = apply_rate_error(arch)
    assert again["runs"][0]["status"] == "duplicate"


def test_reprocessing_carries_the_correction(lab, monkeypatch):
    """A later reprocessing (new software) solves the corrected run with its correction,
    never silently with the reference that was found wrong."""
    from pipelines import process
    from pipelines.reprocess import reprocess_run

    arch, run_a = lab["archive"], lab["runs"]["A"]
    if queries.run_summary(arch, run_a).calibration.revision == 1:  # run alone
        apply_rate_error(arch)
    corrected = _params(arch, run_a)["gyr.scale.x"]
    monkeypatch.setattr(process, "SOFTWARE_VERSION", "99.0-test")
    outcome = reprocess_run(arch, run_a, reason="software 99")
    assert outcome["status"] == "revised", outcome
    cal = queries.run_summary(arch, run_a).calibration
    assert cal.settings["reference_correction"]["quantity"] == "rate_error_ppm"
    assert _params(arch, run_a)["gyr.scale.x"] == pytest.approx(corrected, rel=1e-12)
    assert verify(arch).ok
    # Each revision solved again from the raw bytes with what it records (reason,
    # correction and its look-back record): the one by this "software" to the bit, those
    # by the other version differing in that version alone ("changed", as reprocess says).
    from pipelines.recompute import recompute_run

    newest = cal.revision
    for now, mine in (("99.0-test", {newest}), ("installed", None)):
        if mine is None:
            monkeypatch.undo()
            mine = set(range(1, newest))
        found = recompute_run(arch, run_a)
        for r in found["revisions"]:
            if r["revision"] in mine:
                assert r["status"] == "identical", (now, r)
                continue
            assert (r["status"], r["differences"]) == ("changed", 1), (now, r)
            assert r["first_difference"]["path"] == "calibrations/software_version"
            assert r["changes"]["runs"] == 1 and not r["changes"]["verdicts"]
            assert all(f["changed"] == 0 for f in r["changes"]["families"].values())
        assert found["status"] == "changed"


def refused(lab, equipment: str, error: str) -> str:
    """The output of `calib impact` on the lab's archive, asserted to fail."""
    args = ["impact", equipment, "--from", "2026-03-01", "--error", error]
    res = CliRunner().invoke(app, [*args, "--archive", str(lab["archive"].root)])
    assert res.exit_code != 0
    return res.output


@pytest.mark.parametrize(
    ("error", "message"),
    [
        ("clock_error_ppm=10", "clock_error_ppm is an error of a daq"),
        ("face_angle_error_arcsec[+x,y]=20", "face_angle_error_arcsec is an error of a cube"),
    ],
)
def test_an_error_of_another_kind_of_equipment_is_refused(lab, error, message):
    assert message in refused(lab, "RT-7", error)


def test_a_period_without_runs_on_the_equipment_is_refused(lab):
    assert "no archived run used equipment 'RT-9'" in refused(lab, "RT-9", "rate_error_ppm=10")


def test_rate_error_leaves_runs_without_a_table_rate_alone():
    rng = np.random.default_rng(0)
    sim = six_position_integral_run(random_errors(rng), rng, static_s=2.0)
    same, stats = correct_segments(sim.segments, parse_error("rate_error_ppm=50"))
    assert not stats["affected"] and all(same[k] is sim.segments[k] for k in same)
    # The centrifuge estimates its effective radius: a nominal-radius error reaches no solve.
    same, stats = correct_segments(sim.segments, parse_error("radius_error_mm=0.5"))
    assert not stats["affected"] and "effective radius" in stats["what"]


def test_a_bad_period_is_refused_naming_the_option(lab):
    root = str(lab["archive"].root)
    for period, message in (
        (["--from", "2026-13-01"], "--from: expected a date YYYY-MM-DD"),
        (["--from", "2026-06-01", "--to", "2026-03-01"], "--to 2026-03-01 is before --from"),
    ):
        args = ["impact", "RT-7", *period, "--error", "rate_error_ppm=10", "--archive", root]
        res = CliRunner().invoke(app, args)
        assert res.exit_code != 0 and message in res.output, res.output


def test_a_moved_value_is_given_with_its_si_unit():
    from pipelines.impact import moved_text

    bias = {"name": "acc.bias.z", "before": 0.01, "after": 0.011, "change_in_U": 0.5}
    assert moved_text(bias) == "acc.bias.z 0.01 -> 0.011 m/s^2 (+0.50 U)"
    scale = {"name": "gyr.scale.x", "before": 0.03, "after": 0.0301, "change_in_U": 2.0}
    assert moved_text(scale) == "gyr.scale.x 0.03 -> 0.0301 (+2.00 U)"  # a ratio: no unit
