"""`calib verify`, `calib backup`, `calib restore` on both back ends.

Known truth: the bytes and hashes that went into the archive (make_run), and
the query answers before the backup, which the restored archive must give
exactly.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import pytest
from sqlalchemy import text
from test_archive import make_run
from typer.testing import CliRunner

from pipelines.cli import app
from storage import queries, rawstore
from storage.archive import archive_run
from storage.backup import MANIFEST, BackupError, backup, restore
from storage.db import Archive
from storage.verify import verify


def fill(archive: Archive, tmp: Path) -> list[str]:
    """Three runs of two units, one of them revised; returns the run ids."""
    runs = [
        make_run(tmp / f"in{i}", serial=s, seed=i) for i, s in enumerate(["0012", "0012", "77"])
    ]
    ids = [
        archive_run(archive, r, {"protocol.txt": f"run {i}".encode()}).run_id
        for i, r in enumerate(runs)
    ]
    archive_run(archive, replace(runs[0], settings={"outlier_sigma": 4.0}), {"protocol.txt": b"r2"})
    return ids


def cli(archive: Archive, *args: str, monkeypatch: pytest.MonkeyPatch):  # noqa: ANN201
    monkeypatch.setenv("CALIB_FILESTORE", str(archive.root))
    return CliRunner().invoke(app, [*args, "--archive", archive.url])


def test_verify_reports_changed_and_missing_files(
    archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ids = fill(archive, tmp_path)
    report = verify(archive)
    assert report.ok and report.orphans == []
    # 3 runs x 3 raw objects + 3 samples files, every byte read once.
    raw = [f for i in ids for f in queries.run_summary(archive, i).raw_files]
    samples = [archive.root / queries.run_summary(archive, i).samples_path for i in ids]
    assert report.files_checked == len(raw) + len(samples) == 12
    assert report.bytes_checked == sum(f.size for f in raw) + sum(p.stat().st_size for p in samples)
    res = cli(archive, "verify", monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output

    # Tamper with one raw object (one byte flipped) and remove one samples file.
    victim = archive.root / raw[4].stored_path
    data = bytearray(victim.read_bytes())
    data[10] ^= 0x01
    victim.write_bytes(bytes(data))
    samples[2].unlink()
    report = verify(archive)
    assert not report.ok
    by_kind = {p.kind: p for p in report.problems}
    assert set(by_kind) == {"mismatch", "missing"}
    assert by_kind["mismatch"].path == raw[4].stored_path
    assert by_kind["mismatch"].runs == [ids[1]]
    assert raw[4].sha256 in by_kind["mismatch"].detail
    assert by_kind["missing"].path == samples[2].relative_to(archive.root).as_posix()
    assert by_kind["missing"].runs == [ids[2]]

    res = cli(archive, "verify", "--json", monkeypatch=monkeypatch)
    assert res.exit_code == 1
    doc = json.loads(res.stdout)
    assert doc["ok"] is False and len(doc["problems"]) == 2
    res = cli(archive, "verify", monkeypatch=monkeypatch)
    assert res.exit_code == 1 and "MISMATCH" in res.stdout and raw[4].stored_path in res.stdout


def test_verify_finds_broken_database_invariants(archive: Archive, tmp_path: Path) -> None:
    ids = fill(archive, tmp_path)
    with archive.engine().begin() as conn:  # what no code path does: make two revisions current
        conn.execute(text("UPDATE calibrations SET superseded_by = NULL"))
    report = verify(archive)
    assert [(p.kind, p.runs) for p in report.problems] == [("database", [ids[0]])]
    assert "2 current calibration revisions" in report.problems[0].detail


def _answers(archive: Archive, ids: list[str]) -> dict:
    return {
        "history": queries.history(archive, "0012").to_dict("list"),
        "units": queries.units(archive).to_dict("list"),
        "runs": [queries.run_summary(archive, i) for i in ids],
        "fleet": queries.fleet(archive, "MPU-6000", "acc.bias.x").to_dict("list"),
    }


def _destroy(archive: Archive) -> None:
    """Lose everything: the file store, and the database (file, or every table)."""
    if archive.is_sqlite:
        archive.dispose()
        shutil.rmtree(archive.root)
    else:
        with archive.engine().begin() as conn:
            conn.execute(text("DROP SCHEMA public CASCADE"))
            conn.execute(text("CREATE SCHEMA public"))
        archive.dispose()
        shutil.rmtree(archive.root)


def test_backup_destroy_restore_verify(
    empty_archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    archive = empty_archive
    archive.upgrade()
    ids = fill(archive, tmp_path)
    before = _answers(archive, ids)
    dest = tmp_path / "backup"
    res = cli(archive, "backup", str(dest), monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    manifest = json.loads((dest / MANIFEST).read_text())
    stored = {
        p.relative_to(archive.root).as_posix(): rawstore.hash_and_size(p)[0]
        for top in ("objects", "runs", "samples")
        for p in (archive.root / top).rglob("*")
        if p.is_file()
    }
    assert {k: v["sha256"] for k, v in manifest["files"].items()} == stored
    assert manifest["schema_revision"] == archive.schema_revision()

    _destroy(archive)
    assert not archive.root.exists()
    res = cli(archive, "restore", str(dest), monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    assert verify(archive).ok
    assert _answers(archive, ids) == before

    # Restoring again on top of a full archive is refused; nothing is mixed.
    with pytest.raises(BackupError, match="not empty"):
        restore(dest, archive)


def test_damaged_backup_is_refused_before_anything_is_written(
    archive: Archive, tmp_path: Path
) -> None:
    fill(archive, tmp_path)
    dest = tmp_path / "backup"
    manifest = backup(archive, dest)
    with pytest.raises(BackupError, match="exists and is not an empty folder"):
        backup(archive, dest)
    rel = sorted(manifest["files"])[0]
    (dest / "files" / rel).write_bytes(b"tampered")
    target = Archive(f"sqlite:///{tmp_path / 'target' / 'archive.sqlite'}", tmp_path / "target")
    if not archive.is_sqlite:
        target = archive  # a PostgreSQL backup can only go to PostgreSQL: refused for damage first
    with pytest.raises(BackupError, match=f"damaged:\\n  files/{rel}: sha256"):
        restore(dest, target)
    assert not (tmp_path / "target").exists()
