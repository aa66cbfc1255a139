"""A full disk and a read-only archive, for real: small tmpfs mounts and read-only bind mounts.

- Disk full while a run's files are written, and while its rows are written
  (the SQLite file on a full tmpfs through a symlink): the run fails with a
  message naming the path and saying what to do, nothing of it is archived,
  no temporary file stays, and the same run archives once there is space.
- A read-only archive (a read-only bind mount; SQLite opened read-only, or
  immutable when it cannot keep a log there): history, show, export, query,
  report --output and verify work; report into the archive and process say
  why not.
- Temporary files of killed writers are removed by `calib verify --repair-orphans`;
  a live writer's are kept.

Mounting needs root (CAP_SYS_ADMIN); without it these tests are skipped.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage import rawstore
from storage.db import Archive, resolve_archive
from storage.verify import verify

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "data_samples"


@contextlib.contextmanager
def mounted(target: Path, *args: str) -> Iterator[Path]:
    target.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", *args, target], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount (needs root): {done.stderr.decode().strip()}")
    try:
        yield target
    finally:
        subprocess.run(["umount", "-l", target], check=False)


@contextlib.contextmanager
def tmpfs(target: Path, size_kb: int) -> Iterator[Path]:
    with mounted(target, "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs") as m:
        yield m


@contextlib.contextmanager
def read_only_view(src: Path, target: Path) -> Iterator[Path]:
    with mounted(target, "--bind", str(src)) as m:
        done = subprocess.run(["mount", "-o", "remount,bind,ro", m], capture_output=True)
        assert done.returncode == 0, done.stderr
        yield m


def fill(folder: Path, leave_kb: int) -> None:
    """Fill the file system of `folder` up to `leave_kb` KiB of free space."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize - leave_kb * 1024
    with open(folder / "filler", "wb") as f, contextlib.suppress(OSError):
        f.write(b"\0" * max(free, 0))


def temp_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.endswith(".tmp")]


def process(archive: Archive, name: str) -> dict:
    (source,) = discover_runs([SAMPLES / name])
    return process_run(source, archive)


def test_disk_full_while_writing_files(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "disk", 4096) as disk:
        archive = resolve_archive(str(disk / "archive"))
        archive.upgrade()
        fill(disk, leave_kb=300)  # the MPU-6000 run needs ~1 MB of objects and samples
        out = process(archive, "mpu6000_MPU0001")
        assert out["status"] == "failed"
        assert out["error"].startswith(f"no space left on the file system holding {disk}/archive/")
        assert "free space there" in out["error"] and "internal error" not in out["error"]
        assert temp_files(disk / "archive") == []
        with archive.engine().connect() as conn:
            assert conn.exec_driver_sql("SELECT count(*) FROM runs").scalar() == 0
        (disk / "filler").unlink()
        assert process(archive, "mpu6000_MPU0001")["status"] == "ok"
        assert verify(archive).ok
        archive.dispose()


@pytest.mark.parametrize("leave_kb", [0, 40])
def test_disk_full_while_writing_the_database(tmp_path: Path, leave_kb: int) -> None:
    root = tmp_path / "archive"
    with tmpfs(tmp_path / "dbdisk", 1024) as dbdisk:
        root.mkdir()
        (root / "archive.sqlite").symlink_to(dbdisk / "archive.sqlite")
        archive = resolve_archive(str(root))
        archive.upgrade()
        archive.dispose()
        fill(dbdisk, leave_kb=leave_kb)
        out = process(archive, "mpu6000_MPU0001")
        assert out["status"] == "failed", out
        # No room for SQLite's shared-memory file: it says "disk I/O error" at the open;
        # no room for new pages: "database or disk is full" at the insert.
        db = f"{dbdisk}/archive.sqlite"  # the file itself, through the link
        assert out["error"].startswith(
            (f"no space left for the database {db}", f"the database {db} could not be written")
        ), out["error"]
        assert "disk is full" in out["error"] or "no space left" in out["error"]
        assert temp_files(root) == []
        archive.dispose()
        (dbdisk / "filler").unlink()
        assert process(archive, "mpu6000_MPU0001")["status"] == "ok"
        assert verify(archive).ok
        archive.dispose()


def calib(*args: str, **env_vars: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), **env_vars}
    code = "import sys; from pipelines.cli import app; sys.argv[0] = 'calib'; app()"
    return subprocess.run(
        [sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, timeout=300
    )


@pytest.fixture(scope="module")
def written_archive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict]]:
    root = tmp_path_factory.mktemp("rw") / "archive"
    archive = resolve_archive(str(root))
    archive.upgrade()
    outs = [process(archive, name) for name in ("mpu6000_MPU0001", "csv_IMU-2026-0042")]
    assert [o["status"] for o in outs] == ["ok", "ok"]
    archive.dispose()
    return root, outs


@pytest.mark.e2e
@pytest.mark.parametrize("keep_log", [True, False], ids=["mode-ro", "immutable"])
def test_read_only_archive(written_archive, tmp_path: Path, keep_log: bool) -> None:
    src, outs = written_archive
    copy = tmp_path / "copy"
    shutil.copytree(src, copy)
    if keep_log:  # -wal and -shm beside the file: SQLite reads it with mode=ro
        for suffix in ("-wal", "-shm"):
            (copy / f"archive.sqlite{suffix}").touch()
    run_id, serial = outs[0]["run_id"], outs[0]["serial"]
    with read_only_view(copy, tmp_path / "ro") as ro:
        before = sorted(p.relative_to(ro).as_posix() for p in ro.rglob("*"))
        a = ["--archive", str(ro)]
        for args in (
            ["history", serial, "--json"],
            ["show", run_id, "--json"],
            ["export", run_id],
            ["query", "lineage", run_id, "acc.bias.x"],
            ["verify"],
            ["report", run_id, "--output", str(tmp_path / "rep"), "--no-pdf"],
        ):
            done = calib(*args, *a)
            assert done.returncode == 0, (args, done.stderr[-2000:])
            assert "Traceback" not in done.stderr
        assert json.loads(calib("history", serial, "--json", *a).stdout)[0]["run_id"] == run_id
        assert (tmp_path / "rep" / f"{serial}_result.txt").is_file()
        refused = calib("report", run_id, "--no-pdf", *a)
        assert refused.returncode == 2 and "read-only file system" in refused.stderr
        assert "--output DIR" in refused.stderr and "Traceback" not in refused.stderr
        out = process(Archive(f"sqlite:///{ro}/archive.sqlite", ro), "csv_IMU-2026-0042")
        assert out["status"] == "failed" and "read-only file system" in out["error"]
        assert str(ro) in out["error"] and "internal error" not in out["error"]
        assert sorted(p.relative_to(ro).as_posix() for p in ro.rglob("*")) == before


@pytest.mark.slow
def test_repair_orphans_removes_only_dead_writers_files(written_archive, tmp_path: Path) -> None:
    src, _ = written_archive
    root = tmp_path / "archive"
    shutil.copytree(src, root)
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    ).stdout.strip()
    host = rawstore._WRITER.rsplit("-", 1)[0]
    stale = root / "objects" / f".incoming.{host}-{dead}.abcd1234.tmp"
    live = root / "objects" / f".incoming.{rawstore._WRITER}.efgh5678.tmp"
    for p in (stale, live):
        p.write_bytes(b"staged")
    assert rawstore.stale_temp_files(root) == [stale]
    done = calib("verify", "--repair-orphans", "--archive", str(root))
    assert done.returncode == 0, done.stderr
    assert f"removed objects/{stale.name}" in done.stderr
    assert not stale.exists() and live.exists()


@pytest.mark.e2e  # the commands in processes of their own
@pytest.mark.parametrize("naming", ["CALIB_ARCHIVE", "--archive"])
def test_writes_to_a_read_only_archive_say_why_either_way_it_is_named(
    written_archive, tmp_path: Path, naming: str
) -> None:
    """Every writing command on a read-only archive ends with one sentence naming the
    database, never a traceback, whether the folder is given by env or option."""
    from storage.approval import generate_key

    src, outs = written_archive
    copy = tmp_path / "copy"
    shutil.copytree(src, copy)
    generate_key(tmp_path / "k.key", "Jane Approver", "correct horse battery")
    run_id = outs[0]["run_id"]
    with read_only_view(copy, tmp_path / "ro") as ro:
        env = {"CALIB_KEY_PASSPHRASE": "correct horse battery"}
        a = ["--archive", str(ro)]
        if naming == "CALIB_ARCHIVE":
            env, a = {**env, "CALIB_ARCHIVE": str(ro)}, []
        done = calib("approve", run_id, "--key", str(tmp_path / "k.key"), *a, **env)
        said = " ".join(done.stderr.split())
        assert done.returncode != 0 and "Traceback" not in done.stderr, done.stderr[-3000:]
        assert (
            f"error: run {run_id}: not signed: the database {ro}/archive.sqlite is read-only"
            in (said)
        ), said
        assert "the database the archive" not in said
        done = calib("process", str(SAMPLES / "csv_IMU-2026-0042"), *a, **env)
        assert "Traceback" not in done.stderr
        assert "read-only file system" in done.stdout + done.stderr
        done = calib("backup", str(tmp_path / "bk"), *a, **env)  # reading: works
        assert done.returncode == 0, done.stderr[-3000:]
