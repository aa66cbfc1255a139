"""Damaged logs (ULog, DataFlash, ROS 1 and ROS 2 bags, MCAP) are refused naming the file.

Loggers lose power mid-write (a truncated last record) and storage duplicates or
loses chunks (time that repeats or goes back). ULog and DataFlash carry no
checksum, so the readers check that the records follow each other to the end of
the file, and every reader checks that time increases. A copy cut exactly at a
record boundary is a shorter log and reads as the intact one's first samples; any
other damaged copy must be refused with an IngestError naming the file. Files are
written by each ecosystem's own library (tests/log_writers.py, mcap-ros2-support).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from log_writers import write_dataflash, write_rosbag1, write_rosbag2, write_ulog
from test_ingest_mcap import write_run as write_mcap

from calib_core.recording import Recording
from pipelines.ingest import IngestError, discover_runs, load_run
from pipelines.ingest.dataflash_reader import read_dataflash
from pipelines.ingest.mcap_reader import read_mcap
from pipelines.ingest.rosbag_reader import read_rosbag
from pipelines.ingest.ulog_reader import read_ulog

N = 400
COPIES = 25  # damaged copies per kind and damage


def _rec() -> Recording:
    rng = np.random.default_rng(34)
    t = np.arange(N) / 100.0
    acc = rng.normal(0, 0.02, (N, 3)) + (0, 0, 9.81)
    return Recording(t=t, acc=acc, gyr=rng.normal(0, 0.01, (N, 3)), temp=np.full(N, 21.0))


def _write(kind: str, folder: Path) -> Path:
    rec = _rec()
    if kind == "ulog":
        write_ulog(folder / "a.ulg", rec, topics="both")
        return folder / "a.ulg"
    if kind == "dataflash":
        write_dataflash(folder / "a.bin", rec, instances=2)
        return folder / "a.bin"
    if kind == "rosbag1":
        write_rosbag1(folder / "a.bag", rec)
        return folder / "a.bag"
    if kind == "rosbag2":
        return write_rosbag2(folder / "bag", rec)
    write_mcap(folder / "a.mcap", n=N)
    return folder / "a.mcap"


READ = {
    "ulog": read_ulog,
    "dataflash": read_dataflash,
    "rosbag1": read_rosbag,
    "rosbag2": read_rosbag,
    "mcap": read_mcap,
}
KINDS = list(READ)


def _damaged(data: bytes, damage: str, rng: np.random.Generator) -> bytes:
    n = len(data)
    if damage == "truncated":
        return data[: int(rng.integers(n // 10, n - 1))]
    start = int(rng.integers(n // 10, n - n // 10))  # a chunk copied once more after itself
    stop = start + int(rng.integers(64, max(65, n // 5)))
    return data[:stop] + data[start:stop] + data[stop:]


CUT_READ = ("ulog", "dataflash", "mcap", "rosbag1")  # read to their last whole record when cut


@pytest.mark.parametrize("damage", ["truncated", "duplicated chunk"])
@pytest.mark.parametrize("kind", KINDS)
def test_damaged_copies_are_refused_or_an_intact_prefix(tmp_path: Path, kind, damage) -> None:
    intact_path = _write(kind, tmp_path)
    intact = READ[kind](intact_path)
    data = intact_path.read_bytes()
    rng = np.random.default_rng(list(KINDS).index(kind) * 2 + (damage == "truncated"))
    refused = 0
    for _ in range(COPIES):
        damaged = _damaged(data, damage, rng)
        intact_path.write_bytes(damaged)
        try:
            got = READ[kind](intact_path)
        except IngestError as exc:
            assert exc.file == str(intact_path), str(exc)
            refused += 1
            continue
        # Read: a log cut while written, read to its last whole record (the intact file's
        # first samples, the bytes dropped named), or a chunk of no IMU sample (a bag's
        # index, a ULog's info records) read twice.
        k = len(got)
        assert 0 < k <= len(intact) and (damage == "truncated" or k == len(intact)), (kind, k)
        np.testing.assert_array_equal(got.t, intact.t[:k])
        np.testing.assert_array_equal(got.acc, intact.acc[:k])
        np.testing.assert_array_equal(got.gyr, intact.gyr[:k])
        if damage == "truncated" and kind in CUT_READ:
            (finding,) = got.findings
            dropped = int(finding["value"])
            assert finding["name"] == f"record:cut:{intact_path.name}" and not finding["passed"]
            assert str(intact_path) in finding["detail"]
            assert (
                f"from byte offset {len(damaged) - dropped} of {len(damaged)}"
                in (finding["detail"])
            )
    if damage == "duplicated chunk" or kind not in CUT_READ:
        assert refused >= COPIES // 2, f"{kind} {damage}: only {refused} of {COPIES} refused"


@pytest.mark.parametrize("kind", ["ulog", "dataflash", "rosbag1"])
def test_cut_last_record_is_dropped_and_named(tmp_path: Path, kind) -> None:
    """A last record cut 5 bytes short (a logger that lost power) is dropped, the log read
    to its last whole record with a finding naming the file and the bytes dropped; the
    same bytes missing inside the log (a record's end gone) stay a refusal naming the
    byte offset."""
    path = _write(kind, tmp_path)
    whole = READ[kind](path)
    data = path.read_bytes()
    path.write_bytes(data[:-5])
    got = READ[kind](path)
    k = len(got)  # the last record may be of another topic than the IMU source read
    assert len(whole) - 2 <= k <= len(whole)
    np.testing.assert_array_equal(got.gyr, whole.gyr[:k])
    (finding,) = got.findings
    assert finding["name"] == f"record:cut:{path.name}" and str(path) in finding["detail"]
    record = int(finding["value"])
    assert f"from byte offset {len(data) - 5 - record} of {len(data) - 5}" in finding["detail"]
    middle = len(data) // 2
    path.write_bytes(data[:middle] + data[middle + 5 :])
    with pytest.raises(IngestError, match=r"byte offset \d+") as err:
        READ[kind](path)
    assert err.value.file == str(path)


def test_segment_window_past_the_data_is_refused(tmp_path: Path) -> None:
    """A window that runs past the end of the data while the unit still turns there (a
    log cut mid-rotation) is refused naming the segment and where the file ends, not
    read as a shorter turn; a window padded past a file that ends at rest still reads."""
    from test_ingest_formats_e2e import manifest

    folder = tmp_path / "run"
    folder.mkdir()
    rec = _rec()
    gyr = rec.gyr.copy()
    gyr[200:, 2] += np.deg2rad(90.0)  # turning at 90 deg/s from 2 s to the cut at 4 s
    write_ulog(folder / "cut.ulg", Recording(t=rec.t, acc=rec.acc, gyr=gyr), topics="combined")
    t0 = 5.0  # log_writers.T0_US: the log's clock starts 5 s after boot
    segments = [
        {"label": "x_up", "file": "cut.ulg", "start_s": t0, "end_s": t0 + 1.5},
        {"label": "z_ccw", "file": "cut.ulg", "start_s": t0 + 1.5, "end_s": t0 + 6.0},
    ]
    (folder / "run.toml").write_text(manifest("SIM-CUT", {"kind": "ulog"}, segments))
    refusal = r"segment 'z_ccw': the window \[6\.5, 11\.0\) s runs past the end .*still turns"
    with pytest.raises(IngestError, match=refusal) as err:
        load_run(discover_runs([folder])[0])
    assert err.value.field == "segments[1]" and "cut.ulg ends at 8.99 s" in str(err.value)
    segments[1] = {"label": "x_dn", "file": "cut.ulg", "start_s": t0 + 1.5, "end_s": t0 + 6.0}
    write_ulog(folder / "cut.ulg", rec, topics="combined")  # at rest at its end
    (folder / "run.toml").write_text(manifest("SIM-CUT", {"kind": "ulog"}, segments))
    assert len(load_run(discover_runs([folder])[0]).segments["x_dn"]) == N - 150


# --- Whole runs: no damaged copy archived `ok` with a wrong parameter ----------------------

RUN_COPIES = 30  # damaged copies per route (one rotation file each: where damage misleads)
FAR = 10.0  # standard uncertainties of the intact run's parameter


@pytest.mark.slow
@pytest.mark.parametrize("route", ["ulog", "dataflash"])
def test_no_damaged_copy_is_archived_ok_far_from_the_intact_run(tmp_path: Path, route) -> None:
    """A simulated six_position_integral run as one log per segment; copies with one
    rotation file truncated or holding a chunk twice go through `process_run` into one
    SQLite archive. Counted: copies archived `ok` with a parameter more than 10 standard
    uncertainties (of the intact run's) from the intact run's value; there must be none
    (without the record checks of the readers, 4 of the 30 copies per route were, each a
    truncated rotation file). Noise terms are
    left out: a shorter record moves them within their own, wider, uncertainty."""
    import shutil

    from test_ingest_logs_e2e import write_run

    from calib_core.simulate import random_errors, six_position_integral_run
    from pipelines.process import process_run
    from storage.db import resolve_archive

    rng = np.random.default_rng(3434)
    sim = six_position_integral_run(random_errors(rng), rng, static_s=10.0)
    intact_folder = tmp_path / "intact"
    write_run(intact_folder, route, sim.segments)
    archive = resolve_archive(str(tmp_path / "archive"))
    archive.upgrade()
    try:
        intact = process_run(discover_runs([intact_folder])[0], archive)
        assert intact["status"] == "ok", intact["error"]
        reference = {n: p for n, p in intact["parameters"].items() if ".noise." not in n}
        wrong, statuses = [], []
        labels = sorted(label for label in sim.segments if label[2:] in ("cw", "ccw"))
        for k in range(RUN_COPIES):
            folder = tmp_path / f"copy{k}"
            shutil.copytree(intact_folder, folder)
            toml = folder / "run.toml"  # another serial: a copy is not a duplicate run
            toml.write_text(toml.read_text().replace(f"SIM-{route.upper()}", f"SIM-{k}"))
            victim = next(folder.glob(f"{labels[k % len(labels)]}.*"))
            damage = "truncated" if k % 2 else "duplicated chunk"
            victim.write_bytes(_damaged(victim.read_bytes(), damage, rng))
            outcome = process_run(discover_runs([folder])[0], archive)
            statuses.append(outcome["status"])
            if outcome["status"] != "ok":
                assert "internal error" not in outcome["error"], outcome["error"]
                assert str(folder) in outcome["error"], outcome["error"]  # file or run named
                continue
            for name, p in reference.items():
                got = outcome["parameters"][name]["value"]
                if abs(got - p["value"]) > FAR * p["std"]:
                    wrong.append((k, victim.name, damage, name, got, p["value"], p["std"]))
    finally:
        archive.dispose()
    assert wrong == [], wrong
    assert statuses.count("failed") >= RUN_COPIES // 2, statuses


@pytest.mark.parametrize("kind", ["ulog", "dataflash", "rosbag1"])
def test_value_no_imu_can_read_is_refused_naming_the_record(tmp_path: Path, kind) -> None:
    """A flipped exponent bit makes a float32 reading 1e30: finite, but a damaged record."""
    rec = _rec()
    gyr = rec.gyr.copy()
    gyr[123, 1] = 1e30
    damaged = Recording(t=rec.t, acc=rec.acc, gyr=gyr, temp=rec.temp)
    path = tmp_path / {"ulog": "a.ulg", "dataflash": "a.bin", "rosbag1": "a.bag"}[kind]
    {
        "ulog": lambda: write_ulog(path, damaged, topics="both"),
        "dataflash": lambda: write_dataflash(path, damaged),
        "rosbag1": lambda: write_rosbag1(path, damaged),
    }[kind]()
    with pytest.raises(IngestError, match=r"record 123: gyr .* beyond what any IMU") as err:
        READ[kind](path)
    assert err.value.file == str(path) and err.value.field.endswith(".gyr")


def test_cut_ros1_bag_read_to_its_last_whole_chunk_damage_inside_refused(tmp_path: Path) -> None:
    """A ROS 1 bag cut while written (no index; rosbag record's chunks, here 4 KiB) is read
    to its last whole chunk, the same samples as the intact bag's first, with the finding
    naming the bytes dropped; a message record inside the first whole chunk with a damaged
    header (a field length of 1 MiB) is refused naming the chunk's byte offset."""
    path = tmp_path / "cut.bag"
    write_rosbag1(path, _rec(), chunk_bytes=4096)
    whole = read_rosbag(path)
    data = path.read_bytes()
    cut = data[: len(data) * 2 // 3]
    path.write_bytes(cut)
    got = read_rosbag(path)
    k = len(got)
    assert 0 < k < len(whole)
    np.testing.assert_array_equal(got.gyr, whole.gyr[:k])
    (finding,) = got.findings
    dropped = int(finding["value"])
    assert finding["name"] == "record:cut:cut.bag" and 0 < dropped < 4096 + 200
    assert f"from byte offset {len(cut) - dropped} of {len(cut)}" in finding["detail"]
    chunk = cut.index(b"compression=none", 4096 + 13)  # the first chunk's header
    op = cut.index(b"op=\x02", chunk)  # its first message record's op field
    damaged = bytearray(cut)
    damaged[op - 4 : op] = (1 << 20).to_bytes(4, "little")  # the field's length
    path.write_bytes(bytes(damaged))
    with pytest.raises(IngestError, match=r"the records of the chunk at byte offset \d+") as err:
        read_rosbag(path)
    assert err.value.file == str(path)
