"""The check of the audit chain and of every seal against the rows and files as they
are now (storage.verify calls it; storage.seal writes both).
"""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from sqlalchemy import Connection, select, text

from storage import schema, validation
from storage.schema import AuditEvent, Seal
from storage.seal import APPEND_EVENT, EVENT_FIELDS, GENESIS, ISSUED, SEALING, Event, head
from storage.seal_record import (
    FORMAT,
    FORMATS,
    TEXTS,
    canonical,
    chunks,
    digest_of,
    record_format,
    records,
    text_digest,
    without_texts,
)


@dataclass
class Finding:
    """One thing `check` found: kind ("chain" or "record"), table/row/field path, runs, detail."""

    kind: str
    path: str
    runs: list[str]
    detail: str


@dataclass
class ChainCheck:
    """What `check` found and saw."""

    findings: list[Finding]
    head: tuple[int, str]  # (seq, hash) of the newest event
    seals_checked: int
    digests_now: dict[tuple[str, int], str]  # (run id, revision) -> digest of its rows now


def check(conn: Connection, root: Path) -> ChainCheck:
    """Check the chain and every seal against the rows and files as they are now."""
    findings, sealing = _check_chain(conn)
    seal_ids = conn.execute(select(Seal.id).order_by(Seal.id)).scalars().all()
    digests_now: dict[tuple[str, int], str] = {}
    for chunk in chunks(list(seal_ids)):
        # The sealed record itself is read only where the rows no longer give its digest.
        seals = conn.execute(
            select(
                Seal.id,
                Seal.calibration_id,
                Seal.digest,
                Seal.record["files"].label("files"),
                Seal.record["format"].label("format"),
            ).where(Seal.id.in_(chunk))
        ).all()
        files = {s.calibration_id: rehash_files(root, s.files or {}) for s in seals}
        now = _records_as_sealed(conn, {s.calibration_id: s.format for s in seals}, files)
        for s in seals:
            rec = now.get(s.calibration_id)
            if rec is not None:
                key = (rec["runs"]["run_id"], rec["calibrations"]["revision"])
                digests_now[key] = digest_of(rec)
                if digests_now[key] == s.digest == sealing.get(key):
                    del sealing[key]
                    continue
            sealed, texts = conn.execute(
                select(Seal.record, Seal.texts).where(Seal.id == s.id)
            ).one()
            if isinstance(sealed, dict) and texts is not None:
                sealed = {**sealed, TEXTS: texts}
            findings += _check_seal(s.digest, sealed, rec, sealing)
    findings += [
        Finding(
            "chain",
            "seals",
            [run_id],
            f"revision {rev} was sealed (digest {digest[:12]}...) but its seal row is gone",
        )
        for (run_id, rev), digest in sorted(sealing.items())
    ]
    unsealed = conn.execute(
        select(schema.Run.run_id, schema.CalibrationRow.revision)
        .join(schema.Run, schema.Run.id == schema.CalibrationRow.run_id)
        .where(schema.CalibrationRow.id.not_in(select(Seal.calibration_id)))
    ).all()
    findings += [
        Finding(
            "chain",
            "calibrations",
            [run_id],
            f"revision {rev} has no seal: added behind the archive's back",
        )
        for run_id, rev in unsealed
    ]
    findings += _check_issued(conn, root)
    findings += [
        Finding("record", "validations", [run_id], detail)
        for run_id, detail in validation.check_records(conn)
    ]
    return ChainCheck(findings, head(conn), len(seal_ids), digests_now)


def _check_issued(conn: Connection, root: Path) -> list[Finding]:
    """Every file of an issued certificate against the SHA-256 its event recorded."""
    out: list[Finding] = []
    rows = conn.execute(
        select(AuditEvent.run_id, AuditEvent.revision, AuditEvent.detail)
        .where(AuditEvent.action == ISSUED)
        .order_by(AuditEvent.seq)
    ).all()
    for run_id, rev, detail in rows:
        files = (detail or {}).get("files") or {}
        for rel, now in rehash_files(root, files).items():
            if now != files[rel]:
                what = (
                    "is missing"
                    if now == "(missing)"
                    else f"changed: issued with SHA-256 {files[rel][:12]}..., now {now[:12]}..."
                )
                out.append(
                    Finding(
                        "record",
                        "certificates",
                        [run_id or "?"],
                        f"{run_id} revision {rev}: issued file {rel} {what}",
                    )
                )
    return out


def _records_as_sealed(
    conn: Connection, formats: dict[int, Any], files: dict[int, dict[str, str]]
) -> dict[int, dict[str, Any]]:
    """The record of each calibration now, in the format its seal names (calibration id ->
    sealed ``format`` value); a format this version cannot read gets the current one."""
    by_form: dict[int, list[int]] = defaultdict(list)
    for cal_id, value in formats.items():
        form = record_format(value)
        by_form[form if form in FORMATS else FORMAT].append(cal_id)
    out: dict[int, dict[str, Any]] = {}
    for form, ids in by_form.items():
        out |= records(conn, ids, files, form=form)
    return out


def digest_now(conn: Connection, cal_id: int, files: dict[str, str], sealed_format: Any) -> str:
    """The digest of a calibration's rows and `files` (path: SHA-256 now) as they are now,
    in the record format its seal names (the seal's ``format`` value)."""
    return digest_of(_records_as_sealed(conn, {cal_id: sealed_format}, {cal_id: files})[cal_id])


def rehash_files(root: Path, files: dict[str, str]) -> dict[str, str]:
    """The SHA-256 of each file (paths relative to `root`) now; "(missing)" if gone."""
    # Imported here: the file store loads pyarrow, which the audit trail's readers
    # (calib audit, approvals) never need.
    from storage.rawstore import hash_and_size

    out = {}
    for rel in files:
        p = (root / rel).resolve()
        ok = p.is_relative_to(root.resolve()) and p.is_file()
        out[rel] = hash_and_size(p)[0] if ok else "(missing)"
    return out


def _check_chain(conn: Connection) -> tuple[list[Finding], dict[tuple[str, int], str]]:
    """The chain's links, and that its events match the rows (`_check_event_rows`); also
    (run_id, revision) -> digest of every sealing event."""
    findings: list[Finding] = []
    sealing: dict[tuple[str, int], str] = {}
    named: list[Event] = []  # the events naming a run
    prev_seq, prev_hash = 0, GENESIS
    rows = conn.execution_options(yield_per=5000).execute(
        select(AuditEvent).order_by(AuditEvent.seq)
    )
    for row in rows:
        ev = Event(**{k: getattr(row, k) for k in EVENT_FIELDS})
        where = f"event {ev.seq} ({ev.action}{' of ' + ev.run_id if ev.run_id else ''})"
        problems = []
        if ev.seq != prev_seq + 1:
            problems.append(f"events {prev_seq + 1}..{ev.seq - 1} are missing before {where}")
        if ev.prev_hash != prev_hash:
            problems.append(
                f"{where} does not follow the event before it: "
                f"expected previous hash {prev_hash}, found {ev.prev_hash}"
            )
        if ev.hash() != row.hash:
            problems.append(
                f"{where} was changed: its fields hash to {ev.hash()}, stored hash {row.hash}"
            )
        if ev.action in SEALING and ev.run_id and ev.digest:
            if (ev.run_id, ev.revision) in sealing:
                problems.append(f"{where} seals revision {ev.revision} a second time")
            sealing.setdefault((ev.run_id, ev.revision), ev.digest)
        elif ev.action in SEALING:
            problems.append(
                f"{where} lacks its run, revision or digest: a sealing event names all three"
            )
        runs = [ev.run_id] if ev.run_id else []
        findings += [Finding("chain", "audit_events", runs, p) for p in problems]
        if ev.run_id is not None or ev.action in NAMES_REVISION:
            named.append(ev)
        prev_seq, prev_hash = ev.seq, row.hash
    findings += _check_event_rows(conn, named)
    return findings, sealing


# Actions whose event names one revision of one run.
NAMES_REVISION = (*SEALING, "approved", ISSUED)


def _check_event_rows(conn: Connection, events: list[Event]) -> list[Finding]:
    """Every event naming a run names one the archive holds, and (for an action of one
    revision) a revision of it that the archive holds."""
    runs = set(conn.execute(select(schema.Run.run_id)).scalars())
    revisions = {
        (run_id, rev)
        for run_id, rev in conn.execute(
            select(schema.Run.run_id, schema.CalibrationRow.revision).join(
                schema.Run, schema.Run.id == schema.CalibrationRow.run_id
            )
        )
    }
    out = _check_writers(conn, events)
    for ev in events:
        where = f"event {ev.seq} ({ev.action} by {ev.actor})"
        if ev.run_id is None:
            if ev.action in SEALING:
                continue  # reported by _check_chain
            what = "no run"
        elif ev.run_id not in runs:
            what = f"run {ev.run_id}, which the archive does not hold"
        elif ev.action in NAMES_REVISION and (ev.run_id, ev.revision) not in revisions:
            what = f"revision {ev.revision} of run {ev.run_id}, which the archive does not hold"
        else:
            continue
        out.append(
            Finding(
                "chain", "audit_events", [ev.run_id] if ev.run_id else [], f"{where} names {what}"
            )
        )
    return out


def _check_seal(
    digest: str,
    sealed: Any,
    now: dict[str, Any] | None,
    sealing: dict[tuple[str, int], str],
) -> list[Finding]:
    sealed = sealed if isinstance(sealed, dict) else {}
    run_id = (sealed.get("runs") or {}).get("run_id", "?")
    rev = (sealed.get("calibrations") or {}).get("revision")
    where = f"{run_id} revision {rev}"
    out: list[Finding] = []
    chained = sealing.pop((run_id, rev), None)
    seal_finding = partial(Finding, "chain", "seals", [run_id])
    if digest_of(sealed) != digest or chained != digest:
        out.append(
            seal_finding(
                f"the seal of {where} was changed: it no longer matches the digest "
                f"in the audit chain ({(chained or 'none')[:12]}...)"
            )
        )
    if record_format(sealed.get("format")) not in FORMATS:
        return [
            *out,
            seal_finding(
                f"the seal of {where} is in record format {sealed.get('format')!r}, "
                f"which this version of calib (formats {FORMATS}) cannot read: "
                "verify with the version that wrote it"
            ),
        ]
    if now is None:
        gone = f"{where} is sealed but its rows are gone (deleted)"
        return [*out, Finding("record", "calibrations", [run_id], gone)]
    if digest_of(now) == digest:
        return out
    return out + [
        Finding(
            "record", "/".join(keys), [run_id], f"{where}: sealed {_show(old)}, found {_show(new)}"
        )
        for keys, old, new in _record_differences(sealed, now)
    ]


_ABSENT = object()


def _record_differences(sealed: dict[str, Any], now: dict[str, Any]) -> list[tuple]:
    """(keys, sealed value, value now) of every field that differs. A JSON column's
    change (format 2: its hash) is followed into the JSON where both texts are at hand."""
    out = []
    for keys, expected, found in differences(without_texts(sealed), without_texts(now)):
        out += _into_json(keys, expected, found, sealed.get(TEXTS), now.get(TEXTS))
    return out


def _into_json(
    keys: tuple[str, ...], expected: Any, found: Any, sealed_texts: Any, now_texts: Any
) -> list[tuple]:
    """The differences inside a JSON column whose sealed and present texts hash to what
    the records hold; else (or for equal JSON in other text) the hashes themselves."""
    old, new = _text_at(sealed_texts, keys), _text_at(now_texts, keys)
    if old is None or new is None or (text_digest(old), text_digest(new)) != (expected, found):
        return [(keys, expected, found)]
    try:
        inner = differences(json.loads(old), json.loads(new), keys)
    except ValueError:  # text that is not JSON, written behind the archive's back
        return [(keys, expected, found)]
    return inner or [(keys, expected, found)]


def _text_at(texts: Any, keys: tuple[str, ...]) -> str | None:
    for key in keys:
        if not isinstance(texts, dict):
            return None
        texts = texts.get(key)
    return texts if isinstance(texts, str) else None


def differences(sealed: Any, now: Any, keys: tuple[str, ...] = ()) -> list[tuple]:
    """(keys, sealed value, value now) of every leaf that differs; absent is `_ABSENT`."""
    if isinstance(sealed, dict) and isinstance(now, dict):
        out = []
        for key in sorted(set(sealed) | set(now), key=str):
            out += differences(sealed.get(key, _ABSENT), now.get(key, _ABSENT), (*keys, str(key)))
        return out
    if canonical_or_none(sealed) == canonical_or_none(now):
        return []
    return [(keys, sealed, now)]


def canonical_or_none(value: Any) -> bytes | None:
    return None if value is _ABSENT else canonical(value)


def _show(value: Any) -> str:
    if value is _ABSENT:
        return "(absent)"
    text_ = canonical(value).decode()
    return text_ if len(text_) <= 120 else text_[:117] + "..."


# PostgreSQL: each role that wrote an event, whether it may add runs and append events now.
_ROLE_RIGHTS = text(
    "SELECT r.rolname, has_table_privilege(r.oid, 'runs', 'INSERT'), "
    "has_table_privilege(r.oid, 'audit_events', 'INSERT') OR coalesce("
    "has_function_privilege(r.oid, to_regprocedure(:f), 'EXECUTE'), false) "
    "FROM pg_roles r WHERE r.rolname = ANY(:names)"
)


def _check_writers(conn: Connection, events: list[Event]) -> list[Finding]:
    """PostgreSQL: the writer recorded with each event (its session user, migration 0009)
    may hold the event's role: a sealing event's may add runs (the writer role or the
    owner), an approval's may append events (the approver, writer or owner role). Events
    without a recorded writer (before 0009) and SQLite's OS users are not judged here."""
    users = {ev.db_user for ev in events if ev.db_user}
    if conn.dialect.name != "postgresql" or not users:
        return []
    rights = {
        name: (adds_runs, appends)
        for name, adds_runs, appends in conn.execute(
            _ROLE_RIGHTS, {"f": APPEND_EVENT, "names": sorted(users)}
        )
    }
    out = []
    for ev in events:
        if not ev.db_user or ev.action not in (*SEALING, "approved"):
            continue
        adds_runs, appends = rights.get(ev.db_user, (None, None))
        may = adds_runs if ev.action in SEALING else appends
        if may:
            continue
        why = (
            "no longer exists: its right to write cannot be confirmed"
            if may is None
            else ("may not add runs" if ev.action in SEALING else "may not append events")
        )
        out.append(
            Finding(
                "chain",
                "audit_events",
                [ev.run_id] if ev.run_id else [],
                f"event {ev.seq} ({ev.action} of {ev.run_id}, actor {ev.actor}) was written "
                f"by database role {ev.db_user}, which {why}",
            )
        )
    return out
