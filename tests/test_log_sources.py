"""Which source of IMU samples a log is read from, and `calib inspect` listing them.

PX4 logs sensor_accel / sensor_gyro at about 1 Hz beside a fast sensor_combined;
ArduPilot logs several IMU instances; a bag may carry several Imu topics. The
default reads the fastest; a source below the minimum rate is refused with every
source's rate; a temperature the log does not carry is "not recorded", never 0.
Files are written by the ecosystems' own libraries (tests/log_writers.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from log_writers import write_dataflash, write_rosbag1, write_rosbag2, write_ulog
from typer.testing import CliRunner

from calib_core.recording import Recording
from pipelines.cli import app
from pipelines.ingest.dataflash_reader import read_dataflash
from pipelines.ingest.errors import IngestError
from pipelines.ingest.rosbag_reader import read_rosbag
from pipelines.ingest.ulog_reader import read_ulog

RATE_HZ = 100.0
N = 1000  # 10 s


@pytest.fixture(scope="module")
def rec() -> Recording:
    rng = np.random.default_rng(34)
    t = np.arange(N) / RATE_HZ
    acc = rng.normal(0, 0.02, (N, 3)) + (0, 0, 9.81)
    return Recording(t=t, acc=acc, gyr=rng.normal(0, 0.01, (N, 3)), temp=np.full(N, 21.5))


def inspect(path: Path) -> dict:
    res = CliRunner().invoke(app, ["inspect", str(path), "--json"])
    assert res.exit_code == 0, res.stdout
    return json.loads(res.stdout)


def test_ulog_default_reads_sensor_combined_not_the_1hz_topics(tmp_path: Path, rec) -> None:
    path = tmp_path / "px4.ulg"
    write_ulog(path, rec, topics="both", separate_every=100)  # 1 Hz sensor_accel/_gyro
    got = read_ulog(path)
    assert len(got) == N
    np.testing.assert_allclose(got.gyr, rec.gyr, atol=1e-6)  # float32 in the log
    assert got.temp is not None  # sensor_accel's 1 Hz temperature, interpolated
    with pytest.raises(IngestError, match="below the 10 Hz") as err:
        read_ulog(path, source="sensor_accel")
    assert err.value.file == str(path) and err.value.field == "format.source"
    assert "sensor_accel[0] + sensor_gyro[0] 1 Hz (10 samples)" in err.value.problem
    assert "sensor_combined 100 Hz (1000 samples)" in err.value.problem


def test_ulog_with_only_slow_topics_is_refused_listing_the_rates(tmp_path: Path, rec) -> None:
    path = tmp_path / "slow.ulg"
    write_ulog(path, rec, topics="separate", separate_every=100)
    with pytest.raises(
        IngestError,
        match=r"sensor_accel\[0\] \+ sensor_gyro\[0\] is logged at "
        r"1 Hz, below the 10 Hz",
    ):
        read_ulog(path)
    assert len(read_ulog(path, min_rate_hz=0.5)) == 10  # when the lab says so


def test_inspect_lists_the_ulog_sources_and_rates(tmp_path: Path, rec) -> None:
    path = tmp_path / "px4.ulg"
    write_ulog(path, rec, topics="both", separate_every=100)
    doc = inspect(path)
    assert doc["sources"] == [
        {
            "source": "sensor_accel[0] + sensor_gyro[0]",
            "rate_hz": 1.0,
            "samples": 10,
            "temperature": "recorded",
        },
        {
            "source": "sensor_combined",
            "rate_hz": 100.0,
            "samples": N,
            "temperature": "not recorded",
        },
    ]
    assert doc["samples"] == N and doc["rate_hz"] == 100.0
    text = CliRunner().invoke(app, ["inspect", str(path)]).stdout
    assert "  sensor_combined: 100.0 Hz, 1000 samples, temperature not recorded" in text
    assert "  sensor_accel[0] + sensor_gyro[0]: 1.0 Hz, 10 samples, temperature recorded" in text


def test_dataflash_default_reads_the_fastest_imu(tmp_path: Path, rec) -> None:
    path = tmp_path / "ardupilot.bin"
    write_dataflash(path, rec, instances=2, every=(50, 1))  # IMU 0 at 2 Hz, IMU 1 at 100 Hz
    got = read_dataflash(path)
    assert len(got) == N
    np.testing.assert_allclose(got.acc[:, 0] - 1.0, rec.acc[:, 0], atol=1e-5)  # instance 1
    with pytest.raises(IngestError, match=r"IMU\[0\] is logged at 2 Hz, below") as err:
        read_dataflash(path, instance=0)
    assert "IMU[1] 100 Hz (1000 samples)" in err.value.problem
    assert err.value.field == "format.instance"


def test_dataflash_without_temperature_says_not_recorded(tmp_path: Path, rec) -> None:
    path = tmp_path / "no_t.bin"
    write_dataflash(path, rec, temperature=False)
    assert read_dataflash(path).temp is None  # T = 0 in every record: no thermometer
    doc = inspect(path)
    assert doc["temperature"] == "not recorded" and doc["temperature_c"] is None
    assert doc["sources"][0]["temperature"] == "not recorded"
    text = CliRunner().invoke(app, ["inspect", str(path)]).stdout
    temperature = [line for line in text.splitlines() if line.startswith("temperature")]
    assert "temperature: not recorded" in temperature, text
    assert not any("0.0" in line for line in temperature), temperature


@pytest.mark.parametrize("version", [1, 2])
def test_bag_default_reads_the_fastest_imu_topic(tmp_path: Path, rec, version: int) -> None:
    if version == 1:
        path = tmp_path / "a.bag"
        write_rosbag1(path, rec, slow_every=100)
    else:
        path = write_rosbag2(tmp_path / "bag", rec, slow_every=100)
    got = read_rosbag(path)
    assert len(got) == N
    np.testing.assert_array_equal(got.acc, rec.acc)  # /imu/data, not /imu/slow (+1 on x)
    with pytest.raises(IngestError, match=r"/imu/slow is logged at 1 Hz, below the 10 Hz"):
        read_rosbag(path, imu_topic="/imu/slow")
    rates = {s["source"]: s["rate_hz"] for s in inspect(path)["sources"]}
    assert rates == {"/imu/data": 100.0, "/imu/slow": 1.0}
