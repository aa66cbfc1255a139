"""MPU-6000 text layout: round trip through the writer, discovery by file name, bad input."""

from __future__ import annotations

import hashlib
import os
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from calib_core.recording import Recording
from calib_core.units import DEG, STANDARD_GRAVITY
from calib_testing.run_writers import write_mpu6000_run
from pipelines.ingest import IngestError, discover_runs, find_mpu6000_runs, load_run
from pipelines.ingest.manifest import SIX_POSITION_LABELS
from pipelines.ingest.mpu6000 import read_mpu6000_file

RATE_HZ = 50.0
N = 150  # samples per segment: 3 s at 50 Hz keeps files small and tests fast

# Round-trip tolerances: half a unit of the last printed digit (4 decimals
# m/s^2, 3 decimals deg/s, 1 decimal deg C, integer ms), converted to SI, with
# 1e-9 relative slack for the binary representation of the decimal values.
TOL_ACC = 0.5e-4 * (1 + 1e-9)
TOL_GYR = 0.5e-3 * DEG * (1 + 1e-9)
TOL_TEMP = 0.05 * (1 + 1e-9)
TOL_T = 0.5e-3 * (1 + 1e-9)


def make_segments(rng: np.random.Generator) -> dict[str, Recording]:
    """Twelve segments with plausible values: +-g on one axis, 30 deg/s turns, noise."""
    t = np.arange(N) / RATE_HZ + rng.uniform(0, 0.01)  # not on the ms grid: exercises rounding
    out = {}
    for label in SIX_POSITION_LABELS:
        axis = "xyz".index(label[0])
        acc = rng.normal(0.0, 0.02, (N, 3))
        gyr = rng.normal(0.0, 0.01, (N, 3))
        if label.endswith(("up", "dn")):
            acc[:, axis] += STANDARD_GRAVITY if label.endswith("up") else -STANDARD_GRAVITY
        else:  # rotation about the vertical axis, that axis up
            acc[:, axis] += STANDARD_GRAVITY
            gyr[:, axis] += (30.0 if label.endswith("ccw") else -30.0) * DEG
        temp = 24.0 + np.linspace(0.0, 0.5, N) + rng.normal(0.0, 0.05, N)
        out[label] = Recording(t=t.copy(), acc=acc, gyr=gyr, temp=temp, label=label)
    return out


@pytest.fixture
def run_folder(tmp_path: Path) -> Path:
    write_mpu6000_run(make_segments(np.random.default_rng(7)), tmp_path, "AB12")
    return tmp_path


def edit_line(path: Path, line: int, fn) -> None:
    """Replace 1-based `line` of `path` by fn(old line)."""
    lines = path.read_text().splitlines(keepends=True)
    lines[line - 1] = fn(lines[line - 1])
    path.write_text("".join(lines))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_round_trip_to_printed_precision(tmp_path: Path, seed: int) -> None:
    segments = make_segments(np.random.default_rng(seed))
    files = write_mpu6000_run(segments, tmp_path, "SN-0042")
    assert [f.name for f in files] == [f"SN-0042_{lab}.txt" for lab in SIX_POSITION_LABELS]
    for path, (label, truth) in zip(files, segments.items(), strict=True):
        rec = read_mpu6000_file(path)
        assert rec.label == label and rec.source == str(path) and len(rec) == N
        assert np.abs(rec.t - truth.t).max() <= TOL_T
        assert np.abs(rec.acc - truth.acc).max() <= TOL_ACC
        assert np.abs(rec.gyr - truth.gyr).max() <= TOL_GYR
        assert np.abs(rec.temp - truth.temp).max() <= TOL_TEMP
        # The gyro came back in rad/s, not deg/s: a missed conversion is 57x off.
        assert np.abs(rec.gyr).max() < 1.0


def test_find_runs_groups_by_serial_and_ignores_other_files(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    write_mpu6000_run(make_segments(rng), tmp_path, "B2")
    write_mpu6000_run(make_segments(rng), tmp_path, "A1")
    (tmp_path / "A1_result.txt").write_text("protocol\n")
    (tmp_path / "notes.txt").write_text("hello\n")
    runs = find_mpu6000_runs(tmp_path)
    assert list(runs) == ["A1", "B2"]
    assert list(runs["A1"]) == list(SIX_POSITION_LABELS)
    assert runs["B2"]["z_cw"] == tmp_path / "B2_z_cw.txt"


def test_missing_file_names_what_is_missing(run_folder: Path) -> None:
    (run_folder / "AB12_y_cw.txt").unlink()
    with pytest.raises(IngestError, match=r"AB12_y_cw\.txt") as err:
        find_mpu6000_runs(run_folder)
    assert "11 of the 12" in str(err.value) and err.value.file == str(run_folder)
    # Discovery still finds the run; loading it reports the gap.
    (source,) = discover_runs([run_folder])
    with pytest.raises(IngestError, match=r"missing AB12_y_cw\.txt"):
        load_run(source)


def test_truncated_file_without_summary(run_folder: Path) -> None:
    path = run_folder / "AB12_x_dn.txt"
    path.write_bytes(path.read_bytes()[:3000])  # cut in the middle of the data
    with pytest.raises(IngestError, match="truncated") as err:
        read_mpu6000_file(path)
    assert str(path) in str(err.value)


def test_data_lines_lost_but_summary_kept(run_folder: Path) -> None:
    path = run_folder / "AB12_y_up.txt"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:100] + lines[N:]))  # drop data lines 101..150
    with pytest.raises(IngestError, match=r"printed means disagree.*'time_ms'") as err:
        read_mpu6000_file(path)
    assert err.value.line == 101 + 1  # the means line follows data and underscores


def test_non_numeric_line(run_folder: Path) -> None:
    path = run_folder / "AB12_x_up.txt"
    edit_line(path, 17, lambda s: s.replace(s.split()[1], "abc", 1))
    with pytest.raises(IngestError) as err:
        read_mpu6000_file(path)
    assert f"{path} line 17: field 'ax': expected a finite number, got 'abc'" in str(err.value)
    assert (err.value.line, err.value.field) == (17, "ax")


@pytest.mark.parametrize(
    ("edit", "got"),
    [(lambda s: s.rsplit(maxsplit=1)[0] + "\n", 7), (lambda s: s.rstrip() + " 1.0\n", 9)],
)
def test_wrong_column_count(run_folder: Path, edit, got: int) -> None:
    path = run_folder / "AB12_z_dn.txt"
    edit_line(path, 17, edit)
    with pytest.raises(IngestError) as err:
        read_mpu6000_file(path)
    assert "AB12_z_dn.txt line 17: expected 8 numeric columns" in str(err.value)
    assert f"got {got}" in str(err.value)


def test_empty_file(run_folder: Path) -> None:
    path = run_folder / "AB12_z_up.txt"
    path.write_text("")
    with pytest.raises(IngestError, match=r"AB12_z_up\.txt: file is empty"):
        read_mpu6000_file(path)


def test_time_not_increasing(run_folder: Path) -> None:
    path = run_folder / "AB12_x_ccw.txt"
    edit_line(path, 30, lambda s: " ".join(["0", *s.split()[1:]]) + "\n")  # time 0 ms on line 30
    # The summary is checked after the time: the first complaint is the time.
    with pytest.raises(IngestError, match="time must increase") as err:
        read_mpu6000_file(path)
    assert err.value.line == 30


def test_unsafe_serial_in_file_name(tmp_path: Path) -> None:
    good = write_mpu6000_run(make_segments(np.random.default_rng(1)), tmp_path, "AB12")[0]
    bad = tmp_path / "..etc_x_up.txt"  # '/' cannot be in a file name; '..' can
    bad.write_bytes(good.read_bytes())
    with pytest.raises(IngestError, match=r"invalid serial '\.\.etc'") as err:
        find_mpu6000_runs(tmp_path)
    assert err.value.file == str(bad)
    with pytest.raises(IngestError, match=r"\.\.etc_x_up\.txt"):
        read_mpu6000_file(bad)


def test_writer_refuses_unsafe_serial(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="invalid serial"):
        write_mpu6000_run(
            make_segments(np.random.default_rng(1)), tmp_path / "a" / "b", "../../etc"
        )
    assert not any(tmp_path.rglob("*.txt"))


def test_load_folder_synthesises_manifest_and_hashes(run_folder: Path) -> None:
    stamp = datetime(2024, 3, 5, 12, 30, tzinfo=UTC).timestamp()
    for i, path in enumerate(sorted(run_folder.glob("*.txt"))):
        os.utime(path, (stamp - 100 * i, stamp - 100 * i))  # the newest is `stamp`
    (source,) = discover_runs([run_folder])
    run = load_run(source)
    m = run.manifest
    assert (m.unit.serial, m.unit.model, m.run.procedure) == (
        "AB12",
        "MPU-6000",
        "six_position_integral",
    )
    assert m.run.tolerance_profile == "mpu6000" and m.gravity() == STANDARD_GRAVITY
    assert m.run.started == datetime(2024, 3, 5, 12, 30, tzinfo=UTC)
    assert run.manifest_text is None and run.verification_labels == set()
    assert list(run.segments) == list(SIX_POSITION_LABELS)
    assert len(run.raw_files) == 12
    for raw in run.raw_files:
        data = raw.path.read_bytes()
        assert raw.sha256 == hashlib.sha256(data).hexdigest() and raw.size == len(data)
        assert raw.format == "mpu6000" and raw.name == raw.path.name


def mpu6000_run_toml(serial: str, unit_extra: str = "") -> str:
    """run.toml beside MPU-6000 files (K. Lab, 08:00 at +02:00); `unit_extra`: more [unit] lines."""
    return f"""schema_version = 1
[unit]
serial = "{serial}"
model = "MPU-6000"
manufacturer = "InvenSense"
{unit_extra}[run]
started = 2024-06-01T08:00:00+02:00
operator = "K. Lab"
procedure = "six_position_integral"
tolerance_profile = "mpu6000"
[format]
kind = "mpu6000"
"""


def test_run_toml_beside_mpu_files_takes_over(run_folder: Path) -> None:
    (run_folder / "run.toml").write_text(mpu6000_run_toml("AB12"))
    (source,) = discover_runs([run_folder])
    run = load_run(source)
    assert run.manifest.run.operator == "K. Lab"
    assert run.manifest.run.started == datetime(2024, 6, 1, 6, 0, tzinfo=UTC)
    assert list(run.segments) == list(SIX_POSITION_LABELS)
    assert [r.name for r in run.raw_files][:2] == ["run.toml", "AB12_x_up.txt"]
    assert len(run.raw_files) == 13


def test_folder_of_run_folders_and_nothing_found(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    write_mpu6000_run(make_segments(rng), tmp_path / "day1" / "bench", "U1")
    write_mpu6000_run(make_segments(rng), tmp_path / "day2", "U2")
    sources = discover_runs([tmp_path])
    assert [(s.folder.relative_to(tmp_path).as_posix(), s.serial) for s in sources] == [
        ("day1/bench", "U1"),
        ("day2", "U2"),
    ]
    (tmp_path / "empty").mkdir()
    with pytest.raises(IngestError, match="no run found") as err:
        discover_runs([tmp_path / "empty"])
    assert err.value.file == str(tmp_path / "empty")
