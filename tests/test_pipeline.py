"""End to end: simulated lab runs in both layouts -> real Prefect flow -> real SQLite archive."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import func, select

from calib_core.simulate import random_errors, six_position_integral_run
from calib_testing.calib_command import run_calib
from calib_testing.run_writers import six_position_manifest, write_csv_run, write_mpu6000_run
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage import schema
from storage.db import resolve_archive
from storage.verify import verify

MANIFEST = six_position_manifest("SIM-CSV-1")


def _simulate(seed: int):
    rng = np.random.default_rng(seed)
    return six_position_integral_run(random_errors(rng), rng)


@pytest.fixture
def lab_day(tmp_path: Path) -> dict[str, Path]:
    """A folder with one MPU-6000 run, one CSV run and one broken run (a segment file missing)."""
    day = tmp_path / "day"
    sim_a, sim_b, sim_c = _simulate(1), _simulate(2), _simulate(3)
    write_mpu6000_run(sim_a.segments, day / "mpu", "MPU0001", truth=sim_a.truth_dict())
    write_csv_run(sim_b.segments, day / "csv", MANIFEST, truth=sim_b.truth_dict())
    broken = day / "broken"
    write_mpu6000_run(sim_c.segments, broken, "MPU0666", truth=sim_c.truth_dict())
    (broken / "MPU0666_y_dn.txt").unlink()
    bad_unit = day / "bad_unit"
    write_csv_run(
        sim_c.segments,
        bad_unit,
        {**MANIFEST, "unit": {**MANIFEST["unit"], "serial": "SIM-BAD-UNIT"}},
    )
    toml = (bad_unit / "run.toml").read_text()
    (bad_unit / "run.toml").write_text(toml.replace('acc_unit = "m/s^2"', 'acc_unit = "furlong"'))
    return {
        "day": day,
        "mpu": day / "mpu",
        "csv": day / "csv",
        "broken": broken,
        "truth_mpu": sim_a.truth_dict(),
        "truth_csv": sim_b.truth_dict(),
    }


def _row_counts(arch) -> dict[str, int]:
    with arch.engine().connect() as conn:
        return {
            t.name: conn.execute(select(func.count()).select_from(t)).scalar_one()
            for t in schema.Base.metadata.sorted_tables
        }


def test_batch_archives_good_runs_and_reports_the_bad_one(prefect_harness, lab_day, tmp_path):
    from pipelines.flows import process_batch  # Prefect: imported when run, not when collected

    archive_dir = tmp_path / "archive"
    outcomes = process_batch([str(lab_day["day"])], str(archive_dir))
    by_serial = {o["serial"] or Path(o["source"]).name: o for o in outcomes}
    assert by_serial["MPU0001"]["status"] == "ok", by_serial["MPU0001"]["error"]
    assert by_serial["SIM-CSV-1"]["status"] == "ok", by_serial["SIM-CSV-1"]["error"]
    failed = {Path(o["source"]).name: o["error"] for o in outcomes if o["status"] == "failed"}
    assert set(failed) == {"broken", "bad_unit"}
    assert "MPU0666_y_dn" in failed["broken"]
    assert "run.toml" in failed["bad_unit"] and "furlong" in failed["bad_unit"]

    # parameters against the simulator's truth, within 4 reported standard uncertainties
    for serial, truth in (("MPU0001", lab_day["truth_mpu"]), ("SIM-CSV-1", lab_day["truth_csv"])):
        got = by_serial[serial]["parameters"]
        for name, p in got.items():
            if ".noise." in name:
                continue
            assert p["std"] is not None and p["std"] > 0, name
            err = abs(p["value"] - truth["parameters"][name])
            assert err <= 4 * p["std"], f"{serial} {name}: error {err:.3g} > 4 x {p['std']:.3g}"
        protocol = Path(by_serial[serial]["protocol"])
        assert protocol.name == f"{serial}_result.txt" and protocol.is_file()
        text = protocol.read_text()
        assert serial in text and "Quality control" in text and "gyr.scale.x" in text
        # the profile bounds gyro noise from above only, scale errors on both sides
        # (the parameter table's line: the uncertainty table after it repeats the names)
        lines: dict[str, str] = {}
        for line in text.splitlines():
            if line.startswith("gyr."):
                lines.setdefault(line.split()[0], line)
        assert "<=" in lines["gyr.noise.x"] and "+-" in lines["gyr.scale.x"]

    arch = resolve_archive(str(archive_dir))
    counts = _row_counts(arch)
    assert counts["runs"] == 2 and counts["calibrations"] == 2
    assert set(_serials(arch)) == {"MPU0001", "SIM-CSV-1"}  # nothing of the failed runs

    # the same files again: duplicates, and not one new row anywhere
    again = process_batch([str(lab_day["mpu"]), str(lab_day["csv"])], str(archive_dir))
    assert [o["status"] for o in again] == ["duplicate", "duplicate"]
    assert all(o["run_id"] for o in again)
    assert _row_counts(arch) == counts


def test_process_run_stores_each_raw_file_once_and_nothing_of_failed_runs(tmp_path):
    """Raw files are copied towards the object store while they are hashed at ingest: an
    archived run's objects are its raw files byte for byte; a run that fails after ingest,
    or a duplicate, leaves no file behind (verify finds no orphan)."""
    sim = _simulate(4)
    good = write_csv_run(sim.segments, tmp_path / "good", MANIFEST).parent
    bad_manifest = {**MANIFEST, "run": {**MANIFEST["run"], "settings": {"accel_solver": "bogus"}}}
    bad = write_csv_run(sim.segments, tmp_path / "bad", bad_manifest).parent
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()

    def stored() -> list[Path]:
        return sorted(p for p in (arch.root / "objects").rglob("*") if p.is_file())

    failed = process_run(discover_runs([bad])[0], arch)
    assert failed["status"] == "failed" and "accel_solver" in failed["error"], failed
    assert stored() == []

    assert process_run(discover_runs([good])[0], arch)["status"] == "ok"
    raw = {hashlib.sha256((good / n).read_bytes()).hexdigest() for n in ("run.toml", "imu.csv")}
    assert {p.name for p in stored()} == raw
    assert all(hashlib.sha256(p.read_bytes()).hexdigest() == p.name for p in stored())
    assert process_run(discover_runs([good])[0], arch)["status"] == "duplicate"
    report = verify(arch)
    assert report.ok and report.orphans == [], (report.problems, report.orphans)


def _serials(arch) -> list[str]:
    with arch.engine().connect() as conn:
        return list(conn.execute(select(schema.Device.serial)).scalars())


@pytest.mark.e2e
def test_cli_process_json_contract(lab_day, tmp_path):
    """`calib process --json`: one JSON document on stdout, exit 1 when a run failed."""
    env = {**os.environ, "CALIB_ARCHIVE": str(tmp_path / "cli-archive")}
    proc = run_calib("process", str(lab_day["day"]), "--json", env=env)
    assert proc.returncode == 1 and proc.stdout.startswith("{"), proc.stderr[-3000:]
    doc = json.loads(proc.stdout)
    assert set(doc) == {"runs"} and len(doc["runs"]) == 4
    for run in doc["runs"]:
        assert {"run_id", "serial", "status", "error", "parameters", "checks", "protocol"} <= set(
            run
        )
        assert run["status"] in ("ok", "failed", "duplicate")
        if run["status"] == "ok":
            assert run["error"] is None and run["parameters"]["acc.bias.x"]["unit"] == "m/s^2"
            assert run["parameters"]["gyr.gsens.xy"]["unit"] == "(rad/s)/(m/s^2)"
            assert all(isinstance(c["passed"], bool) for c in run["checks"])
        else:
            assert run["error"]
    ok_ids = [r["run_id"] for r in doc["runs"] if r["status"] == "ok"]
    proc = run_calib("process", str(lab_day["mpu"]), "--json", env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    again = json.loads(proc.stdout)["runs"]
    assert again[0]["status"] == "duplicate" and again[0]["run_id"] in ok_ids

    shown = run_calib("show", ok_ids[0], "--json", env=env)
    assert shown.returncode == 0, shown.stderr[-2000:]
    exported = run_calib("export", ok_ids[0], "--format", "json", env=env)
    assert exported.returncode == 0 and "acc.scale.x" in exported.stdout
