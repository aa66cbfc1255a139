"""MAT v7.3 and MCAP runs dispatched by the manifest's format.kind, end to end.

A simulated six_position_integral run is written one file per segment, as
MATLAB v7.3 (hdf5storage, MATLAB's own HDF5 layout) and as a ROS 2 MCAP log
(mcap-ros2-support's writer with the real sensor_msgs/msg/Imu definition),
described by a run.toml, processed by pipelines.process.process_run into a
real SQLite archive, and every parameter is compared with the simulator's
truth within 4 of its reported standard uncertainties (a 4-sigma miss has
probability ~6e-5 per parameter for a correct estimator).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap_ros2.writer import Writer as Ros2Writer
from test_ingest_mcap import IMU_MSGDEF, TEMPERATURE_MSGDEF, imu_message

from calib_core.simulate import random_errors, six_position_integral_run
from calib_testing.run_writers import dumps_toml
from pipelines.ingest import IngestError, discover_runs, load_run
from pipelines.process import process_run
from storage.db import resolve_archive

T0_NS = 1_763_600_000_000_000_000  # 2025-11-20, Unix ns: MCAP stamps are Unix time


def manifest(serial: str, fmt: dict, segments: list[dict] | dict[str, str]) -> str:
    """run.toml text of a simulated six_position_integral run (a dict: label -> file)."""
    if isinstance(segments, dict):
        segments = [{"label": label, "file": name} for label, name in segments.items()]
    return dumps_toml(
        {
            "schema_version": 1,
            "unit": {"serial": serial, "model": "SIM", "manufacturer": "calib_core.simulate"},
            "run": {
                "started": "2025-11-20T09:00:00Z",
                "operator": "test",
                "procedure": "six_position_integral",
                "tolerance_profile": "mpu6000",
            },
            "format": fmt,
            "segments": segments,
        }
    )


def write_mat_run(folder: Path, segments) -> None:
    """One v7.3 file per segment: a struct `imu` with t (s), acc (g), gyr (deg/s), temp."""
    folder.mkdir(parents=True)
    import hdf5storage  # h5py and HDF5 loaded by the tests that write one, not at collection

    files = {}
    for label, rec in segments.items():
        imu = {"t": rec.t, "acc": rec.acc / 9.80665, "gyr": np.degrees(rec.gyr), "temp": rec.temp}
        hdf5storage.savemat(
            str(folder / f"{label}.mat"), {"imu": imu}, format="7.3", matlab_compatible=True
        )
        files[label] = f"{label}.mat"
    fmt = {
        "kind": "mat",
        "acc_unit": "g",
        "gyr_unit": "deg/s",
        "variables": {"t": "imu.t", "acc": "imu.acc", "gyr": "imu.gyr", "temp": "imu.temp"},
    }
    (folder / "run.toml").write_text(manifest("SIM-MAT73", fmt, files))


def write_mcap_run(folder: Path, segments) -> None:
    """One ROS 2 log per segment: Imu on /imu/data, Temperature on /imu/temperature at 1/10 rate."""
    folder.mkdir(parents=True)
    files = {}
    for label, rec in segments.items():
        stamps = T0_NS + np.round(rec.t * 1e9).astype(np.int64)
        with open(folder / f"{label}.mcap", "wb") as f:
            w = Ros2Writer(f)
            imu_schema = w.register_msgdef("sensor_msgs/msg/Imu", IMU_MSGDEF)
            temp_schema = w.register_msgdef("sensor_msgs/msg/Temperature", TEMPERATURE_MSGDEF)
            for i, ns in enumerate(stamps.tolist()):
                w.write_message(
                    "/imu/data", imu_schema, imu_message(ns, rec.acc[i], rec.gyr[i]), log_time=ns
                )
                if i % 10 == 0:
                    msg = {
                        "header": {
                            "stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9},
                            "frame_id": "",
                        },
                        "temperature": float(rec.temp[i]),
                        "variance": 0.0,
                    }
                    w.write_message("/imu/temperature", temp_schema, msg, log_time=ns)
            w.finish()
        files[label] = f"{label}.mcap"
    fmt = {"kind": "mcap", "imu_topic": "/imu/data", "temperature_topic": "/imu/temperature"}
    (folder / "run.toml").write_text(manifest("SIM-MCAP", fmt, files))


WRITERS = {"mat73": write_mat_run, "mcap": write_mcap_run}


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "seed"), [("mat73", 21), ("mcap", 22)])
def test_run_in_format_is_processed_to_truth(tmp_path: Path, kind: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    sim = six_position_integral_run(random_errors(rng), rng)
    folder = tmp_path / kind
    WRITERS[kind](folder, sim.segments)

    (source,) = discover_runs([folder])
    loaded = load_run(source)
    # The format's precision: float64 in MAT (units converted back and forth, a few ulp);
    # MCAP stamps are integer ns on a Unix time base (float64 Unix s resolves 2.4e-7 s).
    for label, rec in sim.segments.items():
        got = loaded.segments[label]
        assert np.allclose(got.acc, rec.acc, rtol=1e-14, atol=1e-14)
        assert np.allclose(got.gyr, rec.gyr, rtol=1e-14, atol=1e-14)
        t0 = T0_NS / 1e9 if kind == "mcap" else 0.0
        assert np.abs(got.t - t0 - rec.t).max() <= 5e-7
    assert {f.format for f in loaded.raw_files} == {"manifest", kind.removesuffix("73")}

    archive = resolve_archive(str(tmp_path / "archive"))
    archive.upgrade()
    try:
        outcome = process_run(source, archive)
    finally:
        archive.dispose()
    assert outcome["status"] == "ok", outcome["error"]
    truth = sim.truth_dict()["parameters"]
    checked = 0
    for name, p in outcome["parameters"].items():
        if ".noise." in name:
            continue
        assert p["std"] is not None and p["std"] > 0, name
        err = abs(p["value"] - truth[name])
        assert err <= 4 * p["std"], f"{kind} {name}: error {err:.3g} > 4 x {p['std']:.3g}"
        checked += 1
    assert checked == 33  # 12 accelerometer + 12 gyro + 9 g-sensitivity


def test_unknown_mcap_key_names_the_field(tmp_path: Path) -> None:
    rng = np.random.default_rng(23)
    sim = six_position_integral_run(random_errors(rng), rng, static_s=1.0)
    write_mcap_run(tmp_path / "run", {"x_up": sim.segments["x_up"]})
    toml = tmp_path / "run" / "run.toml"
    toml.write_text(toml.read_text().replace("imu_topic", "imu_topik"))
    with pytest.raises(IngestError, match=r"field 'format\.imu_topik': unknown key 'imu_topik'"):
        load_run(discover_runs([tmp_path / "run"])[0])
