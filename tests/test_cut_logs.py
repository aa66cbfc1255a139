"""Logs cut while written, read to their last whole record; the physics guards decide.

A six-position + integral run written one log per segment by each ecosystem's own library
(tests/log_writers.py: pyulog, ArduPilot's record layout with pymavlink's types,
mcap-ros2-support, rosbags' ROS 1 writer with 16 KiB chunks: a ROS 1 bag's whole record
is a chunk, and rosbag record's 768 KiB would hold a whole turn). Each rotation file is
cut at 20 of its record boundaries (a logger that lost power between two records) and the
run is read and solved again: every cut copy must be refused (a turn cut mid-way does not
end at rest; a turn cut in its last slow degrees does not close on whole turns) or give
every parameter within 10 standard uncertainties of the intact run's (noise terms left
out: a shorter record moves them within their own, wider, uncertainty). Without the
guards a ULog rotation cut at 1.5 rad/s was solved with its gyro scale 3134 standard
uncertainties off.
"""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from log_writers import write_dataflash, write_mcap, write_rosbag1, write_ulog
from test_ingest_formats_e2e import manifest

from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.solvers.integral import ROTATION_LABELS
from pipelines.ingest import IngestError, discover_runs, load_run
from pipelines.process import calibrate

CUTS = 20  # record-boundary cuts per rotation file
FAR = 10.0  # standard uncertainties of the intact run's parameter
SUFFIX = {"ulog": "ulg", "dataflash": "bin", "mcap": "mcap", "rosbag1": "bag"}
KIND = {"rosbag1": "rosbag"}  # the manifest's format.kind, where not the route's name
ROS1_CHUNK = 16 << 10  # bytes


def _write_run(folder: Path, route: str, segments) -> None:
    folder.mkdir(parents=True)
    entries = []
    for label, rec in segments.items():
        path = folder / f"{label}.{SUFFIX[route]}"
        if route == "ulog":
            write_ulog(path, rec, topics="combined")
        elif route == "dataflash":
            write_dataflash(path, rec)
        elif route == "rosbag1":
            write_rosbag1(path, rec, chunk_bytes=ROS1_CHUNK)
        else:
            write_mcap(path, rec)
        entries.append({"label": label, "file": path.name})
    (folder / "run.toml").write_text(
        manifest(f"SIM-CUT-{route}", {"kind": KIND.get(route, route)}, entries)
    )


def record_ends(route: str, data: bytes) -> list[int]:
    """Byte offsets where a record of the log ends (its top-level records)."""
    ends = []
    if route == "ulog":
        pos = 16
        while pos + 3 <= len(data):
            (size,) = struct.unpack_from("<H", data, pos)
            pos += 3 + size
            ends.append(pos)
    elif route == "dataflash":
        lengths = {128: 89}  # FMT; then each FMT record gives its type's length
        pos = 0
        while pos < len(data):
            kind = data[pos + 2]
            if kind == 128:
                lengths[data[pos + 3]] = data[pos + 4]
            pos += lengths[kind]
            ends.append(pos)
    elif route == "rosbag1":
        (padding,) = struct.unpack_from("<I", data, 13 + 4 + struct.unpack_from("<I", data, 13)[0])
        pos = 13 + 4 + struct.unpack_from("<I", data, 13)[0] + 4 + padding  # after the bag header
        while pos < len(data):
            (header,) = struct.unpack_from("<I", data, pos)
            (size,) = struct.unpack_from("<I", data, pos + 4 + header)
            pos += 8 + header + size
            ends.append(pos)
    else:
        pos = 8
        while pos + 9 <= len(data) and data[pos] != 0x02:  # up to the footer
            (size,) = struct.unpack_from("<Q", data, pos + 1)
            pos += 9 + size
            ends.append(pos)
    return [e for e in ends if e < len(data)]


def _solve(folder: Path):
    loaded = load_run(discover_runs([folder])[0])
    return loaded, calibrate(loaded)


@pytest.mark.slow
@pytest.mark.parametrize("route", ["ulog", "dataflash", "mcap", "rosbag1"])
def test_cut_rotation_logs_are_refused_or_near_the_intact_run(tmp_path: Path, route) -> None:
    rng = np.random.default_rng(4646)
    sim = six_position_integral_run(random_errors(rng), rng, static_s=10.0)
    intact_folder = tmp_path / "intact"
    _write_run(intact_folder, route, sim.segments)
    _, intact = _solve(intact_folder)
    reference = {n: p for n, p in intact.parameters.items() if ".noise." not in n}
    wrong, refused, read, findings, worst = [], 0, 0, 0, 0.0
    for label in ROTATION_LABELS:
        folder = tmp_path / label
        shutil.copytree(intact_folder, folder)
        victim = folder / f"{label}.{SUFFIX[route]}"
        data = victim.read_bytes()
        ends = record_ends(route, data)
        for cut in np.unique(np.linspace(0, len(ends) - 1, CUTS).round().astype(int)):
            victim.write_bytes(data[: ends[cut]])
            try:
                loaded, cal = _solve(folder)
            except (IngestError, ValueError) as exc:
                refused += 1
                assert str(victim) in str(exc) or label in str(exc), str(exc)
                continue
            read += 1
            findings += bool(loaded.findings)
            for name, p in reference.items():
                got = cal.parameters[name].value
                worst = max(worst, abs(got - p.value) / p.std)
                if abs(got - p.value) > FAR * p.std:
                    wrong.append((label, ends[cut], name, (got - p.value) / p.std))
    print(
        f"{route}: {refused} refused, {read} read ({findings} with a cut finding), "
        f"worst parameter of those read {worst:.2f} standard uncertainties off"
    )
    assert wrong == [], wrong
    assert refused + read == CUTS * len(ROTATION_LABELS)
    if route in ("mcap", "rosbag1"):  # no footer / no index: every cut copy read is named
        assert findings == read


VEHICLE_LOG = Path(__file__).parent / "realdata" / "pymavlink_test_log" / "test.BIN"


def test_a_moving_vehicles_log_is_no_static_bias_run(tmp_path: Path) -> None:
    """ArduPilot's published 64 KiB test log (pymavlink tests/test.BIN: a vehicle moving,
    cut while written) given as a static-bias run: read to its last whole record (24 bytes
    dropped, named), then refused because the record moved (gyro x scatters 3.2 deg/s,
    robust std: 64 x the mpu6000 profile's stated noise 0.05 deg/s), naming the file, the
    segment and what was measured. The relative motion check cannot see it: 45 samples
    over 0.97 s, too short for its windows, and all of them move."""
    from pipelines.process import process_run
    from storage.db import resolve_archive

    folder = tmp_path / "vehicle"
    folder.mkdir()
    shutil.copyfile(VEHICLE_LOG, folder / "test.BIN")
    text = manifest("APM-TEST", {"kind": "dataflash"}, [{"label": "rest", "file": "test.BIN"}])
    (folder / "run.toml").write_text(text.replace("six_position_integral", "static_bias"))
    loaded = load_run(discover_runs([folder])[0])
    (finding,) = loaded.findings
    assert finding["name"] == "record:cut:test.BIN" and finding["value"] == 24.0
    assert "from byte offset 65512 of 65536" in finding["detail"]
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    try:
        result = process_run(discover_runs([folder])[0], arch)
    finally:
        arch.dispose()
    assert result["status"] == "failed", result
    error = result["error"]
    assert "static segment 'rest'" in error and str(folder / "test.BIN") in error, error
    assert "moved" in error and "x its stated noise" in error, error
