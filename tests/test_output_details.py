"""Small things a user notices: the protocol's uncertainty column carries no sign, and every
file calib writes (archive objects, run folder, samples, reports, exports) has one mode."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest
from typer.testing import CliRunner

from calib_core.calibration import Parameter
from calib_testing.documents import parameter_protocol
from pipelines.cli import app
from storage.rawstore import FILE_MODE

ROOT = Path(__file__).resolve().parents[1]


def test_protocol_values_are_signed_and_uncertainties_are_not() -> None:
    text = parameter_protocol(
        [
            Parameter("acc.scale.x", -0.0225, 1.9e-5),
            Parameter("acc.scale.y", 0.0051, 2.1e-5),
        ]
    )
    rows = {line.split()[0]: line.split() for line in text.splitlines() if "acc.scale" in line}
    assert rows["acc.scale.x"][1:3] == ["-0.022500", "0.000019"]
    assert rows["acc.scale.y"][1:3] == ["+0.005100", "0.000021"]
    assert "+0.0000" not in text


@pytest.mark.slow
def test_every_written_file_has_one_mode(tmp_path: Path) -> None:
    """Process a sample (in this process), write its reports and an export: every file
    has FILE_MODE, the mode open() gives under the umask (mkstemp alone gives 0600)."""
    archive = tmp_path / "archive"
    sample = ROOT / "data_samples" / "mpu6000_MPU0001"
    runner = CliRunner()
    done = runner.invoke(
        app,
        ["process", str(sample), "--archive", str(archive), "--json", "--no-progress", "--reports"],
    )
    assert done.exit_code == 0, done.output
    export = tmp_path / "unit.params"
    run_id = json.loads(done.stdout)["runs"][0]["run_id"]
    done = runner.invoke(
        app,
        ["export", run_id, "--archive", str(archive), "--format", "px4", "--device-id", "1"]
        + ["--output", str(export)],
    )
    assert done.exit_code == 0, done.output
    files = [p for p in archive.rglob("*") if p.is_file() and not p.name.startswith("archive.")]
    files.append(export)
    kinds = {p.suffix for p in files}
    assert {".parquet", ".txt", ".html", ".pdf", ".params"} <= kinds, kinds
    umask = os.umask(0o022)
    os.umask(umask)
    assert 0o666 & ~umask == FILE_MODE
    modes = {p.relative_to(tmp_path).as_posix(): oct(stat.S_IMODE(p.stat().st_mode)) for p in files}
    assert set(modes.values()) == {oct(FILE_MODE)}, modes
