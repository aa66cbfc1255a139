"""`calib inspect PATH [--json]`: reads, reports, archives nothing."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from log_writers import write_rosbag1, write_ulog
from typer.testing import CliRunner

from calib_core.recording import Recording
from pipelines.cli import app

SAMPLES = Path(__file__).resolve().parents[1] / "data_samples"
MPU = SAMPLES / "mpu6000_MPU0001"


def inspect(path: Path, *extra: str, archive: Path | None = None):
    env = {"CALIB_ARCHIVE": str(archive)} if archive else {}
    res = CliRunner().invoke(app, ["inspect", str(path), "--json", *extra], env=env)
    return res.exit_code, json.loads(res.stdout)


def test_mpu6000_file_against_the_data(tmp_path: Path) -> None:
    code, doc = inspect(MPU / "MPU0001_x_up.txt", archive=tmp_path / "archive")
    assert code == 0 and doc["format"] == "mpu6000" and doc["segment"] == "x_up"
    data = np.loadtxt(MPU / "MPU0001_x_up.txt", max_rows=1000)
    assert doc["samples"] == len(data) == 1000
    assert doc["rate_hz"] == pytest.approx(1000.0 / np.median(np.diff(data[:, 0])))
    assert doc["duration_s"] == pytest.approx((data[-1, 0] - data[0, 0]) / 1000)
    assert doc["temperature_c"] == [data[:, 7].min(), data[:, 7].max()]
    assert "columns time_ms ax ay az gx gy gz temp" in doc["variant"]
    assert not (tmp_path / "archive").exists()  # nothing archived
    # the program's display after the orientation, from the file's own columns and units
    for line, name, col, digits in zip(
        doc["display"],
        ("Ax", "Ay", "Az", "Gx", "Gy", "Gz"),
        range(1, 7),
        (4, 4, 4, 3, 3, 3),
        strict=True,
    ):
        x = data[:, col]
        assert line == f"{name} : mean={x.mean():.{digits}f} std={x.std(ddof=1):.{digits}f}"


def test_run_folder_lists_segments_and_what_is_missing(tmp_path: Path) -> None:
    code, doc = inspect(MPU)
    (run,) = doc["runs"]
    assert code == 0 and run["procedure"] == "six_position_integral" and run["missing"] == []
    assert len(run["segments"]) == 12
    shutil.copytree(MPU, tmp_path / "run")
    (tmp_path / "run" / "MPU0001_y_cw.txt").unlink()
    code, doc = inspect(tmp_path / "run")
    assert code == 1 and "missing MPU0001_y_cw.txt" in doc["runs"][0]["error"]


def test_csv_sample_folder() -> None:
    code, doc = inspect(SAMPLES / "csv_IMU-2026-0042")
    assert code == 0, doc
    (run,) = doc["runs"]
    assert run["format"] == "csv" and run["missing"] == []


def test_real_session_with_one_turn_per_axis_misses_nothing(tmp_path: Path) -> None:
    """imucal's Ferraris session turns once per axis (rotation_directions = "any")."""
    data = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "imucal_ferraris"
    if not data.is_dir():
        pytest.skip(f"real data not found at {data}")
    run = tmp_path / "ferraris"
    run.mkdir()
    shutil.copyfile(data / "example_ferraris_session.csv", run / "example_ferraris_session.csv")
    manifest = (Path(__file__).parent / "realdata" / "imucal_ferraris.toml").read_text()
    (run / "run.toml").write_text(manifest)
    code, doc = inspect(run)
    assert code == 0 and doc["runs"][0]["missing"] == []
    (run / "run.toml").write_text(manifest.replace('rotation_directions = "any"', ""))
    code, doc = inspect(run)
    assert doc["runs"][0]["missing"] == ["x_ccw", "y_ccw", "z_ccw"]


def test_text_output_has_no_python_reprs(tmp_path: Path) -> None:
    path = tmp_path / "imu.csv"
    path.write_text("t,ax,ay,az,gx,gy,gz\n" + "".join(f"{i / 100},0,0,1,0,0,0\n" for i in range(9)))
    res = CliRunner().invoke(app, ["inspect", str(path)])
    assert res.exit_code == 0, res.stdout
    assert "variant: delimiter ,, decimal ., header_line 1, metadata_lines none" in res.stdout
    assert not any(mark in res.stdout for mark in ("{", "[]", "None", "'"))


def test_csv_file_reports_dialect_and_units(tmp_path: Path) -> None:
    path = tmp_path / "imu.csv"
    rows = "\n".join(f"{i * 10};0,1;0,2;1,0;0,5;0,6;0,7;21,5" for i in range(50))
    path.write_text(
        "device: X\nt [ms];ax (g);ay (g);az (g);wx [deg/s];wy [deg/s];wz [deg/s];"
        "temp\n" + rows + "\n"
    )
    code, doc = inspect(path)
    assert code == 0, doc
    assert doc["variant"]["delimiter"] == ";" and doc["variant"]["decimal"] == ","
    assert doc["variant"]["metadata_lines"] == ["device: X"]
    assert doc["columns"][1] == "ax (g) [g]" and doc["rate_hz"] == pytest.approx(100.0)
    assert doc["temperature_c"] == [21.5, 21.5]


def test_logs(tmp_path: Path) -> None:
    n = 200
    t = np.arange(n) / 100.0
    t[150:] += 0.5  # a gap of 0.5 s
    rec = Recording(t=t, acc=np.ones((n, 3)), gyr=np.zeros((n, 3)), temp=np.linspace(20, 22, n))
    write_ulog(tmp_path / "a.ulg", rec)
    write_rosbag1(tmp_path / "a.bag", rec)
    for name in ("a.ulg", "a.bag"):
        code, doc = inspect(tmp_path / name)
        assert code == 0, doc
        assert doc["samples"] == n and doc["gaps"] == 1
        assert doc["largest_gap_s"] == pytest.approx(0.51, abs=1e-5)
        assert doc["temperature_c"][0] == pytest.approx(20.0, abs=1e-4)


def test_broken_file_names_line(tmp_path: Path) -> None:
    path = tmp_path / "MPU0001_x_up.txt"
    lines = (MPU / "MPU0001_x_up.txt").read_text().splitlines()
    lines[10] = lines[10].replace("9.3", "9,x")
    path.write_text("\n".join(lines) + "\n")
    code, doc = inspect(path)
    assert code == 1 and f"{path} line 11: field 'ax': expected a finite number" in doc["error"]
    res = CliRunner().invoke(app, ["inspect", str(path)])
    assert res.exit_code == 1 and "line 11" in res.stdout


@pytest.mark.skipif(sys.platform == "win32", reason="posix paths")
def test_missing_path(tmp_path: Path) -> None:
    code, doc = inspect(tmp_path / "nope")
    assert code == 1 and "does not exist" in doc["error"]
