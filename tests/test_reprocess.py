"""Re-processing a run from the archive alone gives the identical calibration.

Simulated runs (a run.toml CSV run and a manifest-less MPU-6000 folder) are
processed into a real SQLite archive, the original folders are deleted, and
`calib reprocess` rebuilds them from the archived raw objects: the parameters
must be equal bit for bit (same bytes in, same deterministic solver), and the
archive must answer "duplicate" for unchanged settings and software.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from calib_core.simulate import random_errors, six_position_integral_run
from calib_testing.run_writers import six_position_manifest, write_csv_run, write_mpu6000_run
from pipelines import process as process_module
from pipelines.cli import app
from pipelines.ingest import discover_runs, load_run
from pipelines.process import process_run
from pipelines.reprocess import ReprocessError, reprocess_run, restore_run
from storage import queries, rawstore
from storage.db import resolve_archive

MANIFEST = six_position_manifest("SIM-RE-1")


@pytest.fixture
def arch(tmp_path: Path):
    archive = resolve_archive(str(tmp_path / "archive"))
    archive.upgrade()
    yield archive
    archive.dispose()


def _simulated(seed: int):
    rng = np.random.default_rng(seed)
    return six_position_integral_run(random_errors(rng), rng)


def _first_processing(folder: Path, arch) -> dict:
    (source,) = discover_runs([folder])
    outcome = process_run(source, arch)
    assert outcome["status"] == "ok", outcome["error"]
    shutil.rmtree(folder)  # from here on only the archive has the run
    return outcome


def _archived(folder: Path, arch, layout: str, seed: int) -> dict:
    """A simulated run written in `layout` (a run.toml CSV run or a manifest-less MPU-6000
    folder), processed, its folder deleted: its outcome."""
    sim = _simulated(seed)
    if layout == "csv":
        write_csv_run(sim.segments, folder, MANIFEST)
    else:
        write_mpu6000_run(sim.segments, folder, f"MPU{seed:04d}")
    return _first_processing(folder, arch)


@pytest.mark.parametrize("layout", ["csv", "mpu6000"])
def test_reprocess_gives_identical_parameters_and_duplicate(tmp_path: Path, arch, layout) -> None:
    first = _archived(tmp_path / "run", arch, layout, 11 if layout == "csv" else 12)

    again = reprocess_run(arch, first["run_id"])
    assert again["status"] == "duplicate", again["error"]
    assert again["run_id"] == first["run_id"] and again["source"] == f"archive:{first['run_id']}"
    # Bit for bit: dict equality compares the floats exactly.
    assert again["parameters"] == first["parameters"] and len(first["parameters"]) >= 12
    assert again["checks"] == first["checks"] and again["verdict"] == first["verdict"]


@pytest.mark.parametrize("layout", ["csv", "mpu6000"])
def test_reprocessing_leaves_the_raw_objects_as_they_were(tmp_path: Path, arch, layout) -> None:
    """The temporary folder's hard links to the objects (a run with a manifest) are gone
    afterwards, and no object's bytes, times or link count changed (a run without one is
    copied: its files' times are set)."""
    first = _archived(tmp_path / "run", arch, layout, 13)
    objects = sorted(p for p in (arch.root / "objects").rglob("*") if p.is_file())
    before = {
        p: (p.stat().st_mtime_ns, p.stat().st_nlink, rawstore.hash_and_size(p)[0]) for p in objects
    }
    assert reprocess_run(arch, first["run_id"])["status"] == "duplicate"
    after = {
        p: (p.stat().st_mtime_ns, p.stat().st_nlink, rawstore.hash_and_size(p)[0]) for p in objects
    }
    assert after == before and {n for _, n, _ in after.values()} == {1}


def test_rebuilt_folder_is_the_original_run(tmp_path: Path, arch) -> None:
    """Same raw bytes, and for a manifest-less folder the same synthesised manifest."""
    sim = _simulated(13)
    folder = tmp_path / "mpu"
    write_mpu6000_run(sim.segments, folder, "MPU0043")
    original = load_run(discover_runs([folder])[0])
    first = _first_processing(folder, arch)

    source = restore_run(arch, first["run_id"], tmp_path / "rebuilt")
    rebuilt = load_run(source)
    assert rebuilt.manifest == original.manifest  # incl. started = newest file mtime
    assert [(f.name, f.sha256) for f in rebuilt.raw_files] == [
        (f.name, f.sha256) for f in original.raw_files
    ]
    for label, rec in original.segments.items():
        assert np.array_equal(rebuilt.segments[label].acc, rec.acc)
        assert np.array_equal(rebuilt.segments[label].t, rec.t)


def test_new_software_version_gives_a_new_revision_with_the_same_values(
    tmp_path: Path, arch, monkeypatch
) -> None:
    sim = _simulated(14)
    write_csv_run(sim.segments, tmp_path / "run", MANIFEST)
    first = _first_processing(tmp_path / "run", arch)
    monkeypatch.setattr(process_module, "SOFTWARE_VERSION", "9.9.9-reprocess-test")
    again = reprocess_run(arch, first["run_id"])
    assert again["status"] == "revised", again["error"]  # revision 2 of the same run
    assert again["parameters"] == first["parameters"]
    assert queries.run_summary(arch, first["run_id"]).revisions == 2


def test_altered_or_missing_raw_object_is_refused(tmp_path: Path, arch) -> None:
    sim = _simulated(15)
    write_csv_run(sim.segments, tmp_path / "run", MANIFEST)
    first = _first_processing(tmp_path / "run", arch)
    raw = {r.name: r for r in queries.run_summary(arch, first["run_id"]).raw_files}
    obj = rawstore.object_path(arch.root, raw["imu.csv"].sha256)
    obj.chmod(0o644)
    obj.write_bytes(obj.read_bytes().replace(b"0", b"1", 1))
    with pytest.raises(ReprocessError, match=r"'imu\.csv'.*hashes to .*the file store was altered"):
        reprocess_run(arch, first["run_id"])
    obj.unlink()
    with pytest.raises(ReprocessError, match=r"'imu\.csv'.*missing from the file store"):
        reprocess_run(arch, first["run_id"])
    with pytest.raises(ReprocessError, match="R000000000000"):
        reprocess_run(arch, "R000000000000")


def test_cli_reprocess_json(tmp_path: Path, arch) -> None:
    sim = _simulated(16)
    write_csv_run(sim.segments, tmp_path / "run", MANIFEST)
    first = _first_processing(tmp_path / "run", arch)
    result = CliRunner().invoke(
        app,
        ["reprocess", first["run_id"], "--archive", str(arch.root), "--json", "--reason", "check"],
    )
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    (outcome,) = doc["runs"]
    assert doc["summary"] == {"runs": 1, "revised": 0, "duplicate": 1, "failed": 0, "failures": []}
    assert outcome["status"] == "duplicate" and outcome["parameters"] == first["parameters"]
    result = CliRunner().invoke(
        app, ["reprocess", "R000000000000", "--archive", str(arch.root), "--reason", "check"]
    )
    assert result.exit_code == 2
    for args, said in (
        ([first["run_id"]], "--reason"),  # required
        ([first["run_id"], "--reason", " "], "say why"),
        (["--reason", "why"], "name the runs"),
        ([first["run_id"], "--all", "--reason", "why"], "not both"),
        (["--all", "--serial", "X", "--reason", "why"], "--all selects every run"),
        (["--since", "yesterday", "--reason", "why"], "since: expected a date"),
    ):
        result = CliRunner().invoke(app, ["reprocess", *args, "--archive", str(arch.root)])
        assert result.exit_code == 2 and said in result.output, (args, result.output)
