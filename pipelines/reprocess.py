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

import os
import tempfile
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from pipelines.ingest.manifest import check_relative_name
from pipelines.ingest.run_loader import MANIFEST_NAME, RunSource
from storage.db import Archive

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


class ReprocessError(ValueError):
    """The archive cannot give back the run: unknown id, missing or altered raw object."""


def restore_run(archive: Archive, run_id: str, folder: Path, *, link: bool = False) -> RunSource:
    """Write the raw files of an archived run into `folder` (empty or new) under their names.

    Parameters
    ----------
    archive : the archive holding the run.
    run_id : its run id (``R`` + 12 hex digits).
    folder : where the run folder is rebuilt.
    link : hard-link each raw object into the folder where the file system allows
        (else copy), for a folder that is read and then deleted (`reprocess_run`'s
        temporary one). A run without a manifest is always copied: its files' times
        are set, and the object's times must stay as they are.

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
    raw_files = summary.raw_files
    has_manifest = any(r.name == MANIFEST_NAME for r in raw_files)
    for raw in raw_files:
        try:
            name = check_relative_name(raw.name)
        except ValueError as exc:
            raise ReprocessError(f"run {run_id}: archived raw file name: {exc}") from None
        src = rawstore.object_path(archive.root, raw.sha256)
        if not src.is_file():
            raise ReprocessError(
                f"run {run_id}: raw file {name!r} (sha256 {raw.sha256}) is missing from "
                f"the file store at {src}"
            )
        dest = folder / name
        dest.parent.mkdir(parents=True, exist_ok=True)
        digest = _restore_file(src, dest, link and has_manifest)
        if digest != raw.sha256:
            raise ReprocessError(
                f"run {run_id}: raw object {src} of {name!r} hashes to {digest}, "
                f"archived as {raw.sha256} (the file store was altered)"
            )
    if has_manifest:
        return RunSource(folder, "manifest")
    # No manifest: the loader synthesises one, with `started` = the newest file mtime.
    ns = (summary.started_at.astimezone(UTC) - _EPOCH) // timedelta(microseconds=1) * 1000
    for raw in raw_files:
        os.utime(folder / raw.name, ns=(ns, ns))
    return RunSource(folder, "mpu6000", summary.device.serial)


def _restore_file(src: Path, dest: Path, link: bool) -> str:
    """Hard-link (if `link` and the file system allows) or copy `src` to `dest`; the SHA-256
    of the bytes read. A link writes nothing: the copy wrote every raw byte of the archive
    once more (a tenth of a run's reprocessing went to restoring its files)."""
    from storage.rawstore import copy_hashing, hash_and_size

    if link:
        try:
            os.link(src, dest)
        except OSError:  # another file system, no hard links there, ...: copy
            pass
        else:
            return hash_and_size(dest)[0]
    fd = os.open(dest, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
    try:
        return copy_hashing(src, fd)[0]
    finally:
        os.close(fd)


def reprocess_run(
    archive: Archive,
    run_id: str,
    keep: Path | None = None,
    *,
    reason: str | None = None,
    reraise: Callable[[BaseException], bool] | None = None,
    correct: Callable[[Any], tuple[Any, Any]] | None = None,
) -> dict[str, Any]:
    """Process an archived run again from its archived raw files.

    Parameters
    ----------
    archive : the archive to read the run from and to archive the result to.
    run_id : the run.
    keep : rebuild the run folder here and leave it; None: a temporary folder.
    reason : why, kept with a new revision (`pipelines.process.process_run`).
    reraise : errors to raise rather than report (`process_run`).
    correct : a correction of the loaded run's reference (`process_run`, `pipelines.impact`);
        None: the current revision's own correction, if it has one (it is carried over).

    Returns
    -------
    The run's entry of the `calib process --json` document; ``source`` is
    ``archive:<run_id>``. Status "duplicate" when the settings and software are
    unchanged, "revised" with a new revision otherwise, or "failed".

    Raises
    ------
    ReprocessError when the archive cannot give the run back (`restore_run`).
    """
    from pipelines.process import process_run
    from pipelines.reference_correction import carried_correction

    if correct is None:
        try:
            correct = carried_correction(archive, run_id)
        except LookupError as exc:
            raise ReprocessError(str(exc)) from None
    with tempfile.TemporaryDirectory(prefix=f"reprocess_{run_id}_") as tmp:
        folder = Path(keep) if keep is not None else Path(tmp) / run_id
        source = restore_run(archive, run_id, folder, link=keep is None)
        outcome = process_run(source, archive, reraise=reraise, reason=reason, correct=correct)
    outcome["source"] = f"archive:{run_id}"
    outcome["run_id"] = outcome["run_id"] or run_id  # a failed write names its run too
    if outcome["status"] == "ok":  # the run was archived before: "ok" is a new revision
        outcome["status"] = "revised"
    return outcome


# --- a selection of archived runs (calib reprocess --all / --serial / ...) -----------


def reprocess_run_for_batch(
    run_id: str, archive_url: str, archive_root: str, reason: str
) -> dict[str, Any]:
    """One run of a reprocessing batch, in whichever process the task's work runs.

    Returns the run's outcome (status "revised", "duplicate" or "failed" with the
    reason, e.g. a raw object missing from the file store); raises
    ``pipelines.run_task.TransientError`` for a failure worth another attempt.
    """
    from pipelines.process import run_outcome
    from pipelines.run_task import TransientError, batch_archive, is_transient

    archive = batch_archive(archive_url, archive_root)
    try:
        return reprocess_run(archive, run_id, reason=reason, reraise=is_transient)
    except ReprocessError as exc:
        return run_outcome(
            source=f"archive:{run_id}", serial="", status="failed", run_id=run_id, error=str(exc)
        )
    except Exception as exc:  # only what is_transient let through
        archive.dispose()  # the retry connects afresh
        raise TransientError(f"{run_id}: {type(exc).__name__}: {exc}") from exc


def plan_reprocess(
    archive: Archive, selection: dict[str, Any]
) -> tuple[list[str], list[dict[str, Any]]]:
    """The selected runs still to reprocess, and the outcomes of those already done.

    A run is already done when one of its calibrations was made by this software
    with the settings it would get now: its own settings and procedure, and the
    tolerance profile it names at the version that profile has now. That is the
    archive's own duplicate rule (same settings hash, same software version;
    storage.archive), applied before any work, so running an interrupted
    reprocessing again goes on where it stopped.

    Parameters
    ----------
    archive : the archive.
    selection : filters of `storage.queries.select_runs` (serial, model, since,
        until, software_version, profile); None values are left out.

    Returns
    -------
    (run ids to reprocess, oldest first; "duplicate" outcomes of the others).
    """
    from pipelines import process
    from storage import queries

    unknown = set(selection) - set(queries.SELECTION_KEYS)
    if unknown:
        raise ValueError(f"selection: unknown filter(s) {sorted(unknown)}")
    runs = queries.select_runs(archive, **{k: v for k, v in selection.items() if v is not None})
    version_of = _profile_versions()
    todo: list[str] = []
    skipped: list[dict[str, Any]] = []
    for run in runs:
        done = _done_by(run, process.SOFTWARE_VERSION, version_of)
        if done is None:
            todo.append(run["run_id"])
            continue
        skipped.append(
            process.run_outcome(
                source=f"archive:{run['run_id']}",
                serial=run["serial"],
                status="duplicate",
                run_id=run["run_id"],
                verdict_=done["verdict"],
                message=f"already processed by software {done['software_version']} with these "
                f"settings (revision {done['revision']})",
            )
        )
    return todo, skipped


def _profile_versions():  # noqa: ANN202 - a cached lookup
    """name -> version of the tolerance profile as it is now (None: cannot be loaded)."""
    from functools import cache

    from pipelines.tolerances import load_profile

    @cache
    def version(name: str | None) -> str | None:
        if name is None:
            return None
        try:
            return load_profile(name).version
        except ValueError:  # the reprocessing itself reports it, with the run
            return None

    return version


def _done_by(run: dict[str, Any], software: str, version_of) -> dict[str, Any] | None:  # noqa: ANN001
    """The calibration of `run` that reprocessing it now would duplicate, or None."""
    from storage.settings_hash import settings_hash

    for cal in run["calibrations"]:
        if cal["software_version"] != software:
            continue
        version = version_of(cal["profile_name"])
        if version is None:
            continue
        if cal["settings_hash"] == settings_hash(
            cal["settings"], run["procedure"], cal["profile_name"], version
        ):
            return cal
    return None


REASON_MAX = 500  # characters of a reprocessing reason


def check_reason(reason: str) -> str:
    """The reason of a reprocessing: 1-REASON_MAX printable characters, else ValueError."""
    if not isinstance(reason, str) or not reason.strip():
        raise ValueError("--reason: say why the runs are processed again (e.g. 'software 0.4')")
    if len(reason) > REASON_MAX or not reason.isprintable():
        raise ValueError(
            f"--reason: expected at most {REASON_MAX} printable characters, got {reason[:80]!r}"
        )
    return reason


def summarize(outcomes: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts of a reprocessing batch and the reason of every failure.

    Returns
    -------
    dict: runs, revised, duplicate, failed (counts) and ``failures``, a list of
    {run_id, error}.
    """
    count = {s: sum(o["status"] == s for o in outcomes) for s in ("revised", "duplicate", "failed")}
    failures = [
        {"run_id": o["run_id"], "error": o["error"]} for o in outcomes if o["status"] == "failed"
    ]
    return {"runs": len(outcomes), **count, "failures": failures}


def reprocess_in_process(
    archive: Archive,
    todo: list[str],
    skipped: list[dict[str, Any]],
    reason: str,
    on_progress: Callable[[int, int, dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """A small reprocessing without Prefect (as `pipelines.direct` for `calib process`).

    `todo` and `skipped` are what `plan_reprocess` gave; the outcomes come in the
    order of `reprocess_batch`'s (skipped first), with the same retries.
    """
    from pipelines.issuing import issuing_beside
    from pipelines.run_task import gave_up, run_in_process

    with issuing_beside() as certificates:  # each certificate beside the next run
        outcomes = run_in_process(
            todo,
            lambda r: reprocess_run_for_batch(r, archive.url, str(archive.root), reason),
            lambda r, exc: gave_up(f"archive:{r}", "", exc, r),
            on_progress,
            done=skipped,
        )
    return certificates.reported(outcomes)


def changed_pairs(
    archive: Archive, outcomes: list[dict[str, Any]], reason: str | None = None
) -> list[dict[str, Any]]:
    """The revision pairs (`storage.queries.revision_pairs`) of the runs a reprocessing
    revised: now, or (with its `reason`) by an earlier, interrupted pass of the same
    reprocessing, whose revision with that reason is current (skipped now as duplicates).
    A duplicate whose current revision another write made (another reason, `calib impact
    --apply`) is not in it: this reprocessing changed nothing there."""
    from pipelines import process
    from storage import queries

    revised = [o["run_id"] for o in outcomes if o["status"] == "revised"]
    again = [o["run_id"] for o in outcomes if o["status"] == "duplicate"]
    earlier = queries.revised_for(archive, again, reason) if reason and again else set()
    return [
        p
        for p in queries.revision_pairs(archive, revised + again)
        if p["new"]["software_version"] == process.SOFTWARE_VERSION
        and (p["run_id"] in revised or (p["run_id"], p["new"]["revision"]) in earlier)
    ]
