"""Archiving runs: idempotence, revisions, atomicity, concurrency, queries; on both back ends.

The expected values are the inputs themselves (what went in must come out,
exactly: floats round-trip bit-for-bit through both back ends' double columns)
and row counts derived from the inputs.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import asdict, replace
from datetime import UTC, date, datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from sqlalchemy import func, select

from calib_core.calibration import Calibration, CheckResult, Parameter, StepRecord
from calib_core.settings import SettingError
from storage import queries, rawstore
from storage.archive import ArchiveError, archive_run
from storage.db import Archive, default_archive_url, resolve_archive
from storage.queries.records import EquipmentUse, Unit
from storage.run_input import RawFileIn, RunIn, raw_hash_of, run_id_of
from storage.schema import TABLES, Base
from storage.verify import verify

PROTOCOL = "0012_result.txt"


def make_run(
    src: Path,
    *,
    serial: str = "0012",
    seed: int = 0,
    started_at: datetime = datetime(2024, 5, 1, 8, 30, tzinfo=UTC),
    verdict: str = "pass",
    samples: bool = True,
) -> RunIn:
    """A processed run with random raw bytes and parameters (a different run per seed)."""
    rng = np.random.default_rng(seed)
    src.mkdir(parents=True, exist_ok=True)
    raw = []
    for axis in "xyz":
        data = rng.bytes(1000 + int(rng.integers(0, 500)))
        path = src / f"{serial}_{axis}_up.txt"
        path.write_bytes(data)
        raw.append(RawFileIn(path, path.name, hashlib.sha256(data).hexdigest(), len(data), "txt"))
    cal = Calibration(procedure="six_position", gravity=9.80665)
    for name in ("acc.bias.x", "acc.bias.y", "acc.scale.z", "gyr.bias.x"):
        cal.add(name, rng.normal(0, 0.1), abs(rng.normal(0, 1e-3)))
    doc = cal.to_dict()
    n = 200
    table = pa.table(
        {
            "t_ns": pa.array(np.arange(n, dtype=np.int64) * 20_000_000),
            "ax": pa.array(rng.normal(0, 1, n)),
        }
    )
    return RunIn(
        serial=serial,
        device_model="MPU-6000",
        manufacturer="InvenSense",
        specification="consumer grade",
        started_at=started_at,
        operator="A. Tester",
        procedure="six_position",
        site={"latitude_deg": 55.75, "height_m": 150.0},
        gravity=9.8155,
        environment={"temperature_c": 20.5, "humidity_pct": 45},
        equipment=[
            {
                "kind": "rate_table",
                "serial": "RT-7",
                "model": "AC1120",
                "accuracy_class": "0.01%",
                "calibration_due": "2024-12-31",
                "calibrated_on": date(2023, 12, 31),
            },
        ],
        manifest_text="serial = '0012'\n",
        tolerance_profile="mpu6000",
        raw_files=raw,
        settings={"outlier_sigma": 5.0, "filter": "none"},
        software_version="0.1.0",
        source_revision="abc123",
        steps=[
            StepRecord("ingest", {}, {"rows": 3000}, "0.1.0"),
            StepRecord("solve", {"method": "lsq"}, {"cond": 1.7}, "0.1.0"),
        ],
        calibration=doc,
        parameters=[
            Parameter(k, v["value"], v["std"], v["unit"]) for k, v in doc["parameters"].items()
        ],
        checks=[
            CheckResult("acc.bias.x", doc["parameters"]["acc.bias.x"]["value"], 0.5, True, ""),
        ],
        verdict=verdict,
        profile_name="mpu6000",
        profile_version="1",
        samples=table if samples else None,
    )


def counts(archive: Archive) -> dict[str, int]:
    with archive.engine().connect() as conn:
        return {
            t: conn.execute(select(func.count()).select_from(Base.metadata.tables[t])).scalar_one()
            for t in TABLES
        }


def file_tree(root: Path) -> dict[str, tuple[int, int]]:
    """Files under root (the database files excluded) with size and mtime."""
    return {
        p.relative_to(root).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in root.rglob("*")
        if p.is_file() and not p.name.startswith("archive.sqlite")
    }


# --- one run -------------------------------------------------------------------------


def test_archive_a_run_and_read_it_back(archive: Archive, tmp_path: Path) -> None:
    run = make_run(tmp_path / "in")
    res = archive_run(archive, run, {PROTOCOL: b"protocol text"})

    raw_hash = raw_hash_of([f.sha256 for f in run.raw_files])
    assert res.status == "ok" and res.revision == 1
    assert res.run_id == run_id_of(raw_hash)
    assert res.run_dir == archive.root / "runs" / "0012" / "2024-05-01" / res.run_id
    assert (res.run_dir / PROTOCOL).read_bytes() == b"protocol text"
    assert res.files == {PROTOCOL: res.run_dir / PROTOCOL}
    for f in run.raw_files:  # content-addressed copies, byte for byte
        assert rawstore.object_path(archive.root, f.sha256).read_bytes() == f.path.read_bytes()

    assert counts(archive) == {
        "devices": 1,
        "equipment": 1,
        "runs": 1,
        "run_equipment": 1,
        "raw_files": 3,
        "calibrations": 1,
        "processing_steps": 2,
        "parameters": 4,
        "check_results": 1,
        "thermal_models": 0,
        "seals": 1,  # the revision's sealed record (storage.seal)
        "audit_events": 1,  # "archived"
        "unit_latest": 1,  # the unit's latest run and valid calibration (derived)
        "unit_latest_values": 4,  # that calibration's parameters, one per name (derived)
        "validations": 0,  # none until `calib validate`
    }
    s = queries.run_summary(archive, res.run_id)
    assert s.raw_hash == raw_hash
    assert s.started_at == run.started_at and s.started_at.tzinfo == UTC
    assert s.device == Unit("0012", "MPU-6000", "InvenSense", "consumer grade")
    assert (s.site, s.environment) == (run.site.as_dict(), run.environment.as_dict())
    assert s.gravity == run.gravity
    assert s.equipment == [
        EquipmentUse(
            "rate_table", "AC1120", "RT-7", "0.01%", date(2024, 12, 31), date(2023, 12, 31)
        )
    ]
    assert sorted((r.name, r.sha256, r.size) for r in s.raw_files) == sorted(
        (f.name, f.sha256, f.size) for f in run.raw_files
    )
    cal = s.calibration
    assert cal.revision == 1 and cal.verdict == "pass" and cal.superseded_by is None
    assert {p.name: (p.value, p.std) for p in cal.parameters} == {
        p.name: (p.value, p.std) for p in run.parameters
    }
    assert [st.name for st in cal.steps] == ["ingest", "solve"]
    assert cal.steps[1].statistics == {"cond": 1.7}
    assert cal.checks[0].limit == 0.5 and cal.checks[0].passed is True

    exported = queries.export_calibration(archive, res.run_id)
    assert exported["calibration"] == run.calibration
    assert Calibration.from_dict(exported["calibration"]).to_dict() == run.calibration
    assert exported["unit"]["serial"] == "0012"
    assert exported["run"]["started_at"] == "2024-05-01T08:30:00+00:00"

    # Samples: serial "0012" must stay a string through the hive partitions.
    back = rawstore.read_samples(archive.root, "0012")
    assert back.column("serial").type == pa.string()
    assert set(back.column("serial").to_pylist()) == {"0012"}
    assert back.column("t_ns").to_pylist() == run.samples.column("t_ns").to_pylist()
    assert s.samples_path == f"samples/serial=0012/date=2024-05-01/{res.run_id}.parquet"


def test_identical_rearchive_is_a_duplicate_and_writes_nothing(
    archive: Archive, tmp_path: Path
) -> None:
    run = make_run(tmp_path / "in")
    first = archive_run(archive, run, {PROTOCOL: b"p"})
    rows, files = counts(archive), file_tree(archive.root)
    # The same files listed in another order are the same run.
    again = archive_run(archive, replace(run, raw_files=run.raw_files[::-1]), {PROTOCOL: b"p"})
    assert again.status == "duplicate"
    assert (again.run_id, again.revision, again.calibration_id) == (
        first.run_id,
        1,
        first.calibration_id,
    )
    assert first.run_id in again.message
    assert counts(archive) == rows
    assert file_tree(archive.root) == files


def test_new_settings_or_software_add_revisions_that_supersede(
    archive: Archive, tmp_path: Path
) -> None:
    run = make_run(tmp_path / "in")
    r1 = archive_run(archive, run, {PROTOCOL: b"rev 1"})
    rows1 = counts(archive)
    run2 = replace(
        run,
        settings={**run.settings, "outlier_sigma": 4.0},
        parameters=[replace(p, value=p.value + 1e-3) for p in run.parameters],
    )
    r2 = archive_run(archive, run2, {PROTOCOL: b"rev 2"})
    assert (r2.status, r2.run_id, r2.revision) == ("revised", r1.run_id, 2)
    r3 = archive_run(archive, replace(run2, software_version="0.2.0"), {PROTOCOL: b"rev 3"})
    assert (r3.status, r3.revision) == ("revised", 3)

    # Only the per-calibration rows grew; nothing was deleted.
    per_cal = {
        "calibrations": 1,
        "processing_steps": 2,
        "parameters": 4,
        "check_results": 1,
        "seals": 1,
        "audit_events": 1,
    }
    assert counts(archive) == {t: n + 2 * per_cal.get(t, 0) for t, n in rows1.items()}
    # Every revision's protocol kept, none overwritten.
    assert (r1.run_dir / PROTOCOL).read_bytes() == b"rev 1"
    assert r2.files[PROTOCOL] == r1.run_dir / "revision-2" / PROTOCOL
    assert r2.files[PROTOCOL].read_bytes() == b"rev 2"
    assert r3.files[PROTOCOL].read_bytes() == b"rev 3"

    h = queries.history(archive, "0012")
    assert h["revision"].tolist() == [1, 2, 3]
    assert h["superseded"].tolist() == [True, True, False]
    ph = queries.parameter_history(archive, "0012", "acc.bias.x", include_superseded=True)
    v1 = next(p.value for p in run.parameters if p.name == "acc.bias.x")
    assert ph["value"].tolist() == [v1, v1 + 1e-3, v1 + 1e-3]
    cur = queries.parameter_history(archive, "0012", "acc.bias.x")
    assert cur["revision"].tolist() == [3]
    assert queries.run_summary(archive, r1.run_id).calibration.revision == 3
    assert queries.export_calibration(archive, r1.run_id, revision=1)["superseded"] is True

    # Going back to revision 1's settings and software: that processing exists already.
    back = archive_run(archive, run)
    assert (back.status, back.revision) == ("duplicate", 1)
    assert "revision 1" in back.message


# --- rejected input and failures --------------------------------------------------------


def test_bad_serial_is_rejected_before_any_file_is_written(
    archive: Archive, tmp_path: Path
) -> None:
    run = replace(make_run(tmp_path / "in"), serial="../../etc")
    with pytest.raises(ValueError, match=r"invalid serial '\.\./\.\./etc'"):
        archive_run(archive, run)
    ok_run = make_run(tmp_path / "in")
    with pytest.raises(ValueError, match="invalid extra file name"):
        archive_run(archive, ok_run, {"../escape.txt": b"x"})
    assert file_tree(archive.root) == {}
    assert not (tmp_path / "etc").exists()
    assert set(counts(archive).values()) == {0}


def test_raw_file_changed_since_hashing_is_refused(archive: Archive, tmp_path: Path) -> None:
    run = make_run(tmp_path / "in")
    run.raw_files[1].path.write_bytes(b"changed after ingest")
    with pytest.raises(ValueError, match=f"raw file .*{run.raw_files[1].name}.*hashes to"):
        archive_run(archive, run, {PROTOCOL: b"p"})
    assert set(counts(archive).values()) == {0}
    assert not (archive.root / "runs").exists() or not any((archive.root / "runs").rglob("*.txt"))


def test_failing_transaction_leaves_no_rows_and_no_run_folder(
    archive: Archive, tmp_path: Path
) -> None:
    good = make_run(tmp_path / "a", seed=1)
    bad = make_run(tmp_path / "b", seed=2)
    # std < 0 passes the Python checks but violates the parameters table's CHECK
    # constraint: the failure comes from the database after the run, calibration
    # and step rows have already been sent in the same transaction.
    bad.parameters[-1] = replace(bad.parameters[-1], std=-1.0)
    with pytest.raises(ArchiveError, match="refused the rows"):
        archive_run(archive, bad, {PROTOCOL: b"p"})
    assert set(counts(archive).values()) == {0}
    bad_id = run_id_of(raw_hash_of([f.sha256 for f in bad.raw_files]))
    assert not list((archive.root / "runs").rglob(bad_id))
    assert rawstore.read_samples(archive.root).num_rows == 0

    # A failing revision leaves the archived run as it was.
    r1 = archive_run(archive, good, {PROTOCOL: b"rev 1"})
    rows = counts(archive)
    bad_rev = replace(good, settings={"other": True})
    bad_rev.parameters = [replace(good.parameters[0], std=-1.0), *good.parameters[1:]]
    with pytest.raises(ArchiveError):
        archive_run(archive, bad_rev, {PROTOCOL: b"rev 2"})
    assert counts(archive) == rows
    assert not (r1.run_dir / "revision-2").exists()
    assert (r1.run_dir / PROTOCOL).read_bytes() == b"rev 1"
    assert queries.history(archive, "0012")["superseded"].tolist() == [False]


def test_same_raw_files_under_another_serial_are_refused(archive: Archive, tmp_path: Path) -> None:
    run = make_run(tmp_path / "in")
    archive_run(archive, run)
    with pytest.raises(ArchiveError, match="already archived as run .* of serial '0012'"):
        archive_run(archive, replace(run, serial="0013"))


def test_naive_datetime_is_refused(archive: Archive, tmp_path: Path) -> None:
    run = replace(make_run(tmp_path / "in"), started_at=datetime(2024, 5, 1, 8, 30))
    with pytest.raises(ValueError, match="started_at: expected a time-zone-aware"):
        archive_run(archive, run)


def test_the_archive_boundary_takes_objects_not_dicts(archive: Archive, tmp_path: Path) -> None:
    """Parameters, checks and steps cross into storage as calib_core objects: a dict (the
    old untyped boundary) is refused by name before anything is written."""
    run = make_run(tmp_path / "in")
    kinds = {"parameters": "Parameter", "checks": "CheckResult", "steps": "StepRecord"}
    for name, kind in kinds.items():
        dicts = [asdict(item) for item in getattr(run, name)]
        with pytest.raises(TypeError, match=rf"^{name}\[0\]: expected a {kind}, got dict$"):
            archive_run(archive, replace(run, **{name: dicts}))
    assert set(counts(archive).values()) == {0}
    assert archive_run(archive, run).status == "ok"


def test_site_environment_and_equipment_are_typed_by_name(tmp_path: Path) -> None:
    """A RunIn's site, environment and equipment are typed when it is made, as the archive
    keeps them (whole numbers of a number as floats, texts stripped); a wrong key or value
    is refused naming it."""
    run = make_run(tmp_path / "in")
    typed = replace(run, environment={"humidity_pct": 45, "vibration": " none "})
    assert typed.environment.humidity_pct == 45.0 and type(typed.environment.humidity_pct) is float
    assert typed.environment.vibration == "none" and typed.environment.temperature_c is None
    assert typed.site.latitude_deg == 55.75 and typed.equipment[0].calibration_due == date(
        2024, 12, 31
    )
    for change, message in (
        ({"site": {"latitud_deg": 55.0}}, r"site\.latitud_deg: unknown setting of \[site\]; "
         "did you mean latitude_deg"),
        ({"environment": {"humidity_pct": 140}}, r"environment\.humidity_pct: expected a number "
         r"in \[0, 100\], got 140"),
        ({"equipment": [{"kind": "cube"}]}, r"equipment\[0\]\.serial: required field"),
        ({"equipment": [{"kind": "cube", "serial": "C1", "calibration_due": "soon"}]},
         r"equipment\[0\]\.calibration_due: expected a date \(YYYY-MM-DD\), got 'soon'"),
    ):  # fmt: skip
        with pytest.raises(SettingError, match=message):
            replace(run, **change)


@pytest.mark.parametrize("workers", [2, 4])
def test_concurrent_archiving_of_one_run_keeps_one_copy(
    archive: Archive, tmp_path: Path, workers: int
) -> None:
    run = make_run(tmp_path / "in")
    barrier = threading.Barrier(workers)
    results, errors = [], []

    def work() -> None:
        try:
            barrier.wait(timeout=10)
            results.append(archive_run(archive, run, {PROTOCOL: b"p"}))
        except BaseException as exc:  # noqa: BLE001 - asserted below
            errors.append(exc)

    threads = [threading.Thread(target=work) for _ in range(workers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert errors == []
    assert sorted(r.status for r in results) == ["duplicate"] * (workers - 1) + ["ok"]
    assert len({r.run_id for r in results}) == 1
    c = counts(archive)
    assert (c["runs"], c["calibrations"], c["parameters"], c["devices"]) == (1, 1, 4, 1)
    assert (results[0].run_dir / PROTOCOL).read_bytes() == b"p"


# --- time and queries ---------------------------------------------------------------------


def test_datetimes_come_back_utc_aware(archive: Archive, tmp_path: Path) -> None:
    cest = timezone(timedelta(hours=2))
    run = make_run(tmp_path / "in", started_at=datetime(2024, 5, 1, 0, 30, tzinfo=cest))
    res = archive_run(archive, run)
    s = queries.run_summary(archive, res.run_id)
    assert s.started_at == run.started_at  # the same instant...
    assert s.started_at.tzinfo == UTC  # ...expressed in UTC
    assert s.started_at.hour == 22 and s.started_at.day == 30
    # The run folder is dated by the UTC day.
    assert res.run_dir.parent.name == "2024-04-30"
    assert s.created_at.tzinfo == UTC
    assert abs(s.created_at - datetime.now(UTC)) < timedelta(minutes=5)
    h = queries.history(archive, "0012")
    assert h["started_at"].iloc[0] == run.started_at


def test_latest_valid_calibration_as_of_a_date(archive: Archive, tmp_path: Path) -> None:
    t0 = datetime(2024, 1, 10, 9, tzinfo=UTC)
    jan = archive_run(archive, make_run(tmp_path / "a", seed=1, started_at=t0))
    feb = archive_run(archive, make_run(tmp_path / "b", seed=2, started_at=t0 + timedelta(31)))
    archive_run(
        archive, make_run(tmp_path / "c", seed=3, started_at=t0 + timedelta(60), verdict="fail")
    )
    archive_run(
        archive, make_run(tmp_path / "d", serial="0099", seed=4, started_at=t0 + timedelta(1))
    )

    assert queries.latest_calibration(archive, "0012", t0 - timedelta(seconds=1)) is None
    assert queries.latest_calibration(archive, "0012", t0).run_id == jan.run_id
    assert queries.latest_calibration(archive, "0012", t0 + timedelta(40)).run_id == feb.run_id
    latest = queries.latest_calibration(archive, "0012")  # the failed March run does not count
    assert latest.run_id == feb.run_id and latest.verdict == "pass"
    assert len(latest.parameters) == 4
    assert queries.latest_calibration(archive, "no-such-unit") is None
    with pytest.raises(ValueError, match="as_of"):
        queries.latest_calibration(archive, "0012", datetime(2024, 1, 1))

    h = queries.history(archive, "0012")
    assert h["verdict"].tolist() == ["pass", "pass", "fail"]
    assert queries.parameter_history(archive, "0012", "acc.bias.x")["run_id"].tolist()[:2] == [
        jan.run_id,
        feb.run_id,
    ]
    # Untrusted input is a bound parameter: a quote in it is just a non-matching serial.
    assert queries.history(archive, "0012' OR '1'='1").empty
    with pytest.raises(LookupError, match="no run"):
        queries.run_summary(archive, "R000000000000")


# --- raw store and archive location (no database needed) -------------------------------


def test_raw_store_is_content_addressed_and_verified(tmp_path: Path) -> None:
    src = tmp_path / "a.bin"
    src.write_bytes(b"abc")
    sha = hashlib.sha256(b"abc").hexdigest()
    p = rawstore.store_raw(tmp_path / "root", src, sha)
    assert p == tmp_path / "root" / "objects" / sha[:2] / sha and p.read_bytes() == b"abc"
    mtime = p.stat().st_mtime_ns
    assert rawstore.store_raw(tmp_path / "root", src, sha) == p and p.stat().st_mtime_ns == mtime
    with pytest.raises(ValueError, match="hashes to"):
        rawstore.store_raw(tmp_path / "root", src, "0" * 64)
    assert not (tmp_path / "root" / "objects" / "00").exists() or not any(
        (tmp_path / "root" / "objects" / "00").iterdir()
    )


def test_pending_files_store_the_staged_bytes_under_their_hash(tmp_path: Path) -> None:
    """stage_raw copies a file while hashing it: the object committed is exactly the bytes
    that gave its name, whatever happens to the source afterwards; nothing is visible before
    the commit, and nothing of an uncommitted batch is left."""
    root, src = tmp_path / "root", tmp_path / "raw.bin"
    src.write_bytes(b"first")
    sha = hashlib.sha256(b"first").hexdigest()
    with rawstore.PendingFiles() as pending:
        assert pending.stage_raw(root, src) == (sha, 5)
        src.write_bytes(b"changed after it was read")
        # staged already: store_raw has nothing left to read or verify
        assert rawstore.store_raw(root, src, sha, pending) == rawstore.object_path(root, sha)
        pending.write_bytes(root / "runs" / "a.txt", b"a")
        assert not rawstore.object_path(root, sha).exists()
        assert not (root / "runs" / "a.txt").exists()
        pending.commit()
    assert rawstore.object_path(root, sha).read_bytes() == b"first"
    assert (root / "runs" / "a.txt").read_bytes() == b"a"

    with rawstore.PendingFiles() as pending:
        staged, _ = pending.stage_raw(root, src)
        assert pending.stage_raw(root, rawstore.object_path(root, sha)) == (sha, 5)  # stored
        pending.write_bytes(root / "runs" / "b.txt", b"b")
        with pytest.raises(ValueError, match="hashes to"):
            pending.copy(src, rawstore.object_path(root, "0" * 64), "0" * 64)
    files = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
    assert files == sorted([rawstore.object_path(Path("."), sha).as_posix(), "runs/a.txt"])
    assert not rawstore.object_path(root, staged).exists()


def test_samples_parquet_uses_delta_timestamps_and_string_partitions(tmp_path: Path) -> None:
    t = pa.table(
        {
            "t_ns": pa.array(np.arange(1000, dtype=np.int64) * 5_000_000),
            "ax": pa.array(np.zeros(1000)),
        }
    )
    with rawstore.PendingFiles() as pending:
        p1, _ = rawstore.write_samples(pending, tmp_path, "0012", date(2024, 5, 1), "R1", t)
        rawstore.write_samples(pending, tmp_path, "12", date(2024, 5, 2), "R2", t)
        pending.commit()
    meta = pq.ParquetFile(p1).metadata.row_group(0)
    cols = {meta.column(i).path_in_schema: meta.column(i) for i in range(meta.num_columns)}
    assert "DELTA_BINARY_PACKED" in cols["t_ns"].encodings
    assert cols["t_ns"].compression == "ZSTD"
    only = rawstore.read_samples(tmp_path, "0012")
    assert only.num_rows == 1000 and set(only.column("serial").to_pylist()) == {"0012"}
    assert set(rawstore.read_samples(tmp_path).column("serial").to_pylist()) == {"0012", "12"}
    with pytest.raises(ValueError, match="invalid serial"):
        rawstore.run_dir(tmp_path, "..", date(2024, 1, 1), "R1")


def test_resolve_archive(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("CALIB_ARCHIVE", raising=False)
    monkeypatch.delenv("CALIB_FILESTORE", raising=False)
    a = resolve_archive(None)
    assert a.root == tmp_path / "calib-archive"
    assert a.url == default_archive_url(tmp_path / "calib-archive")
    monkeypatch.setenv("CALIB_ARCHIVE", str(tmp_path / "lab"))
    assert resolve_archive(None).root == tmp_path / "lab"
    url = "postgresql+psycopg://writer:secret@db.example/calib"
    monkeypatch.setenv("CALIB_FILESTORE", str(tmp_path / "shared"))
    b = resolve_archive(url)
    assert (b.url, b.root) == (url, tmp_path / "shared")
    assert "secret" not in repr(b)
    (tmp_path / "afile").write_text("")
    with pytest.raises(ValueError, match="expected a directory or a database URL"):
        resolve_archive(str(tmp_path / "afile"))


def test_concurrent_new_runs_of_one_new_unit_share_one_device(
    archive: Archive, tmp_path: Path
) -> None:
    """Different runs of a serial not yet archived: both archive, the device row is made once."""
    runs = [make_run(tmp_path / f"in{i}", seed=10 + i) for i in range(3)]
    barrier = threading.Barrier(len(runs))
    results, errors = [], []

    def work(run: RunIn) -> None:
        try:
            barrier.wait(timeout=10)
            results.append(archive_run(archive, run))
        except BaseException as exc:  # noqa: BLE001 - asserted below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(r,)) for r in runs]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert errors == []
    assert [r.status for r in results] == ["ok"] * len(runs)
    c = counts(archive)
    assert (c["devices"], c["equipment"], c["runs"], c["run_equipment"]) == (1, 1, 3, 3)
    # the concurrent writers appended to the audit chain one after the other: one unbroken chain
    assert (c["seals"], c["audit_events"]) == (3, 3)
    assert verify(archive, orphans=False).ok
