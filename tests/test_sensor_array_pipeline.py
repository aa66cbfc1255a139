"""The six-IMU array procedure end to end: CSV files -> `calib process` -> SQLite archive.

docs/methods.md 2.7 (the patent): six IMUs on a cube, pairs on three faces, one
static record and one clockwise and one counter-clockwise full turn about the
vertical. Each IMU logs one continuous recording (static, cw, static, ccw,
static) as a lab's logger would, in g and deg/s; automatic segmentation
(``labels = "array"``) cuts it into ``<sensor>_static``, ``_cw``, ``_ccw``.
"""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from calib_core.simulate import random_errors
from calib_core.simulate.array import array_session
from calib_core.solvers.sensor_array import cube_mounts
from calib_core.units import DEG, STANDARD_GRAVITY
from calib_testing.run_writers import dumps_toml, six_position_manifest
from pipelines.cli import app

G = STANDARD_GRAVITY
SENSORS = tuple(cube_mounts())


def _write_run(folder, sessions):
    folder.mkdir()
    for name, rec in sessions.items():
        frame = {"t [s]": rec.t}
        frame |= {f"acc_{a} [g]": rec.acc[:, i] / G for i, a in enumerate("xyz")}
        frame |= {f"gyro_{a} [deg/s]": rec.gyr[:, i] / DEG for i, a in enumerate("xyz")}
        pd.DataFrame(frame).to_csv(folder / f"{name}.csv", index=False, float_format="%.8g")
    manifest = six_position_manifest("CUBE-6", operator="lab")
    manifest["run"] |= {
        "procedure": "sensor_array",
        "settings": {"mounts": "cube6", "segmentation": {"labels": "array"}},
    }
    manifest["format"] = {"kind": "csv"}
    manifest["segments"] = [{"label": name, "file": f"{name}.csv"} for name in sessions]
    (folder / "run.toml").write_text(dumps_toml(manifest), encoding="utf-8")


@pytest.mark.slow
def test_six_imu_array_from_files_to_the_archive(tmp_path):
    """Every archived parameter within 4 of its reported standard uncertainties of the truth.

    The uncertainties are the solver's (tests/test_sensor_array.py shows them
    honest over seeds); 4 sigma leaves a false alarm of 6e-5 per parameter
    (~0.3 % for the ~40 here). The CSV's 8 significant digits quantise 1 g to
    1e-7 g, far below the noise. A turn labelled with the wrong sense (s2, s4
    and s6 see the vertical along a negative axis) flips gyro scale factors by
    ~2, thousands of sigma.
    """
    rng = np.random.default_rng(2207)
    truth = random_errors(rng)
    # docs/methods.md 3.4: settle >= 30 s, record >= 10 s at >= 100 Hz: 40 s statics keep 10 s
    sessions = array_session(truth, cube_mounts(), rng, rate_hz=100.0, static_s=40.0)
    folder = tmp_path / "cube"
    _write_run(folder, sessions)
    archive = tmp_path / "archive"
    res = CliRunner().invoke(app, ["process", str(folder), "--archive", str(archive), "--json"])
    assert res.exit_code in (0, 1), res.output
    (run,) = json.loads(res.output)["runs"]
    assert run["status"] == "ok", run["error"]

    shown = CliRunner().invoke(app, ["show", run["run_id"], "--archive", str(archive), "--json"])
    assert shown.exit_code == 0, shown.output
    steps = {s["name"]: s for s in json.loads(shown.output)["calibration"]["steps"]}
    found = steps["segment"]["statistics"]["segments"]
    assert set(found) == {f"{s}_{p}" for s in SENSORS for p in ("static", "ccw", "cw")}
    for s in SENSORS:  # the order of the session: the cw turn comes before the ccw turn
        assert found[f"{s}_cw"]["start_s"] < found[f"{s}_ccw"]["start_s"]
        assert found[f"{s}_static"]["end_s"] - found[f"{s}_static"]["start_s"] >= 10.0 - 0.01

    with sqlite3.connect(archive / "archive.sqlite") as db:
        rows = db.execute("SELECT name, value, std FROM parameters").fetchall()
    true = truth.parameters()
    archived = {name: (value, std) for name, value, std in rows}
    assert {n for n in true if not n.endswith(("noise.x", "noise.y", "noise.z"))} <= set(archived)
    for name, (value, std) in archived.items():
        if name in true:
            assert abs(value - true[name]) <= 4 * std, (name, value, true[name], std)


def test_unknown_labelling_is_refused_naming_the_setting():
    from calib_core.preprocess.chain import preprocess

    rng = np.random.default_rng(1)
    sessions = array_session(random_errors(rng), {"s5": np.eye(3)}, rng, static_s=12.0)
    with pytest.raises(
        ValueError, match=r"segmentation.labels must be one of 'faces', 'array', got 'cube'"
    ):
        preprocess(sessions, {"segmentation": {"labels": "cube"}}, gravity=G)
