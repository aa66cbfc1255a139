"""`calib process` on a static-bias record larger than the run's memory limit: streamed in
chunks (pipelines.process_streamed), the same parameters, conditions and as-found values
as the in-memory path, the raw file and the samples archived, the archive verified."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest

from calib_testing.calib_command import run_calib
from calib_testing.run_writers import dumps_toml
from storage import schema
from storage.db import resolve_archive
from storage.verify import verify

RATE = 100.0
N = 130_000  # 21.7 min at RATE: the sensor's temperature trend is judged (>= 10 min)
LIMIT_MB = 4  # the file is about five times larger
G = 9.80665


def write_static_csv(path: Path, seed: int = 3) -> None:
    """A still unit, z up: white noise, a gyro random walk, a spike, a warming sensor."""
    rng = np.random.default_rng(seed)
    t = 1.0 + np.arange(N) / RATE
    gyr = rng.normal(0.0, 5e-4, (N, 3)) + [0.01, -0.02, 0.005]
    gyr += np.cumsum(rng.normal(0.0, 2e-6, (N, 3)), axis=0)
    acc = rng.normal(0.0, 0.02, (N, 3)) + [0.05, -0.03, G + 0.1]
    gyr[5000:5002, 1] += 0.5  # the solve's n-sigma rule and its fill are exercised
    temp = 25.0 + 0.3 * (t - t[0]) / 3600.0 + rng.normal(0.0, 0.01, N)
    cols = {
        "time": t,
        **{f"acc_{a}": acc[:, i] for i, a in enumerate("xyz")},
        **{f"gyr_{a}": gyr[:, i] for i, a in enumerate("xyz")},
        "temp": temp,
    }
    pacsv.write_csv(pa.table(cols), path)


def manifest(started: str, settings: dict) -> dict:
    return {
        "schema_version": 1,
        "unit": {"serial": "SB-0001", "model": "TestIMU", "manufacturer": "Lab"},
        "run": {
            "started": started,
            "operator": "T. Est",
            "procedure": "static_bias",
            "tolerance_profile": "bench",
            "settings": {"up_axis": "+z", **settings},  # the default steps, none off
        },
        "site": {"latitude_deg": 48.137, "height_m": 519.0, "gravity_model": "helmert"},
        "environment": {
            "temperature_c": 21.0,
            "humidity_pct": 40.0,
            "pressure_hpa": 960.0,
            "warmup_min": 30.0,
        },
        "acquisition": {"settle_s": 60.0, "resolution_bits": 16},
        "format": {
            "kind": "csv",
            "time_column": "time",
            "acc_columns": ["acc_x", "acc_y", "acc_z"],
            "gyr_columns": ["gyr_x", "gyr_y", "gyr_z"],
            "temp_column": "temp",
        },
        "segments": [{"label": "record", "file": "imu.csv"}],
    }


def write_run(
    folder: Path, data: Path, started: str, settings: dict, window: dict | None = None
) -> Path:
    """A run of `data` (a copy) in `folder`; `window`: the segment's start_s / end_s."""
    folder.mkdir(parents=True)
    doc = manifest(started, settings)
    doc["segments"][0].update(window or {})
    if data.suffix == ".mcap":  # a ROS 2 log: the Imu topic, no temperature topic
        doc["format"] = {"kind": "mcap", "imu_topic": "/imu/data"}
        doc["segments"] = [{"label": "record", "file": "imu.mcap"}]
    shutil.copyfile(data, folder / doc["segments"][0]["file"])
    (folder / "run.toml").write_text(dumps_toml(doc), encoding="utf-8")
    return folder


def calib_process(folder: Path, archive: Path) -> tuple[dict, str]:
    """`calib process --json` in a child process: its one run and its stderr."""
    env = {
        **os.environ,
        "CALIB_ARCHIVE": str(archive),
        "CALIB_ISSUE_CERTIFICATES": "0",
        "CALIB_PROFILES": str(folder.parent / "profiles"),
    }
    proc = run_calib("process", str(folder), "--json", env=env)
    assert proc.stdout.startswith("{"), proc.stderr[-3000:]
    (run,) = json.loads(proc.stdout)["runs"]
    assert run["status"] == "ok", run["error"]
    return run, proc.stderr


def steps_of(archive: Path, run_id: str) -> dict[str, dict]:
    arch = resolve_archive(str(archive))
    from sqlalchemy import select

    with arch.engine().connect() as conn:
        run_pk = conn.execute(select(schema.Run.id).where(schema.Run.run_id == run_id)).scalar_one()
        rows = conn.execute(
            select(schema.ProcessingStep.name, schema.ProcessingStep.statistics).where(
                schema.ProcessingStep.run_id == run_pk
            )
        ).all()
    return {name: stats for name, stats in rows}


# float64 sums of N samples taken in another order (chunk by chunk, merged) differ by at
# most about N * eps of the sum of magnitudes (Higham, Accuracy and Stability of Numerical
# Algorithms, 4.2); the record's values sit within a few stds of their means, so relative
# to a parameter that bound is N * eps times a small factor: 1e3 * N * eps = 2.9e-8 covers
# it and the least-squares noise fits built on them, while one sample more or less, or a
# different outlier fill, moves a mean by ~1/N = 7.7e-6 relative.
REL = 1e3 * N * np.finfo(float).eps


def close(a: float | None, b: float | None, scale: float, rel: float = REL) -> bool:
    if a is None or b is None:
        return a is b
    return abs(a - b) <= rel * max(abs(b), scale)


def assert_streamed_as_in_memory(
    tmp_path: Path, runs: dict, rel: float, limit_mb: float, n: int, data: Path
) -> None:
    """The streamed run (``runs["streamed"]``, archived under tmp_path/archive-streamed)
    against the in-memory one (``runs["memory"]``): every parameter and check value within
    `rel`, the same checks and verdict, the streamed ingest step's figures, the raw file
    `data` archived byte for byte."""
    mem, got = runs["memory"], runs["streamed"]
    assert set(got["parameters"]) == set(mem["parameters"])
    for name, p in mem["parameters"].items():
        q = got["parameters"][name]
        assert q["unit"] == p["unit"], name
        assert close(q["value"], p["value"], p["std"] or 0.0, rel), (name, q, p)
        assert close(q["std"], p["std"], 0.0, rel), (name, q, p)
    by_name = {c["name"]: c for c in mem["checks"]}
    assert {c["name"] for c in got["checks"]} == set(by_name)
    assert "motion:record" in by_name and got["verdict"] == mem["verdict"]
    for c in got["checks"]:
        ref = by_name[c["name"]]
        assert c["passed"] == ref["passed"], c["name"]
        if isinstance(ref["value"], float):
            assert close(c["value"], ref["value"], 0.0, rel), (c, ref)
    ingest = steps_of(tmp_path / "archive-streamed", got["run_id"])["ingest"]
    assert ingest["streamed"]["memory_limit"] == limit_mb * 10**6
    assert ingest["streamed"]["bytes"] > 4 * ingest["streamed"]["memory_limit"]
    assert ingest["samples"] == {"record": n}
    arch = resolve_archive(str(tmp_path / "archive-streamed"))
    sha = hashlib.sha256(data.read_bytes()).hexdigest()
    assert any(p.name == sha for p in (arch.root / "objects").rglob("*"))


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("long") / "imu.csv"
    write_static_csv(path)
    assert path.stat().st_size > 4 * LIMIT_MB * 10**6
    return path


def write_profile(folder: Path, minutes: float = 20.0) -> None:
    """The MPU-6000 profile with a static record of `minutes` (the CSV record here is 21.7
    min), so a run passes and is the later run's earlier calibration."""
    shipped = Path(__file__).parents[1] / "pipelines" / "profiles" / "mpu6000.toml"
    text = shipped.read_text(encoding="utf-8").replace('name = "mpu6000"', 'name = "bench"')
    text = text.replace("[conditions]", f"[conditions]\nstatic_record_min = {{ low = {minutes} }}")
    folder.mkdir()
    (folder / "bench.toml").write_text(text, encoding="utf-8")


@pytest.mark.slow  # the 130,000-sample CSV with its as-found solve; fast: the windowed test below
def test_streamed_run_matches_the_in_memory_run(data, tmp_path):
    """The same record, in memory and streamed (a 4 MB limit), in two archives where an
    earlier run of the unit exists (so the as-found solve runs on both routes)."""
    write_profile(tmp_path / "profiles")
    earlier = write_run(tmp_path / "earlier", data, "2026-03-01T08:00:00+00:00", {})
    runs, stderr = {}, {}
    for route, settings in (("memory", {}), ("streamed", {"memory_limit_mb": LIMIT_MB})):
        archive = tmp_path / f"archive-{route}"
        calib_process(earlier, archive)
        folder = write_run(tmp_path / route, data, "2026-03-02T08:00:00+00:00", settings)
        runs[route], stderr[route] = calib_process(folder, archive)
        report = verify(resolve_archive(str(archive)))
        assert report.ok and report.orphans == [], (report.problems, report.orphans)
    mem, got = runs["memory"], runs["streamed"]

    # the same document, the same parameters to the rounding of chunked sums
    assert set(got) == set(mem)
    assert set(got["parameters"]) == set(mem["parameters"])
    for name, p in mem["parameters"].items():
        q = got["parameters"][name]
        assert q["unit"] == p["unit"], name
        assert close(q["value"], p["value"], p["std"] or 0.0), (name, q, p)
        assert close(q["std"], p["std"], 0.0), (name, q, p)

    # the same checks, the motion check of the record included (made from the stream's
    # windows: tests/test_static_motion.py), the same verdict
    by_name = {c["name"]: c for c in mem["checks"]}
    assert {c["name"] for c in got["checks"]} == set(by_name)
    assert "motion:record" in by_name
    assert mem["verdict"] == "pass" and got["verdict"] == "pass"
    for c in got["checks"]:
        ref = by_name[c["name"]]
        assert c["passed"] == ref["passed"], c["name"]
        if isinstance(ref["value"], float):
            assert close(c["value"], ref["value"], 0.0), (c, ref)
    motion = next(c for c in got["checks"] if c["name"] == "motion:record")
    assert motion["passed"] and close(motion["limit"], by_name["motion:record"]["limit"], 0.0)
    drift = by_name["condition:temperature_drift_c_per_h"]["value"]
    assert drift == pytest.approx(0.3, abs=0.03)  # the written trend: judged on both routes

    # as found: the earlier run's calibration applied to the samples, solved again
    found = {
        route: steps_of(tmp_path / f"archive-{route}", runs[route]["run_id"])["as_found"]
        for route in runs
    }
    rows = {r["parameter"]: r for r in found["memory"]["parameters"]}
    assert rows and len(found["streamed"]["parameters"]) == len(rows)
    for r in found["streamed"]["parameters"]:
        ref = rows[r["parameter"]]
        assert r["verdict"] == ref["verdict"], (r, ref)
        # the error as found is ~0 here (the same record): compared on the as-left's scale
        scale = max(abs(ref["as_left"]), ref["std"] or 0.0)
        for key in ("earlier", "as_left", "error", "std", "U"):
            assert close(r[key], ref[key], scale), (key, r, ref)

    # streamed: the raw file archived byte for byte, the samples the file's rows
    arch = resolve_archive(str(tmp_path / "archive-streamed"))
    stored = arch.root / "objects"
    sha = hashlib.sha256(data.read_bytes()).hexdigest()
    assert any(p.name == sha for p in stored.rglob("*"))
    ingest = steps_of(tmp_path / "archive-streamed", got["run_id"])["ingest"]
    assert ingest["streamed"]["memory_limit"] == LIMIT_MB * 10**6
    assert ingest["streamed"]["bytes"] > 4 * ingest["streamed"]["memory_limit"]
    assert ingest["samples"] == {"record": N}
    files = sorted((arch.root / "samples").rglob("*.parquet"))
    table = pq.read_table([f for f in files if got["run_id"] in f.name][0])
    assert table.num_rows == N and table.column("segment").unique().to_pylist() == ["record"]
    src = pacsv.read_csv(data)
    assert np.array_equal(table.column("t").to_numpy(), src.column("time").to_numpy())
    assert np.array_equal(table.column("temp").to_numpy(), src.column("temp").to_numpy())


MCAP_N = 24_000  # 4 min at RATE: 371-byte messages, the file 8 times a 1 MB limit
MCAP_LIMIT_MB = 1


@pytest.fixture(scope="module")
def mcap_data(tmp_path_factory) -> Path:
    """A still unit as ROS 2 sensor_msgs/msg/Imu messages written by mcap-ros2-support's
    Writer (tests/test_ingest_mcap.py's message), a spike on one gyro axis."""
    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer as Ros2Writer
    from test_ingest_mcap import IMU_MSGDEF, T0_NS, imu_message

    rng = np.random.default_rng(5)
    gyr = rng.normal(0.0, 5e-4, (MCAP_N, 3)) + [0.01, -0.02, 0.005]
    gyr += np.cumsum(rng.normal(0.0, 2e-6, (MCAP_N, 3)), axis=0)
    acc = rng.normal(0.0, 0.02, (MCAP_N, 3)) + [0.05, -0.03, G + 0.1]
    gyr[5000:5002, 1] += 0.5
    stamps = T0_NS + int(1e9 / RATE) * np.arange(MCAP_N, dtype=np.int64)
    path = tmp_path_factory.mktemp("mcap") / "imu.mcap"
    with path.open("wb") as fh:
        w = Ros2Writer(fh, chunk_size=64 << 10, compression=CompressionType.NONE)
        schema = w.register_msgdef("sensor_msgs/msg/Imu", IMU_MSGDEF)
        for i in range(MCAP_N):
            msg = imu_message(int(stamps[i]), acc[i], gyr[i])
            w.write_message("/imu/data", schema, msg, log_time=int(stamps[i]) + 250_000)
        w.finish()
    assert path.stat().st_size > 4 * MCAP_LIMIT_MB * 10**6
    return path


@pytest.mark.slow  # fast: test_mcap_stream (the streamer), the CSV route below (calib process)
def test_streamed_mcap_run_matches_the_in_memory_run(mcap_data, tmp_path):
    """`calib process` of a ROS 2 Imu log larger than a 1 MB limit (`stream_mcap`) gives
    the in-memory run's parameters and checks to the rounding of chunked sums (the bound
    REL above, for this record's N), its motion check included; the archive verifies."""
    write_profile(tmp_path / "profiles", minutes=3.0)
    rel = 1e3 * MCAP_N * np.finfo(float).eps
    runs = {}
    for route, settings in (("memory", {}), ("streamed", {"memory_limit_mb": MCAP_LIMIT_MB})):
        archive = tmp_path / f"archive-{route}"
        folder = write_run(tmp_path / route, mcap_data, "2026-03-02T08:00:00+00:00", settings)
        runs[route], _ = calib_process(folder, archive)
        report = verify(resolve_archive(str(archive)))
        assert report.ok and report.orphans == [], (report.problems, report.orphans)
    assert_streamed_as_in_memory(tmp_path, runs, rel, MCAP_LIMIT_MB, MCAP_N, mcap_data)


def small_run(tmp_path: Path, name: str, settings: dict, unit: dict | None = None) -> Path:
    """A 1 MB-limit run of a 1.3 MB record (in-process: `process_run`)."""
    rng = np.random.default_rng(4)
    n = 12_000
    t = np.arange(n) / RATE
    cols = {"time": t}
    for a in "xyz":
        cols[f"acc_{a}"] = rng.normal(0.0, 0.02, n) + (G if a == "z" else 0.0)
    for a in "xyz":
        cols[f"gyr_{a}"] = rng.normal(0.0, 1e-3, n)
    cols["gyr_y"][6000] = 40.0  # rad/s: beyond a 2000 deg/s gyro
    cols["temp"] = np.full(n, 25.0)
    folder = tmp_path / name
    folder.mkdir()
    pacsv.write_csv(pa.table(cols), folder / "imu.csv")
    doc = manifest("2026-03-02T08:00:00+00:00", {"memory_limit_mb": 1, **settings})
    doc["unit"].update(unit or {})
    (folder / "run.toml").write_text(dumps_toml(doc), encoding="utf-8")
    assert (folder / "imu.csv").stat().st_size > 10**6
    return folder


def test_a_memory_limit_that_is_not_a_number_of_mb_is_refused_naming_the_setting(tmp_path):
    from pipelines.ingest import discover_runs
    from pipelines.process import process_run

    folder = small_run(tmp_path, "run", {"memory_limit_mb": 0.5})
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    out = process_run(discover_runs([folder])[0], arch)
    assert out["status"] == "failed" and "expected a number >= 1" in out["error"], out
    assert "memory_limit_mb" in out["error"]
    assert not any(p.is_file() for p in (arch.root / "objects").rglob("*"))


def test_a_step_that_needs_the_whole_record_reads_it_into_memory_whatever_its_size(
    tmp_path, monkeypatch
):
    """A low-pass filter (forward and backward over the whole record) is not refused above
    the memory limit: the record is read into memory, so the run is the one without a
    limit (the same checks and their values, bit for bit)."""
    from pipelines.ingest import discover_runs
    from pipelines.process import process_run

    write_profile(tmp_path / "profiles", minutes=1.0)
    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path / "profiles"))
    outs = {}
    for name, limit in (("limited", 1), ("free", 1000)):
        folder = small_run(
            tmp_path, name, {"lowpass": {"cutoff_hz": 10.0}, "memory_limit_mb": limit}
        )
        arch = resolve_archive(str(tmp_path / f"archive-{name}"))
        arch.upgrade()
        outs[name] = process_run(discover_runs([folder])[0], arch)
        assert outs[name]["status"] == "ok", outs[name]["error"]
        steps = steps_of(tmp_path / f"archive-{name}", outs[name]["run_id"])
        assert "lowpass" in steps and "streamed" not in steps["ingest"], steps["ingest"]
    assert outs["limited"]["checks"] == outs["free"]["checks"]
    assert outs["limited"]["verdict"] == outs["free"]["verdict"]


# Timings: the only figures of a step that may differ between two runs of one record.
TIMINGS = {"seconds", "preprocess_seconds"}


def all_steps(archive: Path, run_id: str) -> list[tuple[str, dict, dict]]:
    """(name, settings, statistics without timings) of a run's steps, in their order:
    the settings without memory_limit_mb (the one setting two routes' runs differ by),
    the ingest step without its figures of the streamed route (memory limit, bytes), the
    run's own id as "<this run>"."""
    from sqlalchemy import select

    arch = resolve_archive(str(archive))
    with arch.engine().connect() as conn:
        run_pk = conn.execute(select(schema.Run.id).where(schema.Run.run_id == run_id)).scalar_one()
        step = schema.ProcessingStep
        rows = conn.execute(
            select(step.name, step.settings, step.statistics)
            .where(step.run_id == run_pk)
            .order_by(step.id)
        ).all()
    out = []
    for name, settings, stats in rows:
        settings = {k: v for k, v in (settings or {}).items() if k != "memory_limit_mb"}
        stats = {k: v for k, v in (stats or {}).items() if k not in TIMINGS}
        if name == "ingest":
            stats.pop("streamed", None)
        # the run's own id (its manifest's hash: the memory limit in it) named as such
        stats = json.loads(json.dumps(stats).replace(run_id, "<this run>"))
        out.append((name, settings, stats))
    return out


def same_values(a, b, rel: float, where: str) -> None:
    """a and b equal, their floats to `rel` relative, walking dicts and lists."""
    if isinstance(b, dict):
        assert isinstance(a, dict) and set(a) == set(b), (where, a, b)
        for k in b:
            same_values(a[k], b[k], rel, f"{where}.{k}")
    elif isinstance(b, list | tuple):
        assert type(a) is type(b) and len(a) == len(b), (where, a, b)
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same_values(x, y, rel, f"{where}[{i}]")
    elif isinstance(b, float) and isinstance(a, float):
        assert abs(a - b) <= rel * abs(b) or a == b, (where, a, b)
    else:
        assert a == b, (where, a, b)


def test_default_settings_and_a_time_window_give_the_same_run_at_any_memory_limit(data, tmp_path):
    """The static-bias samples (spikes, a warming sensor) with a segment time window and
    default settings, no step turned off, at the default memory limit (read into memory)
    and at one that forces chunks: nothing refused, the same parameters, checks and
    steps. One science on both routes (the in-memory solve is the chunked one of one
    chunk), so the values differ only by the order of chunked sums: 1e-12 relative."""
    write_profile(tmp_path / "profiles", minutes=15.0)
    window = {"start_s": 101.0, "end_s": 1201.0}  # 110000 of the N samples
    runs = {}
    for route, settings in (("memory", {}), ("streamed", {"memory_limit_mb": LIMIT_MB})):
        folder = write_run(tmp_path / route, data, "2026-03-02T08:00:00+00:00", settings, window)
        runs[route], _ = calib_process(folder, tmp_path / f"archive-{route}")
    mem, got = runs["memory"], runs["streamed"]
    ingest = steps_of(tmp_path / "archive-streamed", got["run_id"])["ingest"]
    assert ingest["streamed"]["memory_limit"] == LIMIT_MB * 10**6  # chunks, the other not
    assert "streamed" not in steps_of(tmp_path / "archive-memory", mem["run_id"])["ingest"]
    assert ingest["samples"] == {"record": 110_000}
    same_values(got["parameters"], mem["parameters"], 1e-12, "parameters")
    assert {c["name"] for c in mem["checks"]} >= {
        "motion:record",
        "condition:temperature_drift_c_per_h",
    }
    same_values(
        sorted(got["checks"], key=lambda c: c["name"]),
        sorted(mem["checks"], key=lambda c: c["name"]),
        1e-12,
        "checks",
    )
    assert got["verdict"] == mem["verdict"] == "pass"
    steps = {
        route: all_steps(tmp_path / f"archive-{route}", runs[route]["run_id"]) for route in runs
    }
    assert [s[0] for s in steps["memory"]] == [s[0] for s in steps["streamed"]]
    same_values(steps["streamed"], steps["memory"], 1e-12, "steps")


@pytest.mark.parametrize(
    ("window", "said"),
    [
        ({"start_s": 5000.0, "end_s": 6000.0}, "lies 4699.01 s outside the record and 0 s"),
        ({"start_s": 5000.0}, "holds no samples"),
    ],
)
def test_a_window_outside_the_data_or_without_samples_is_refused_on_both_routes(
    data, tmp_path, window, said
):
    """A window mostly outside the data, or without samples: the in-memory reader's
    refusal on the streamed route too (the same message, the data's span named)."""
    for route, settings in (("memory", {}), ("streamed", {"memory_limit_mb": LIMIT_MB})):
        folder = write_run(tmp_path / route, data, "2026-03-02T08:00:00+00:00", settings, window)
        from pipelines.ingest import discover_runs
        from pipelines.process import process_run

        arch = resolve_archive(str(tmp_path / f"archive-{route}"))
        arch.upgrade()
        out = process_run(discover_runs([folder])[0], arch)
        assert out["status"] == "failed", out
        assert said in out["error"] and "imu.csv spans 1 .. 1300.99 s" in out["error"], out


def test_streamed_route_refuses_a_reading_at_the_sensor_range(tmp_path):
    """The range check of the in-memory ingest, from the first pass's extremes: the same
    message (file, time, axis), nothing archived or left behind."""
    from pipelines.ingest import discover_runs
    from pipelines.process import process_run

    folder = small_run(tmp_path, "run", {}, {"gyro_range_dps": 2000.0})
    arch = resolve_archive(str(tmp_path / "archive"))
    arch.upgrade()
    out = process_run(discover_runs([folder])[0], arch)
    assert out["status"] == "failed", out
    assert "gyro y reads" in out["error"] and "t = 60.000 s" in out["error"], out["error"]
    # neither the raw copy nor the samples' Parquet (temporary files) left behind
    assert not any(p.is_file() for p in (arch.root / "samples").rglob("*"))
    assert not any(p.is_file() for p in (arch.root / "objects").rglob("*"))
