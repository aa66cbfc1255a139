"""Backup and restore of a whole archive: database snapshot + file store + hash manifest.

A backup is a folder::

    manifest.json        format, back end, schema revision, time, and the SHA-256
                         and size of the database snapshot and of every file
    database.sqlite      SQLite: a consistent copy made with the online backup API
    database.pgdump      PostgreSQL: pg_dump custom format (one snapshot transaction)
    files/...            the file store (objects/, runs/, samples/) as it was

Consistency: the database is copied first, then the files. The file store
only grows (content-addressed objects, new run folders, never an overwrite),
and a run's files are written before its rows are committed, so every file the
snapshot references is already there when the files are copied; files of runs
committed later are harmless orphans in the backup. `manifest.json` is written
last: a backup folder without one is incomplete.

`restore` checks every hash of the backup before it writes anything and only
restores into an empty location (no database tables, no files), so it can
never mix two archives. Afterwards `storage.verify.verify` should pass.
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import inspect
from sqlalchemy.engine import make_url

from storage import pgtools, rawstore
from storage.db import Archive, read_only_sqlite_uri
from storage.verify import sqlite_file

MANIFEST = "manifest.json"
FORMAT = 1
FILES = "files"
STORE_DIRS = ("objects", "runs", "samples")
PG_TIMEOUT_S = 3600


class BackupError(RuntimeError):
    """A backup could not be made or restored; the message says which file and why."""


def _store_files(root: Path) -> list[Path]:
    """Files of the file store, without temporary files of writes in progress."""
    files = []
    for top in STORE_DIRS:
        base = root / top
        if base.is_dir():
            files += [p for p in sorted(base.rglob("*")) if p.is_file() and not _is_temp(p)]
    return files


def _is_temp(p: Path) -> bool:
    return p.name.startswith(".") and p.name.endswith(".tmp")


def _pg_tool(tool: str, url: str, *args: str) -> None:
    """PostgreSQL's client `tool` on the database at `url` (no owner, no privileges) with
    `args`; the password goes in the environment, never on the command line."""
    u = make_url(url)
    env = dict(os.environ)
    if u.password:
        env["PGPASSWORD"] = str(u.password)
    dsn = pgtools.libpq_dsn(u.set(password=None).render_as_string(hide_password=False))
    command = [str(pgtools.tool(tool)), "--no-owner", "--no-privileges", f"--dbname={dsn}", *args]
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=PG_TIMEOUT_S)
    if done.returncode:
        raise BackupError(f"{tool} failed (exit {done.returncode}): {done.stderr.strip()}")


def _sqlite_copy(src: sqlite3.Connection, target: Path) -> None:
    """The database of `src` copied into the file `target` in one step (a read snapshot of the
    whole database: SQLite's online backup); both connections closed."""
    dst = sqlite3.connect(str(target))
    try:
        with dst:
            src.backup(dst)
    finally:
        dst.close()
        src.close()


def backup(archive: Archive, dest: Path) -> dict[str, Any]:
    """Make a consistent backup of `archive` in the new folder `dest`.

    Parameters
    ----------
    archive : the archive to back up (SQLite or PostgreSQL).
    dest : a folder that does not exist yet, or is empty.

    Returns
    -------
    The manifest (also written to dest/manifest.json).
    """
    dest = Path(dest)
    if dest.exists() and (not dest.is_dir() or any(dest.iterdir())):
        raise BackupError(f"backup destination {dest}: exists and is not an empty folder")
    dest.mkdir(parents=True, exist_ok=True)
    revision = archive.schema_revision()
    if revision is None:
        raise BackupError(f"archive {archive.display_url}: no schema, nothing to back up")
    if archive.is_sqlite:
        db_name = "database.sqlite"
        src = (
            sqlite3.connect(read_only_sqlite_uri(sqlite_file(archive)), uri=True)
            if archive.read_only
            else sqlite3.connect(str(sqlite_file(archive)))
        )
        _sqlite_copy(src, dest / db_name)
    else:
        db_name = "database.pgdump"
        _pg_tool("pg_dump", archive.url, "--format=custom", f"--file={dest / db_name}")
    db_sha, db_size = rawstore.hash_and_size(dest / db_name)

    files: dict[str, dict[str, Any]] = {}
    root = archive.root
    for p in _store_files(root):
        rel = p.relative_to(root).as_posix()
        sha, size = rawstore.copy_atomic(p, dest / FILES / rel)
        files[rel] = {"sha256": sha, "size": size}
    manifest = {
        "format": FORMAT,
        "created_at": datetime.now(UTC).isoformat(),
        "backend": "sqlite" if archive.is_sqlite else "postgresql",
        "schema_revision": revision,
        "database": {"file": db_name, "sha256": db_sha, "size": db_size},
        "files": files,
    }
    rawstore.write_atomic(dest / MANIFEST, json.dumps(manifest, indent=1).encode())
    return manifest


def read_manifest(src: Path) -> dict[str, Any]:
    """The manifest of a backup folder, checked for shape; BackupError names what is wrong."""
    path = Path(src) / MANIFEST
    if not path.is_file():
        raise BackupError(f"{path}: missing (not a backup folder, or an incomplete backup)")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BackupError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise BackupError(f"{path}: expected a backup manifest of format {FORMAT}")
    if manifest.get("backend") not in ("sqlite", "postgresql"):
        raise BackupError(f"{path}: field 'backend' must be sqlite or postgresql")
    db = manifest.get("database")
    if not isinstance(db, dict) or db.get("file") not in ("database.sqlite", "database.pgdump"):
        raise BackupError(f"{path}: field 'database.file' is not a database snapshot name")
    files = manifest.get("files")
    if not isinstance(files, dict):
        raise BackupError(f"{path}: field 'files' must map paths to hashes")
    for rel, entry in files.items():
        parts = Path(rel).parts
        if Path(rel).is_absolute() or ".." in parts or not parts or parts[0] not in STORE_DIRS:
            raise BackupError(f"{path}: file entry {rel!r} is outside the file store layout")
        if not isinstance(entry, dict) or not isinstance(entry.get("sha256"), str):
            raise BackupError(f"{path}: file entry {rel!r} has no sha256")
    return manifest


def check_backup(src: Path) -> dict[str, Any]:
    """Re-hash every file of a backup against its manifest; return the manifest.

    Raises BackupError listing missing or changed files.
    """
    src = Path(src)
    manifest = read_manifest(src)
    bad = []
    entries = [(manifest["database"]["file"], manifest["database"])] + [
        (f"{FILES}/{rel}", e) for rel, e in manifest["files"].items()
    ]
    for rel, entry in entries:
        p = src / rel
        if not p.is_file():
            bad.append(f"{rel}: missing")
            continue
        sha, size = rawstore.hash_and_size(p)
        if sha != entry["sha256"] or size != entry.get("size", size):
            bad.append(f"{rel}: sha256 {sha} ({size} bytes), manifest says {entry['sha256']}")
    if bad:
        shown = "\n  ".join(bad[:20]) + (
            f"\n  ... and {len(bad) - 20} more" if len(bad) > 20 else ""
        )
        raise BackupError(f"backup {src} is damaged:\n  {shown}")
    return manifest


def _check_empty_target(archive: Archive) -> None:
    root = archive.root
    leftovers = _store_files(root) if root.exists() else []
    if leftovers:
        raise BackupError(
            f"restore target {root}: the file store is not empty ({leftovers[0]} ...); "
            "restore only into an empty location"
        )
    db = sqlite_file(archive)
    if db is not None and db.exists() and db.stat().st_size > 0:
        raise BackupError(f"restore target {db}: a database file exists already")
    if db is None:
        with archive.engine().connect() as conn:
            tables = inspect(conn).get_table_names()
        if tables:
            raise BackupError(
                f"restore target {archive.display_url}: the database has tables "
                f"({', '.join(sorted(tables)[:5])}...); restore only into an empty database"
            )


def restore(src: Path, archive: Archive) -> dict[str, Any]:
    """Restore the backup folder `src` into an empty archive location.

    The back end must be the one the backup was made from (a SQLite backup
    into a SQLite location, a PostgreSQL dump into an empty PostgreSQL
    database). Every hash is checked before anything is written; then the
    files are copied (each re-hashed while copying), the database restored,
    and the schema upgraded to the current revision.

    Returns
    -------
    The backup's manifest.
    """
    src = Path(src)
    manifest = check_backup(src)
    backend = "sqlite" if archive.is_sqlite else "postgresql"
    if manifest["backend"] != backend:
        raise BackupError(
            f"backup {src} holds a {manifest['backend']} database; the target "
            f"{archive.display_url} is {backend}: restore into the same kind of back end"
        )
    _check_empty_target(archive)
    archive.dispose()  # no pooled connection may see the database while it is replaced

    for rel, entry in manifest["files"].items():
        sha, _ = rawstore.copy_atomic(src / FILES / rel, archive.root / rel)
        if sha != entry["sha256"]:  # changed since check_backup: refuse to go on
            raise BackupError(f"backup file {rel} changed while being restored")
    db_file = src / manifest["database"]["file"]
    if backend == "sqlite":
        target = sqlite_file(archive)
        target.parent.mkdir(parents=True, exist_ok=True)
        _sqlite_copy(sqlite3.connect(str(db_file)), target)
    else:
        _pg_tool("pg_restore", archive.url, "--exit-on-error", "--single-transaction", str(db_file))
    archive.upgrade()
    if not archive.is_sqlite:  # the restored files are the database's store now
        from storage.store_identity import adopt

        adopt(archive)
    return manifest
