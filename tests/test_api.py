"""The public Python API: the README's "From Python" blocks run, every
public name has a NumPy-style docstring, docs/api.md is what scripts/api_doc.py writes,
and importing the packages stays cheap (the names are imported on first use)."""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pipelines", "calib_core", "storage")


def _python_blocks(markdown: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", markdown, flags=re.S | re.M)


def test_readme_python_blocks_run(tmp_path, monkeypatch, capsys):
    blocks = _python_blocks((ROOT / "README.md").read_text(encoding="utf-8"))
    assert len(blocks) >= 3, "the README's From Python section lost its code"
    shutil.copytree(ROOT / "data_samples", tmp_path / "data_samples")
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "__readme__"}
    for i, block in enumerate(blocks, 1):
        exec(compile(block, f"README.md python block {i}", "exec"), namespace)  # noqa: S102
    out = capsys.readouterr().out
    # What the blocks say they do happened: the archive, the report, the files.
    assert "ok R" in out and "pass MPU0001_result.txt" in out
    for written in (
        "my-archive/archive.sqlite",
        "reports/MPU0001_result.txt",
        "MPU0001.params",
        "MPU0001_calibrated.parquet",
    ):
        assert (tmp_path / written).is_file(), written
    assert "CAL_ACC0_XOFF" in (tmp_path / "MPU0001.params").read_text()


def _public(package: str) -> list[tuple[str, object]]:
    module = importlib.import_module(package)
    return [(n, getattr(module, n)) for n in module.__all__ if not n.startswith("_")]


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_has_a_numpy_docstring(package):
    for name, obj in _public(package):
        if isinstance(obj, dict):  # a table (PROCEDURES): documented by its module
            continue
        doc = inspect.getdoc(obj) or ""
        if inspect.isclass(obj):
            assert re.search(r"^(Attributes|Parameters)\n-{10}$", doc, re.M), f"{package}.{name}"
        else:
            assert "Parameters\n----------" in doc, f"{package}.{name}: no Parameters section"
            assert "Returns\n-------" in doc, f"{package}.{name}: no Returns section"
        if not inspect.isclass(obj):  # every parameter a caller may pass is described
            missing = set(inspect.signature(obj).parameters) - _listed(doc)
            assert not missing, f"{package}.{name}: {sorted(missing)} not described"


def _listed(doc: str) -> set[str]:
    """Parameter names given as 'a, b : ...' lines."""
    return {n.strip() for line in re.findall(r"^([\w, ]+) :", doc, re.M) for n in line.split(",")}


def _api_doc_module():
    spec = importlib.util.spec_from_file_location("api_doc", ROOT / "scripts" / "api_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_docs_api_md_is_current():
    assert (ROOT / "docs" / "api.md").read_text(encoding="utf-8") == _api_doc_module().render(), (
        "docs/api.md is out of date: run python scripts/api_doc.py"
    )


def test_importing_the_packages_loads_no_heavy_library():
    code = (
        "import sys, calib_core, pipelines, storage\n"
        "heavy = {'numpy', 'scipy', 'pandas', 'sqlalchemy', 'prefect', 'typer'}\n"
        "heavy &= set(sys.modules)\n"
        "assert not heavy, heavy\n"
        "assert callable(pipelines.read_run) and 'pipelines.ingest' in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_unknown_names_are_attribute_errors():
    import pipelines

    with pytest.raises(AttributeError, match="pipelines.*no attribute 'nope'"):
        pipelines.nope  # noqa: B018
    assert {"read_run", "calibrate", "export_run"} <= set(dir(pipelines))


def test_read_run_names_the_path_without_a_single_run(tmp_path):
    import pipelines

    folder = ROOT / "data_samples" / "mpu6000_MPU0001"
    with pytest.raises(pipelines.IngestError, match=r"data_samples: no run found"):
        pipelines.read_run(ROOT / "data_samples")  # runs are one level down
    for f in folder.glob("MPU0001_*.txt"):  # two units' files in one folder
        shutil.copy(f, tmp_path / f.name)
        shutil.copy(f, tmp_path / f.name.replace("MPU0001", "MPU0002"))
    with pytest.raises(pipelines.IngestError, match=r"expected one run here, found 2 \(.*MPU0002"):
        pipelines.read_run(tmp_path)
    assert pipelines.read_run(tmp_path, serial="MPU0002").manifest.unit.serial == "MPU0002"
    with pytest.raises(pipelines.IngestError, match="of serial NOPE here, found 0"):
        pipelines.read_run(folder, serial="NOPE")
    assert pipelines.read_run(folder, serial="MPU0001").manifest.unit.serial == "MPU0001"


def test_judge_lists_the_checks_every_view_of_the_run_counts(tmp_path, monkeypatch):
    """`pipelines.judge` of a calibrated run gives the names the archive keeps for it once
    processed (what `calib show`, the report and the web count); without an archive the
    unit's description is listed as not judged, never counted against the verdict."""
    import calib_core
    import pipelines
    import storage
    from calib_core.conditions import counts_against_verdict, status
    from storage import queries

    monkeypatch.setenv("CALIB_ISSUE_CERTIFICATES", "0")
    folder = ROOT / "data_samples" / "mpu6000_MPU0001"
    run = pipelines.read_run(folder)
    cal = pipelines.calibrate(run)
    alone = pipelines.judge(run, cal)
    archive = storage.open_archive(tmp_path / "archive")
    before = pipelines.judge(run, cal, archive)
    (source,) = pipelines.discover_runs([folder])
    outcome = pipelines.process_run(source, archive)
    kept = queries.run_summary(archive, outcome["run_id"]).calibration.checks
    names = sorted(c.name for c in kept)
    assert sorted(c.name for c in alone) == names == sorted(c.name for c in before)
    assert len(names) > len(calib_core.check_calibration(cal, pipelines.load_profile("mpu6000")))
    device = {c.name: c for c in alone}["device:description"]
    assert status(device) == "not judged" and "needs the archive" in device.detail
    assert not counts_against_verdict(device)
    judged = {c.name: c for c in before}["device:description"]
    assert judged.passed and judged.detail == {c.name: c for c in kept}[judged.name].detail
    assert calib_core.overall_verdict(alone) == calib_core.overall_verdict(before)
