"""The real sessions in ../shared/realdata ingest with the manifests in tests/realdata.

- imucal's Ferraris session: CSV with a sample counter at 102.4 Hz, sections
  from its section list. Checked sample for sample against the file, the
  rotation sense of every turn against its label, and the calibration against
  imucal's own calibrated output of the same session (reference/).
- imu_tk's Xsens session: two whitespace text files (.mat names) in raw counts,
  acc and gyro merged on one time base, converted with datasheet scale/offset.

The data is not copied into the project: each test copies the files it needs
into a temporary run folder, and skips with a message when the shared folder
is absent.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from calib_core.units import DEG
from pipelines.ingest import IngestError, discover_runs, load_run
from pipelines.process import process_run, solve_loaded
from storage.db import resolve_archive

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
MANIFESTS = Path(__file__).resolve().parent / "realdata"
# The Xsens session's manifest is the benchmark set's (calib validate --benchmark).
SESSIONS = Path(__file__).resolve().parents[1] / "pipelines" / "validation" / "sessions"
FERRARIS = REALDATA / "imucal_ferraris"
XSENS = REALDATA / "imutk_xsens"
FERRARIS_RATE_HZ = 102.4
# imucal section -> our label; the turn labels are checked against the data below.
SECTION_LABELS = {
    "x_p": "x_up", "x_a": "x_dn", "y_p": "y_up", "y_a": "y_dn", "z_p": "z_up", "z_a": "z_dn",
    "x_rot": "x_cw", "y_rot": "y_cw", "z_rot": "z_cw",
}  # fmt: skip
XSENS_ACC_SCALE = np.array([415.0, 413.0, 415.0])  # counts per m/s^2 (datasheet)
XSENS_ACC_OFFSET = np.array([33123.0, 33276.0, 32360.0])
XSENS_GYR_SCALE = np.array([4778.0, 4758.0, 4766.0])  # counts per rad/s
XSENS_GYR_OFFSET = np.array([32768.0, 32466.0, 32485.0])


def _need(folder: Path) -> None:
    if not folder.is_dir():
        pytest.skip(f"real data not found at {folder} (the shared realdata folder is absent)")


def _run_folder(tmp_path: Path, data: Path, files: list[str], manifest: str) -> Path:
    folder = tmp_path / data.name
    folder.mkdir()
    for name in files:
        shutil.copyfile(data / name, folder / name)
    where = SESSIONS if (SESSIONS / manifest).is_file() else MANIFESTS
    shutil.copyfile(where / manifest, folder / "run.toml")
    return folder


@pytest.fixture
def ferraris_run(tmp_path: Path):
    _need(FERRARIS)
    folder = _run_folder(
        tmp_path, FERRARIS, ["example_ferraris_session.csv"], "imucal_ferraris.toml"
    )
    return load_run(discover_runs([folder])[0])


def test_ferraris_sections_are_the_listed_samples(ferraris_run) -> None:
    raw = pd.read_csv(FERRARIS / "example_ferraris_session.csv")
    sections = json.loads((FERRARIS / "example_ferraris_session_list.json").read_text())
    assert list(ferraris_run.segments) == [SECTION_LABELS[k] for k in sections]
    for section, span in sections.items():
        rec = ferraris_run.segments[SECTION_LABELS[section]]
        rows = raw.iloc[span["start"] : span["end"]]  # imucal's sections: end exclusive
        assert len(rec) == len(rows)
        # Same numbers: m/s^2 unchanged, deg/s times the exact factor, t = index / rate.
        assert np.array_equal(rec.acc, rows[["acc_x", "acc_y", "acc_z"]].to_numpy())
        assert np.array_equal(rec.gyr, rows[["gyr_x", "gyr_y", "gyr_z"]].to_numpy() * DEG)
        assert np.array_equal(rec.t, rows["n_samples"].to_numpy() / FERRARIS_RATE_HZ)


def test_ferraris_turns_are_negative_about_their_axis(ferraris_run) -> None:
    """x_rot, y_rot, z_rot are labelled cw: their gyro integral must be about -360 deg.

    A hand turn is one revolution give or take the hand's slack; a sign or
    axis mistake would give +360 deg or ~0 deg, far outside +-30 deg.
    """
    for label in ("x_cw", "y_cw", "z_cw"):
        rec = ferraris_run.segments[label]
        axis = "xyz".index(label[0])
        angle = np.sum(rec.gyr[:, axis]) / FERRARIS_RATE_HZ / DEG
        assert abs(angle + 360.0) < 30.0, (label, angle)


def test_ferraris_calibration_matches_imucal(ferraris_run) -> None:
    """Our six-position + integral calibration corrects the first 50 samples as imucal's does.

    imucal's calibrated output of the same session's first 50 rows (x axis up)
    is in reference/. Both are estimates of the same linear model from the
    same sections by different estimators (Ferraris' closed form vs least
    squares), so they may differ by up to the model's own misfit: the largest
    mean static residual of our fit (accelerometer). For the gyro, the
    uncertainty of what acts on a resting sample: 3 x (bias std + |f| x the
    largest g-sensitivity std, a term imucal's model lacks).
    """
    cal, *_ = solve_loaded(ferraris_run)
    raw = pd.read_csv(FERRARIS / "example_ferraris_session.csv").iloc[:50]
    ref = pd.read_csv(FERRARIS / "reference" / "ferraris_example_calibrated_head50.csv")
    acc, gyr = cal.correct(
        raw[["acc_x", "acc_y", "acc_z"]].to_numpy(),
        raw[["gyr_x", "gyr_y", "gyr_z"]].to_numpy() * DEG,
    )
    misfit = max(
        np.abs(r.mean).max()
        for r in cal.residuals
        if r.sensor == "acc" and r.segment[2:] in ("up", "dn")
    )
    assert np.abs(acc - ref[["acc_x", "acc_y", "acc_z"]].to_numpy()).max() <= misfit
    p = cal.parameters
    gsens_std = max(v.std for k, v in p.items() if k.startswith("gyr.gsens."))
    bias_std = max(p[f"gyr.bias.{a}"].std for a in "xyz")
    tol = 3 * (bias_std + cal.gravity * gsens_std)
    assert np.abs(gyr - ref[["gyr_x", "gyr_y", "gyr_z"]].to_numpy() * DEG).max() <= tol


def test_xsens_counts_merge_on_one_time_base(tmp_path: Path) -> None:
    _need(XSENS)
    folder = _run_folder(tmp_path, XSENS, ["xsens_acc.mat", "xsens_gyro.mat"], "imutk_xsens.toml")
    run = load_run(discover_runs([folder])[0])
    rec = run.segments["session"]
    acc_raw = np.loadtxt(XSENS / "xsens_acc.mat")
    gyr_raw = np.loadtxt(XSENS / "xsens_gyro.mat")
    assert len(rec) == len(acc_raw) == 51175
    assert np.array_equal(rec.t, acc_raw[:, 0])
    # (counts - offset) / scale, per axis: the independent computation differs by rounding.
    assert np.allclose(
        rec.acc, (acc_raw[:, 1:] - XSENS_ACC_OFFSET) / XSENS_ACC_SCALE, rtol=1e-15, atol=1e-13
    )
    assert np.allclose(
        rec.gyr, (gyr_raw[:, 1:] - XSENS_GYR_OFFSET) / XSENS_GYR_SCALE, rtol=1e-15, atol=1e-13
    )
    assert [(f.name, f.format) for f in run.raw_files] == [
        ("run.toml", "manifest"),
        ("xsens_acc.mat", "csv"),
        ("xsens_gyro.mat", "csv"),
    ]
    # The first ~45 s are at rest: with the datasheet scale the magnitude is g to the
    # datasheet's scale accuracy (0.5 %); a counts-per-g vs per-m/s^2 mix-up is a factor 9.8.
    rest = rec.t < 45.0
    assert abs(np.linalg.norm(rec.acc[rest], axis=1).mean() - 9.81744) < 0.005 * 9.81744


def test_xsens_separate_files_must_share_time(tmp_path: Path) -> None:
    _need(XSENS)
    folder = _run_folder(tmp_path, XSENS, ["xsens_acc.mat", "xsens_gyro.mat"], "imutk_xsens.toml")
    lines = (folder / "xsens_gyro.mat").read_text().splitlines()
    stamp = lines[99].split()[0]  # line 100: moved by 0.5 ms, still between its neighbours
    lines[99] = lines[99].replace(stamp, f"{float(stamp) + 0.0005:.7e}", 1)
    (folder / "xsens_gyro.mat").write_text("\n".join(lines) + "\n")
    with pytest.raises(
        IngestError, match=r"xsens_gyro\.mat line 100: time [\d.]+ s differs from the acc"
    ):
        load_run(discover_runs([folder])[0])


def test_real_sessions_process_into_an_archive(tmp_path: Path) -> None:
    """Both sessions go through the whole pipeline; the equipment-free fit stays near the datasheet.

    The Xsens datasheet scale factors are nominal: the fitted scale corrections
    must stay within a few per cent (a unit mix-up would be a factor ~10 or 57).
    """
    _need(FERRARIS)
    _need(XSENS)
    runs = tmp_path / "runs"
    runs.mkdir()
    _run_folder(runs, FERRARIS, ["example_ferraris_session.csv"], "imucal_ferraris.toml")
    _run_folder(runs, XSENS, ["xsens_acc.mat", "xsens_gyro.mat"], "imutk_xsens.toml")
    archive = resolve_archive(str(tmp_path / "archive"))
    archive.upgrade()
    try:
        outcomes = {
            o["serial"]: o for o in (process_run(s, archive) for s in discover_runs([runs]))
        }
    finally:
        archive.dispose()
    for outcome in outcomes.values():
        assert outcome["status"] == "ok", outcome["error"]
    xsens = outcomes["imutk-xsens"]["parameters"]
    for sensor in ("acc", "gyr"):
        for a in "xyz":
            assert abs(xsens[f"{sensor}.scale.{a}"]["value"]) < 0.05
