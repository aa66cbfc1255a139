"""Recomputation, the pipeline glue: every archived revision solved again from its raw
bytes and compared with its sealed record (`calib verify --recompute`, docs/archive.md).

A seal proves that a revision's rows are those written; it cannot prove that they are what
the run's raw bytes give: a writer may seal made-up numbers with the project's own code.
Here each revision of a run is solved again by the path `calib process` takes
(`pipelines.process.load_source` and `derive_run`) from the raw files the archive holds
(`pipelines.reprocess.restore_run`, each hash checked), with what the revision records:

- its reason (step ``reprocess``) and its reference correction (settings
  ``reference_correction``, with the look-back record its step carries);
- what it was judged against (`pipelines.process.AsJudged`): the tolerance profile's
  thresholds its ``check`` step holds (not the profile file of now), the repeatability
  group that step holds, with their values as of the revision; the earlier calibration of
  its ``as_found`` step; for a revision judged again, its last ``rejudge`` step's runs.

The result is compared with the revision's rows (which `calib verify` compares with the
seal) value for value: parameters, checks, steps, the calibration row with its document,
the protocol's SHA-256 and the run's own fields. The wall times a step records
(`calib_core.calibration.WALL_TIMES`) are the one thing left out. Made by this software
version, any difference is tampering or a result that does not reproduce: ``differs``,
naming the first differing field (``parameters/acc.bias.x/value``). Made by another version,
differences are expected: ``changed``, with the change report `calib reprocess` prints
(`pipelines.changes`).
"""

from __future__ import annotations

import json
import random
import re
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from storage.db import Archive

STATUSES = ("identical", "differs", "changed", "failed")
DIFFERENCES_MAX = 20  # differing fields listed per revision (all are counted)
# The record's parts, compared in this order: the first difference names the most telling.
PARTS = ("parameters", "check_results", "processing_steps", "calibrations", "files", "runs")


def plan_recompute(
    archive: Archive, run_ids: list[str] | None = None, sample: int | None = None
) -> list[str]:
    """The runs to recompute: `run_ids` (prefixes resolved), `sample` runs drawn at random
    (a fresh draw each time: a writer cannot know which runs will be checked), or every
    run (both None), oldest first.

    Raises LookupError for an unknown run id, ValueError for a sample size below 1.
    """
    from storage import queries

    if run_ids:
        return [queries.full_run_id(archive, r) for r in run_ids]
    every = [r["run_id"] for r in queries.select_runs(archive)]
    if sample is None:
        return every
    if sample < 1:
        raise ValueError(f"--sample: expected a number of runs >= 1, got {sample}")
    chosen = set(random.SystemRandom().sample(every, min(sample, len(every))))
    return [r for r in every if r in chosen]


def recompute_run(archive: Archive, run_id: str) -> dict[str, Any]:
    """Every revision of one run solved again and compared with its rows.

    Returns
    -------
    dict: run_id, serial, status (the worst of its revisions': "identical", "changed",
    "differs" or "failed"), error (a run that could not be solved again), and
    ``revisions``: per revision its revision, software_version, status, first_difference
    (``table/row/field``: what the archive holds, what the solve gives), differences
    (count), fields (the first `DIFFERENCES_MAX` paths) and, made by another software
    version, ``changes`` (`pipelines.changes.change_report` of the pair).
    """
    from pipelines.reprocess import ReprocessError, restore_run
    from storage import queries

    sealed = queries.archived_revisions(archive, run_id)
    serial = sealed[0]["devices"]["serial"] if sealed else ""
    out: dict[str, Any] = {"run_id": run_id, "serial": serial, "error": None, "revisions": []}
    try:
        with tempfile.TemporaryDirectory(prefix=f"recompute_{run_id}_") as tmp:
            source = restore_run(archive, run_id, Path(tmp) / run_id, link=True)
            out["revisions"] = [_recompute_revision(archive, source, rec) for rec in sealed]
    except (ReprocessError, LookupError) as exc:
        out["error"] = str(exc)
    worst = [r["status"] for r in out["revisions"]] + (["failed"] if out["error"] else [])
    out["status"] = max(worst or ["identical"], key=_severity)
    return out


def _severity(status: str) -> int:
    return ("identical", "changed", "differs", "failed").index(status)


def _recompute_revision(archive: Archive, source: Any, rec: dict[str, Any]) -> dict[str, Any]:
    """One revision solved again (module docstring) and compared with `rec`."""
    from pipelines.process import SOFTWARE_VERSION, derive_run, load_source
    from pipelines.reference_correction import correction_of
    from pipelines.run_task import is_transient
    from storage import rawstore

    cal = rec["calibrations"]
    steps = sorted(rec["processing_steps"].values(), key=lambda s: s["seq"])
    head = {"revision": cal["revision"], "software_version": cal["software_version"]}
    reason = next((s["settings"]["reason"] for s in steps if s["name"] == "reprocess"), None)
    impact = next(
        (
            (s["statistics"] or {}).get("impact")
            for s in steps
            if s["name"] == "reference_correction"
        ),
        None,
    )
    pending = rawstore.PendingFiles()
    try:
        correct = correction_of(cal["settings"], impact)
        loaded, first = load_source(source, archive, pending, reason=reason, correct=correct)
        derived = derive_run(loaded, first, archive, as_judged(rec, steps))
    except Exception as exc:  # noqa: BLE001 - a revision that no longer solves is a finding
        if is_transient(exc):
            raise
        return {**head, "status": "failed", "error": f"{type(exc).__name__}: {exc}"}
    finally:
        pending.close()
    expected = expected_record(derived, rec, steps)
    found = differences(rec, expected, list(rec["raw_files"]))
    entry = {**head, "status": "identical", "differences": len(found)}
    entry["fields"] = [f["path"] for f in found[:DIFFERENCES_MAX]]
    entry["first_difference"] = found[0] if found else None
    if found and cal["software_version"] != SOFTWARE_VERSION:
        entry["status"] = "changed"
        entry["changes"] = _change_report(rec, derived)
    elif found:
        entry["status"] = "differs"
        # The same version string from other sources (a development tree): say so, as a
        # code change explains a difference that tampering would otherwise have to.
        entry["source_revisions"] = [cal["source_revision"], derived.run.source_revision]
    return entry


def as_judged(rec: dict[str, Any], steps: list[dict[str, Any]]) -> Any:
    """What the revision records it was judged against (`pipelines.process.AsJudged`)."""
    from calib_core.tolerances import ToleranceProfile
    from pipelines.process import AsJudged

    check = next((s for s in steps if s["name"] == "check"), None) or {}
    group = (check.get("statistics") or {}).get("repeatability_group") or []
    thresholds = (check.get("settings") or {}).get("thresholds")
    profile = None if thresholds is None else ToleranceProfile.from_dict(thresholds)
    found = next((s["settings"] for s in steps if s["name"] == "as_found"), None)
    earlier = None if found is None else (found["earlier_run_id"], found["earlier_revision"])
    return AsJudged(rec["cal_id"], tuple(group), earlier, profile)


def expected_record(
    derived: Any, rec: dict[str, Any], steps: list[dict[str, Any]]
) -> dict[str, Any]:
    """The rows `derived` (`pipelines.process.Derived`) gives, in the form of `rec`.

    A revision judged again (``rejudge`` steps) keeps its recorded rejudge steps; the
    last one's outcome (group, verdict) is the solve's, its settings hash covers the runs
    that step names (`storage.settings_hash`).
    """
    from storage.revision_rows import check_rows, step_row
    from storage.run_input import calibration_document, run_row, settings_hash_of
    from storage.seal_record import labelled
    from storage.settings_hash import JUDGED_AGAINST, REJUDGE_STEP, settings_hash

    run = derived.run
    cal = {
        "settings_hash": settings_hash_of(run),
        "settings": run.settings,
        "software_version": run.software_version,
        "document": calibration_document(run),
        "verdict": run.verdict,
        "profile_name": run.profile_name,
        "profile_version": run.profile_version,
    }
    made = [step_row(0, 0, i, st, None) for i, st in enumerate(run.steps)]
    again = [s for s in steps if s["name"] == REJUDGE_STEP]
    files = {derived.protocol_name: _sha256(derived.extra_files[derived.protocol_name])}
    if again:  # judged again: no files of its own, its rejudge steps after the solve's
        last = again[-1]
        against = (last["settings"] or {}).get(JUDGED_AGAINST)
        if against is not None:
            cal["settings_hash"] = settings_hash(
                run.settings, run.procedure, run.profile_name, run.profile_version, against
            )
        group = derived.judged.step.statistics.get("repeatability_group")
        outcome = {"repeatability_group": group, "verdict": run.verdict}
        made += [{**s, "statistics": s["statistics"]} for s in again[:-1]]
        made.append({**last, "statistics": outcome})
        made = [{**s, "seq": i} for i, s in enumerate(made)]
        files = {}
    checks = check_rows(0, run.checks, run.profile_name, run.profile_version)
    return {
        "runs": run_row(run),
        "calibrations": cal,
        "parameters": {p.name: p.to_row(run.parameter_temperature_c) for p in run.parameters},
        "check_results": labelled([(c["name"], c) for c in sorted(checks, key=_name)]),
        "processing_steps": {f"{s['seq']}:{s['name']}": s for s in made},
        "files": files,
    }


def _name(row: dict[str, Any]) -> str:
    return row["name"]


def _sha256(data: bytes) -> str:
    from hashlib import sha256

    return sha256(data).hexdigest()


def differences(
    rec: dict[str, Any], expected: dict[str, Any], names: list[str]
) -> list[dict[str, Any]]:
    """Every field where the archived revision `rec` and the solve's `expected` differ, in
    `PARTS` order: path (``table/row/field``), archived, recomputed (canonical JSON).

    `names` : the run's raw file names. Where a value names a file with its folder (a
    segment's source, a finding's detail), the folder it was read from is left out: the
    run was processed from wherever it lay, and is solved again from a temporary one.
    """
    at = _folders(names)
    found: list[dict[str, Any]] = []
    for part in PARTS:
        held, made = rec.get(part) or {}, expected[part]
        if part == "files":  # the seal's paths hold the revision's folder: compare by name
            held = {Path(p).name: sha for p, sha in held.items()}
            found += _compare(part, held, made, at)
        elif part in ("runs", "calibrations"):
            found += _compare(part, {f: held.get(f) for f in made}, made, at)
        else:
            for row in sorted(set(held) | set(made)):
                path = f"{part}/{row}"
                if row not in held or row not in made:
                    where = "the archive" if row in held else "the solve"
                    found.append(_difference(path, held.get(row), made.get(row), where))
                    continue
                fields = [f for f in held[row] if f not in ("seq", "source_revision")]
                pick = {f: held[row][f] for f in fields}
                found += _compare(path, pick, {f: made[row].get(f) for f in fields}, at)
    return found


def _folders(names: list[str]) -> re.Pattern[str]:
    """The folder part before any of the raw file `names` in a JSON text."""
    files = "|".join(re.escape(n) for n in sorted(names, key=len, reverse=True))
    return re.compile(rf"[^\"(\s]*[/\\]+(?=(?:{files})\b)" if names else r"(?!)")


def _compare(
    path: str, held: dict[str, Any], made: dict[str, Any], at: re.Pattern[str]
) -> list[dict[str, Any]]:
    out = []
    for name in sorted(set(held) | set(made)):
        a, b = _normal(held.get(name), name), _normal(made.get(name), name)
        if a != b and at.sub("", a) != at.sub("", b):
            out.append({"path": f"{path}/{name}", "archived": a, "recomputed": b})
    return out


def _difference(path: str, held: Any, made: Any, where: str) -> dict[str, Any]:
    return {
        "path": path,
        "archived": _normal(held, ""),
        "recomputed": _normal(made, ""),
        "only_in": where,
    }


def _normal(value: Any, name: str) -> str:
    """Canonical JSON of a value (times in UTC; a step's wall times left out)."""
    if name == "statistics" and isinstance(value, dict):
        from calib_core.calibration import WALL_TIMES

        value = {k: v for k, v in value.items() if k not in WALL_TIMES}
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=_plain)


def _plain(value: Any) -> Any:
    if isinstance(value, datetime):
        return value.astimezone(UTC).isoformat()
    if hasattr(value, "tolist"):  # a NumPy scalar or array, as the JSON column stored it
        return value.tolist()
    if hasattr(value, "isoformat"):
        return value.isoformat()
    raise TypeError(f"{type(value).__name__} is not part of a record")


def _change_report(rec: dict[str, Any], derived: Any) -> dict[str, Any]:
    """`calib reprocess`'s change report of the archived revision against the solve."""
    from pipelines.changes import change_report

    old = {n: (p["value"], p["std"]) for n, p in rec["parameters"].items()}
    new = {p.name: (p.value, p.std) for p in derived.run.parameters}
    pair = {
        "run_id": rec["runs"]["run_id"],
        "new": {"verdict": derived.run.verdict, "parameters": new},
        "old": {"verdict": rec["calibrations"]["verdict"], "parameters": old},
    }
    return change_report([pair])


# --- a batch -------------------------------------------------------------------


def recompute_run_for_batch(run_id: str, archive_url: str, archive_root: str) -> dict[str, Any]:
    """One run of a recomputation, in whichever process the task's work runs; raises
    ``pipelines.run_task.TransientError`` for a failure worth another attempt."""
    from pipelines.run_task import TransientError, batch_archive, is_transient

    archive = batch_archive(archive_url, archive_root)
    try:
        return recompute_run(archive, run_id)
    except Exception as exc:  # noqa: BLE001 - a batch goes on past a run
        if not is_transient(exc):
            return failed_outcome(run_id, exc)
        archive.dispose()  # the retry connects afresh
        raise TransientError(f"{run_id}: {type(exc).__name__}: {exc}") from exc


def failed_outcome(run_id: str, exc: BaseException) -> dict[str, Any]:
    """The outcome of a run that could not be recomputed (past its retries)."""
    return {
        "run_id": run_id,
        "serial": "",
        "status": "failed",
        "error": f"{type(exc).__name__}: {exc}",
        "revisions": [],
    }


def summarize(outcomes: list[dict[str, Any]]) -> dict[str, Any]:
    """Runs and revisions per status; ``ok`` when every revision is identical or was made by
    another software version (``changed``)."""
    revisions = [r for o in outcomes for r in o["revisions"]]
    return {
        "ok": all(o["status"] in ("identical", "changed") for o in outcomes),
        "runs": {s: sum(o["status"] == s for o in outcomes) for s in STATUSES},
        "revisions": {s: sum(r["status"] == s for r in revisions) for s in STATUSES},
    }


def problem_lines(outcomes: list[dict[str, Any]]) -> list[str]:
    """One line per revision that differs or failed: run, revision, the first field."""
    lines = []
    for o in outcomes:
        if o["error"]:
            lines.append(f"FAILED\t{o['run_id']}\t-\t{o['error']}")
        for r in o["revisions"]:
            if r["status"] == "failed":
                lines.append(f"FAILED\t{o['run_id']}\t{r['revision']}\t{r['error']}")
            elif r["status"] == "differs":
                d = r["first_difference"]
                made, now = r["source_revisions"]
                source = "" if made == now else f", source {made}, solved by source {now}"
                lines.append(
                    f"DIFFERS\t{o['run_id']}\t{r['revision']}\t{d['path']}: archived "
                    f"{d['archived']}, recomputed {d['recomputed']} ({r['differences']} "
                    f"field(s) differ; made by this software {r['software_version']}{source})"
                )
    return lines


def recompute_in_process(
    archive: Archive, run_ids: list[str], on_progress: Any = None
) -> list[dict[str, Any]]:
    """A small recomputation without Prefect (as `pipelines.direct` for `calib process`)."""
    from pipelines.run_task import run_in_process

    return run_in_process(
        run_ids,
        lambda r: recompute_run_for_batch(r, archive.url, str(archive.root)),
        failed_outcome,
        on_progress,
    )
