"""Which folder is a database's file store: recorded once, checked before every write.

A SQLite archive keeps its database inside its file store, so the two cannot be
mixed up. A PostgreSQL archive's file store is a folder named apart from the
database (``CALIB_FILESTORE``, else ``./calib-archive`` of wherever the command
runs): a command started in another folder would write the runs' files there and
`verify` would later find them missing. So the first write of a PostgreSQL archive
gives its store an identity: a random id written to ``.calib-store.json`` in the
folder and, with the folder's path, into the detail of that write's audit event
(``file_store``), so the database records it in its chain. Every later write
(`check`) refuses a folder whose id is another or missing, naming both folders.
A restore (storage.backup) marks its new folder with the recorded id (`adopt`).
"""

from __future__ import annotations

import json
import os
import time
import uuid
from pathlib import Path
from typing import Any

from sqlalchemy import select
from sqlalchemy.engine import make_url

from storage import seal
from storage.db import Archive
from storage.schema import AuditEvent, Run

MARKER = ".calib-store.json"
KEY = "file_store"  # the key of an event's detail that records the store
_CHECKED: set[tuple[str, str]] = set()  # (database URL, root) found to match in this process


class StoreMismatchError(ValueError):
    """The file store folder is not the one recorded for the database (nothing written)."""


def recorded(archive: Archive) -> dict[str, Any] | None:
    """The file store recorded in the database ({"id", "root"}), or None."""
    with archive.engine().connect() as conn:
        details = (
            conn.execute(
                select(AuditEvent.detail)
                .where(AuditEvent.detail[KEY].is_not(None))
                .order_by(AuditEvent.seq)
                .limit(1)
            )
            .scalars()
            .all()
        )
    found = details[0].get(KEY) if details else None
    return found if isinstance(found, dict) else None


def _marker(root: Path) -> dict[str, Any] | None:
    try:
        doc = json.loads((root / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("id"), str) else None


def check(archive: Archive) -> None:
    """Refuse (StoreMismatchError) to write into a folder that is not the database's file
    store; on the first write, mark the folder and have the write's event record it
    (`seal.append_event` takes it from ``seal.PENDING_DETAIL``). SQLite: nothing to do."""
    if archive.is_sqlite or (archive.url, str(archive.root)) in _CHECKED:
        return
    root = Path(archive.root).resolve()
    known = recorded(archive)
    here = _marker(root)
    if known is None:
        _first_write(archive, root, here)
        return
    why = _mismatch(archive, root, known, here)
    if why:
        raise StoreMismatchError(f"{why}; nothing was written")
    _CHECKED.add((archive.url, str(archive.root)))


def mismatch(archive: Archive) -> str:
    """Why `archive.root` is not the file store the database records ("": it is, or none
    is recorded)."""
    known = recorded(archive)
    root = Path(archive.root).resolve()
    return "" if known is None else _mismatch(archive, root, known, _marker(root))


def _mismatch(
    archive: Archive, root: Path, known: dict[str, Any], here: dict[str, Any] | None
) -> str:
    if here is not None and here["id"] == known.get("id"):
        return ""
    found = (
        "no file store of a calib archive"
        if here is None
        else f"the file store of another archive (id {here['id'][:8]})"
    )
    return (
        f"the archive {archive.display_url} keeps its files in {known.get('root')} "
        f"(file store id {str(known.get('id'))[:8]}), not in {root}, which holds {found}; "
        f"set CALIB_FILESTORE={known.get('root')} (or run the command there)"
    )


def _first_write(archive: Archive, root: Path, here: dict[str, Any] | None) -> None:
    """Mark the folder, and have the write's event record it.

    Refused when the folder is another database's store already, and when the archive
    holds runs already of which the folder has none (an archive from before stores
    were recorded, opened from the wrong folder)."""
    if here is not None and here.get("database") != archive.display_url:
        raise StoreMismatchError(
            f"{root} is the file store of another archive ({here.get('database', '?')}, id "
            f"{here['id'][:8]}); the archive {archive.display_url} has no file store recorded "
            "yet: give it a folder of its own with CALIB_FILESTORE; nothing was written"
        )
    with archive.engine().connect() as conn:
        some = conn.execute(select(Run.run_dir).order_by(Run.id).limit(1)).scalar_one_or_none()
    if some is not None and not (root / some).is_dir():
        raise StoreMismatchError(
            f"the archive {archive.display_url} holds runs whose folders are not in {root} "
            f"(the first, {some}, is not there): set CALIB_FILESTORE to the folder that holds "
            "them; nothing was written"
        )
    if here is None:  # (else a marker of an earlier attempt whose event was not written)
        here = _new_marker(archive, root)
    url = make_url(archive.url).render_as_string(hide_password=False)
    seal.PENDING_DETAIL[url] = {KEY: {"id": here["id"], "root": str(root)}}


def _new_marker(archive: Archive, root: Path) -> dict[str, Any]:
    """Write the folder's marker, or take the one a concurrent first write made: the file
    is created exclusively, so two processes writing their first runs at once record one
    id, not each its own."""
    mine = {"id": uuid.uuid4().hex, "database": archive.display_url, "root": str(root)}
    root.mkdir(parents=True, exist_ok=True)
    try:
        with open(root / MARKER, "x", encoding="utf-8") as f:
            f.write(json.dumps(mine) + "\n")
            f.flush()
            os.fsync(f.fileno())
    except FileExistsError:
        theirs = None
        for _ in range(100):  # the other writer may not have written its line yet
            if (theirs := _marker(root)) is not None:
                break
            time.sleep(0.01)
        if theirs is None:
            raise StoreMismatchError(
                f"{root / MARKER} exists but cannot be read as a file store marker; nothing "
                "was written"
            ) from None
        return theirs
    return mine


def adopt(archive: Archive) -> None:
    """Mark `archive.root` as the store the database records (a restore put its files
    there); nothing when none is recorded."""
    known = recorded(archive)
    if known is None:
        return
    root = Path(archive.root).resolve()
    root.mkdir(parents=True, exist_ok=True)
    doc = {
        "id": known["id"],
        "database": archive.display_url,
        "root": str(root),
        "restored_from": known["root"],
    }
    (root / MARKER).write_text(json.dumps(doc) + "\n", encoding="utf-8")
