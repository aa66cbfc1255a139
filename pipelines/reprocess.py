"""Reprocessing, the pipeline glue: an archived run processed again from the archive alone.

The archive keeps every raw file of a run byte for byte, named by its SHA-256
(storage.rawstore.object_path), and its original name (``raw_files.name``).
`restore_run` copies them back under their names into a fresh folder, checking
each hash, so the folder is the run folder as it was: a ``run.toml`` run gets
its manifest back among the raw files; an MPU-6000 folder without a manifest
gets its files' modification times set to the archived start time, from which
the loader synthesises the same manifest (run_loader takes ``started`` from
the newest file modification time). `reprocess_run` then runs the ordinary
pipeline (pipelines.process.process_run) on that folder: with unchanged
settings and software the archive answers "duplicate", with new ones it
archives a new revision of the same run.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from pipelines.ingest.manifest import check_relative_name
from pipelines.ingest.run_loader import MANIFEST_NAME, RunSource
from storage.db import Archive

_CHUNK = 1 << 20
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


class ReprocessError(ValueError):
    """The archive cannot give back the run: unknown id, missing or altered raw object."""


def restore_run(archive: Archive, run_id: str, folder: Path) -> RunSource:
    """Write the raw files of an archived run into `folder` (empty or new) under their names.

    Parameters
    ----------
    archive : the archive holding the run.
    run_id : its run id (``R`` + 12 hex digits).
    folder : where the run folder is rebuilt.

    Returns
    -------
    The RunSource of the rebuilt folder, ready for pipelines.process.process_run.

    Raises
    ------
    ReprocessError for an unknown run, a raw object that is missing from the
    file store or whose bytes no longer hash to the archived SHA-256, and a
    stored name that would land outside the folder.
    """
    from storage import queries, rawstore

    try:
        summary = queries.run_summary(archive, run_id)
    except LookupError as exc:
        raise ReprocessError(str(exc)) from None
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    raw_files = summary["raw_files"]
    for raw in raw_files:
        try:
            name = check_relative_name(raw["name"])
        except ValueError as exc:
            raise ReprocessError(f"run {run_id}: archived raw file name: {exc}") from None
        src = rawstore.object_path(archive.root, raw["sha256"])
        if not src.is_file():
            raise ReprocessError(
                f"run {run_id}: raw file {name!r} (sha256 {raw['sha256']}) is missing from "
                f"the file store at {src}"
            )
        dest = folder / name
        dest.parent.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha256()
        with src.open("rb") as fin, dest.open("wb") as fout:
            while chunk := fin.read(_CHUNK):
                digest.update(chunk)
                fout.write(chunk)
        if digest.hexdigest() != raw["sha256"]:
            raise ReprocessError(
                f"run {run_id}: raw object {src} of {name!r} hashes to {digest.hexdigest()}, "
                f"archived as {raw['sha256']} (the file store was altered)"
            )
    if any(r["name"] == MANIFEST_NAME for r in raw_files):
        return RunSource(folder, "manifest")
    # No manifest: the loader synthesises one, with `started` = the newest file mtime.
    started: datetime = summary["started_at"]
    ns = (started.astimezone(UTC) - _EPOCH) // timedelta(microseconds=1) * 1000
    for raw in raw_files:
        os.utime(folder / raw["name"], ns=(ns, ns))
    return RunSource(folder, "mpu6000", summary["device"]["serial"])


def reprocess_run(archive: Archive, run_id: str, keep: Path | None = None) -> dict[str, Any]:
    """Process an archived run again from its archived raw files.

    Parameters
    ----------
    archive : the archive to read the run from and to archive the result to.
    run_id : the run.
    keep : rebuild the run folder here and leave it; None: a temporary folder.

    Returns
    -------
    The run's entry of the `calib process --json` document; ``source`` is
    ``archive:<run_id>``. Status "duplicate" when the settings and software are
    unchanged, "revised"-as-"ok" with a new revision otherwise.
    """
    from pipelines.process import process_run

    with tempfile.TemporaryDirectory(prefix=f"reprocess_{run_id}_") as tmp:
        folder = Path(keep) if keep is not None else Path(tmp) / run_id
        source = restore_run(archive, run_id, folder)
        outcome = process_run(source, archive)
    outcome["source"] = f"archive:{run_id}"
    return outcome
