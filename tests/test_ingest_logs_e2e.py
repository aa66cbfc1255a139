"""New routes in: PX4 ULog, ArduPilot DataFlash, ROS 2 .db3 and ROS 1 .bag
bags, imu_tk text, each end to end through `calib process --json`.

A simulated six_position_integral run is written one file per segment by each
ecosystem's own writer (tests/log_writers.py: pyulog, the DataFlash record
layout with pymavlink's type table, rosbags' ROS 1 and ROS 2 writers; imu_tk
text as numpy writes it), each with a run.toml naming the format kind. One
`calib process DAY --json` run (a real Prefect flow into a real SQLite archive)
processes all five; every parameter must lie within 4 of its reported standard
uncertainties of the simulator's truth (a 4-sigma miss has probability ~6e-5
per parameter for a correct estimator). ULog and DataFlash store float32: its
rounding (6e-8 relative, ~6e-7 m/s^2) is far below the noise of a segment mean.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from log_writers import write_dataflash, write_rosbag1, write_rosbag2, write_ulog
from test_ingest_formats_e2e import manifest

from calib_core.simulate import random_errors, six_position_integral_run
from calib_testing.calib_command import run_calib
from pipelines.ingest import IngestError, discover_runs, load_run


def write_run(folder: Path, route: str, segments) -> None:
    folder.mkdir(parents=True)
    entries = []
    for label, rec in segments.items():
        if route == "ulog":
            write_ulog(folder / f"{label}.ulg", rec, topics="both")
            entries.append({"label": label, "file": f"{label}.ulg"})
        elif route == "dataflash":
            write_dataflash(folder / f"{label}.bin", rec, instances=2)
            entries.append({"label": label, "file": f"{label}.bin"})
        elif route == "rosbag2":
            db3 = write_rosbag2(folder / label, rec)
            entries.append({"label": label, "file": f"{label}/{db3.name}"})
        elif route == "rosbag1":
            write_rosbag1(folder / f"{label}.bag", rec)
            entries.append({"label": label, "file": f"{label}.bag"})
        else:  # imu_tk: "t x y z" per line, one file per sensor
            for sensor, values in (("acc", rec.acc), ("gyr", rec.gyr)):
                np.savetxt(
                    folder / f"{label}_{sensor}.txt", np.column_stack([rec.t, values]), fmt="%.17g"
                )
            entries.append(
                {"label": label, "acc_file": f"{label}_acc.txt", "gyr_file": f"{label}_gyr.txt"}
            )
    kinds = {"rosbag2": "rosbag", "rosbag1": "rosbag"}
    fmt = {"kind": kinds.get(route, route)}
    if route in ("rosbag1", "rosbag2"):
        fmt["temperature_topic"] = "/imu/temperature"
    (folder / "run.toml").write_text(manifest(f"SIM-{route.upper()}", fmt, entries))


ROUTES = ("ulog", "dataflash", "rosbag2", "rosbag1", "imutk")


@pytest.fixture(scope="module")
def sim():
    rng = np.random.default_rng(1717)
    return six_position_integral_run(random_errors(rng), rng, static_s=10.0)


@pytest.mark.slow
@pytest.mark.parametrize("route", ROUTES)
def test_route_reads_the_simulated_samples(tmp_path: Path, route: str, sim) -> None:
    write_run(tmp_path / route, route, sim.segments)
    loaded = load_run(discover_runs([tmp_path / route])[0])
    tol = 1e-6 if route in ("ulog", "dataflash") else 1e-14  # float32 storage
    for label, rec in sim.segments.items():
        got = loaded.segments[label]
        assert len(got) == len(rec)
        np.testing.assert_allclose(got.acc, rec.acc, rtol=tol, atol=tol * 10)
        np.testing.assert_allclose(got.gyr, rec.gyr, rtol=tol, atol=tol)
        dt = np.diff(got.t) - np.diff(rec.t)
        assert np.abs(dt).max() <= 1e-6  # us (ULog, DataFlash) or ns stamps
        if route != "imutk":
            assert got.temp is not None


@pytest.mark.slow
def test_calib_process_every_route(tmp_path: Path, sim) -> None:
    day = tmp_path / "day"
    for route in ROUTES:
        write_run(day / route, route, sim.segments)
    env = {**os.environ, "CALIB_ARCHIVE": str(tmp_path / "archive")}
    proc = run_calib("process", str(day), "--json", env=env)
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-3000:]
    runs = {r["serial"]: r for r in json.loads(proc.stdout)["runs"]}
    assert sorted(runs) == sorted(f"SIM-{r.upper()}" for r in ROUTES)
    truth = sim.truth_dict()["parameters"]
    for serial, run in runs.items():
        assert run["status"] == "ok", (serial, run["error"])
        checked = 0
        for name, p in run["parameters"].items():
            if ".noise." in name:
                continue
            err = abs(p["value"] - truth[name])
            assert err <= 4 * p["std"], f"{serial} {name}: error {err:.3g} > 4 x {p['std']:.3g}"
            checked += 1
        assert checked == 33, serial


@pytest.mark.parametrize(
    ("route", "damage", "message"),
    [
        ("ulog", lambda b: b"XLog" + b[4:], "not a ULog file"),
        ("dataflash", lambda b: b"\x00" + b[1:], "not an ArduPilot DataFlash log"),
        ("rosbag1", lambda b: b[:5] + b"X" + b[6:], "not a ROS bag"),
        ("rosbag2", lambda b: b[:4096], "damaged rosbag2"),
    ],
)
def test_damaged_log_names_the_file(tmp_path: Path, sim, route, damage, message) -> None:
    segments = {"x_up": sim.segments["x_up"]}
    write_run(tmp_path / "run", route, segments)
    path = next(
        p for p in (tmp_path / "run").rglob("*") if p.suffix in (".ulg", ".bin", ".bag", ".db3")
    )
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(IngestError, match=message) as err:
        load_run(discover_runs([tmp_path / "run"])[0])
    assert err.value.file == str(path)


def test_dataflash_second_imu_and_unknown_key(tmp_path: Path, sim) -> None:
    segments = {"x_up": sim.segments["x_up"]}
    write_run(tmp_path / "run", "dataflash", segments)
    toml = tmp_path / "run" / "run.toml"
    kind = 'kind = "dataflash"'
    toml.write_text(toml.read_text().replace(kind, kind + "\ninstance = 1"))
    got = load_run(discover_runs([tmp_path / "run"])[0]).segments["x_up"]
    np.testing.assert_allclose(got.acc[:, 0] - 1.0, sim.segments["x_up"].acc[:, 0], atol=1e-5)
    toml.write_text(toml.read_text().replace("instance = 1", "instanse = 1"))
    with pytest.raises(IngestError, match=r"field 'format\.instanse': unknown key"):
        load_run(discover_runs([tmp_path / "run"])[0])
