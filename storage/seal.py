"""Seals and the audit chain: what makes a change behind the archive's back visible.

Every calibration revision is *sealed* in the transaction that archives it: its
*record* is read back from the rows just written (run with the unit as it
describes it, device, equipment links, raw files, calibration with its document,
steps, parameters, checks) together with the SHA-256 of every file the revision
wrote (protocol...), serialised as canonical JSON, and hashed (the *digest*). The
record is kept in ``seals`` so a later mismatch can be shown field by field; the
digest goes into an event of the audit chain.

The audit chain (``audit_events``) is append-only: every write to the archive
(run archived, revision, approval, repair, restore, thermal model, role change,
migration) is an event with who, when, what and why, numbered by ``seq`` and
hashed over its fields and the hash of the event before it. Changing, deleting or
reordering an event breaks the chain; changing a sealed row changes the record's
digest; deleting a run leaves a sealed event without its rows. `check` reports
each of these (storage.verify calls it). What a hash chain alone cannot show is
the removal of the *last* events: `head` gives the newest event's seq and hash,
to be written down elsewhere (the verify summary prints it) and compared later.
"""

from __future__ import annotations

import getpass
import hashlib
import json
import os
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import date, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import Connection, insert, inspect, select, text

from storage import schema
from storage.db import Archive
from storage.rawstore import hash_and_size
from storage.schema import AuditEvent, Seal, utcnow

ACTOR_ENV = "CALIB_USER"
GENESIS = "0" * 64  # prev_hash of the first event
# Actions whose event carries the digest of the record they sealed.
SEALING = ("archived", "revised", "sealed")
_CHUNK = 500  # calibrations per round of record queries
# Any constant: held while appending to the chain, so PostgreSQL writers take turns.
_PG_CHAIN_LOCK = 0x63616C6963  # "calic"
MAX_REASON = 2000  # characters of a reason


def actor() -> str:
    """Who is writing: env ``CALIB_USER`` (the configured identity), else the OS user."""
    name = os.environ.get(ACTOR_ENV, "").strip()
    if not name:
        try:
            name = getpass.getuser()
        except (KeyError, OSError):  # no passwd entry (a container), no LOGNAME
            name = f"uid {os.getuid()}"
    if len(name) > 200 or any(ord(c) < 32 for c in name):
        raise ValueError(f"{ACTOR_ENV}: at most 200 characters and no control characters")
    return name


def check_reason(reason: str | None) -> None:
    """A reason is free text of at most MAX_REASON characters without NUL bytes (ValueError)."""
    if reason is not None and (not isinstance(reason, str) or len(reason) > MAX_REASON
                               or "\x00" in reason):  # fmt: skip
        raise ValueError(f"reason: expected text of at most {MAX_REASON} characters without "
                         f"NUL bytes, got {str(reason)[:40]!r}...")  # fmt: skip


def canonical(value: Any) -> bytes:
    """Canonical JSON (sorted keys, no spaces, ISO dates) as UTF-8: what is hashed.

    Records are trees read from the database, never cyclic: the encoder's cycle
    check (a quarter of its time on a record) is off.
    """
    return json.dumps(
        value, sort_keys=True, separators=(",", ":"), ensure_ascii=False, default=_iso,
        check_circular=False,
    ).encode()  # fmt: skip


def _iso(value: Any) -> str:
    if isinstance(value, date | datetime):
        return value.isoformat()
    raise TypeError(f"{type(value).__name__} is not part of a record")


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


# --- records ---------------------------------------------------------------------

_RUN = ("run_id", "started_at", "operator", "procedure", "site", "gravity", "environment",
        "manifest_text", "raw_hash", "tolerance_profile", "run_dir", "samples_path",
        "samples_sha256", "created_at")  # fmt: skip
_CAL = ("revision", "settings_hash", "settings", "software_version", "source_revision",
        "created_at", "document", "verdict", "profile_name", "profile_version")  # fmt: skip
_DEVICE = ("serial", "model", "manufacturer", "specification")
_DESCRIPTION = ("model", "manufacturer", "specification")  # of the unit, kept per run
_RAW = ("name", "sha256", "size", "format", "stored_path")
_STEP = ("seq", "name", "settings", "statistics", "software_version", "source_revision")
_PARAM = ("name", "value", "std", "unit", "temperature_c")
_CHECK = ("name", "value", "limit", "passed", "detail", "profile_name", "profile_version")


def _cols(model: type, names: tuple[str, ...], prefix: str = "") -> list:
    return [getattr(model, n).label(prefix + n) for n in names]


def records(
    conn: Connection,
    cal_ids: list[int],
    files: dict[int, dict[str, str]] | None = None,
    *,
    per_run_description: bool = True,
) -> dict[int, dict[str, Any]]:
    """The record of each calibration revision, as its rows are now.

    Parameters
    ----------
    conn : an open connection (inside the archiving transaction, or verify's).
    cal_ids : calibration ids (a few hundred at a time: they go into IN lists).
    files : calibration id -> {path relative to the file store: sha256} of the files
        the revision wrote; missing ids get ``{}``.
    per_run_description : False only for a schema before migration 0006, whose runs
        have no description of their own (`seal_unsealed` decides).

    Returns
    -------
    calibration id -> record: one key per table (``runs``, ``devices``,
    ``run_equipment``, ``raw_files``, ``calibrations``, ``processing_steps``,
    ``parameters``, ``check_results``) plus ``files``. Rows of a table are keyed
    by a label (parameter name, step ``seq:name``...) so a difference names the row.

    ``devices`` is the unit's row (serial and registered description); the run's
    own description (``runs.model``, ``manufacturer``, ``specification``, migration
    0006) is in ``runs`` field by field where it differs from the registered one.
    So both are sealed, and a record sealed when they agreed (every record sealed
    before 0006, which copied the device row's description into the runs) keeps its
    digest; a run's field changed to differ shows as sealed "(absent)".
    """
    head = conn.execute(
        select(
            schema.CalibrationRow.id.label("cal_pk"),
            schema.Run.id.label("run_pk"),
            *_cols(schema.Run, _RUN, "r_"),
            *_cols(schema.CalibrationRow, _CAL, "c_"),
            *_cols(schema.Device, _DEVICE, "d_"),
            *(_cols(schema.Run, _DESCRIPTION, "u_") if per_run_description else ()),
        )  # fmt: skip
        .join(schema.Run, schema.Run.id == schema.CalibrationRow.run_id)
        .join(schema.Device, schema.Device.id == schema.Run.device_id)
        .where(schema.CalibrationRow.id.in_(cal_ids))
    ).mappings()
    out: dict[int, dict[str, Any]] = {}
    run_of: dict[int, int] = {}
    for m in head:
        run_of[m["cal_pk"]] = m["run_pk"]
        out[m["cal_pk"]] = {
            "runs": {n: m["r_" + n] for n in _RUN} | _own_description(m, per_run_description),
            "calibrations": {n: m["c_" + n] for n in _CAL},
            "devices": {n: m["d_" + n] for n in _DEVICE},
            "files": dict(sorted((files or {}).get(m["cal_pk"], {}).items())),
        }
    by_run = _run_children(conn, sorted(set(run_of.values())))
    by_cal = _calibration_children(conn, list(out))
    for cal_pk, rec in out.items():
        rec.update(by_run[run_of[cal_pk]])
        rec.update(by_cal[cal_pk])
    return out


def _own_description(m: Any, per_run: bool) -> dict[str, Any]:
    """The fields of the run's own description that differ from its device row's."""
    if not per_run:
        return {}
    return {n: m["u_" + n] for n in _DESCRIPTION if m["u_" + n] != m["d_" + n]}


def _labelled(rows: list[tuple[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """Rows keyed by label; a repeated label gets ``#2``, ``#3``... in row order."""
    out: dict[str, dict[str, Any]] = {}
    for label, row in rows:
        key, n = label, 1
        while key in out:
            n += 1
            key = f"{label}#{n}"
        out[key] = row
    return out


def _run_children(conn: Connection, run_pks: list[int]) -> dict[int, dict[str, Any]]:
    eq_rows: dict[int, list] = defaultdict(list)
    for m in conn.execute(
        select(
            schema.RunEquipment.run_id,
            schema.Equipment.kind,
            schema.Equipment.serial,
            schema.Equipment.model,
            schema.Equipment.accuracy_class,
            schema.RunEquipment.calibration_due,
            schema.RunEquipment.calibrated_on,
        )  # fmt: skip
        .join(schema.Equipment, schema.Equipment.id == schema.RunEquipment.equipment_id)
        .where(schema.RunEquipment.run_id.in_(run_pks))
        .order_by(schema.RunEquipment.run_id, schema.Equipment.kind, schema.Equipment.serial)
    ).mappings():
        row = {k: v for k, v in m.items() if k != "run_id"}
        eq_rows[m["run_id"]].append((f"{m['kind']}:{m['serial']}", row))
    raw_rows: dict[int, list] = defaultdict(list)
    for m in conn.execute(
        select(schema.RawFileRow.run_id, *_cols(schema.RawFileRow, _RAW))
        .where(schema.RawFileRow.run_id.in_(run_pks))
        .order_by(schema.RawFileRow.run_id, schema.RawFileRow.name)
    ).mappings():
        raw_rows[m["run_id"]].append((m["name"], {n: m[n] for n in _RAW}))
    return {
        pk: {"run_equipment": _labelled(eq_rows[pk]), "raw_files": _labelled(raw_rows[pk])}
        for pk in run_pks
    }


def _calibration_children(conn: Connection, cal_pks: list[int]) -> dict[int, dict[str, Any]]:
    out: dict[int, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    tables = (
        ("processing_steps", schema.ProcessingStep, _STEP, schema.ProcessingStep.seq),
        ("parameters", schema.ParameterRow, _PARAM, schema.ParameterRow.name),
        ("check_results", schema.CheckResultRow, _CHECK, schema.CheckResultRow.name),
    )
    for table, model, names, order in tables:
        for cal_pk, *values in conn.execute(
            select(model.calibration_id, *_cols(model, names))
            .where(model.calibration_id.in_(cal_pks))
            .order_by(model.calibration_id, order, model.id)
        ):
            row = dict(zip(names, values, strict=True))
            label = f"{row['seq']}:{row['name']}" if table == "processing_steps" else row["name"]
            out[cal_pk][table].append((label, row))
    return {pk: {t: _labelled(out[pk][t]) for t, *_ in tables} for pk in cal_pks}


def digest_of(record: dict[str, Any]) -> str:
    return sha256_hex(canonical(record))


# --- the chain -------------------------------------------------------------------


@dataclass(frozen=True)
class Event:
    """One audit event as it is hashed (``hash`` excluded)."""

    seq: int
    at: datetime
    actor: str
    action: str
    run_id: str | None
    revision: int | None
    reason: str | None
    detail: dict[str, Any]
    digest: str | None
    prev_hash: str

    def hash(self) -> str:
        return sha256_hex(canonical({k: getattr(self, k) for k in _EVENT_FIELDS}))


_EVENT_FIELDS = ("seq", "at", "actor", "action", "run_id", "revision", "reason", "detail",
                 "digest", "prev_hash")  # fmt: skip


def head(conn: Connection) -> tuple[int, str]:
    """(seq, hash) of the newest event; (0, GENESIS) for an empty chain."""
    row = conn.execute(
        select(AuditEvent.seq, AuditEvent.hash).order_by(AuditEvent.seq.desc()).limit(1)
    ).one_or_none()
    return (0, GENESIS) if row is None else (row.seq, row.hash)


def append_event(
    conn: Connection,
    action: str,
    *,
    run_id: str | None = None,
    revision: int | None = None,
    reason: str | None = None,
    detail: dict[str, Any] | None = None,
    digest: str | None = None,
    who: str | None = None,
) -> Event:
    """Append one event to the chain, in the caller's transaction.

    On SQLite the caller's transaction holds the write lock already (BEGIN
    IMMEDIATE); on PostgreSQL an advisory lock held to the end of the transaction
    makes concurrent writers append one after the other.
    """
    check_reason(reason)
    if conn.dialect.name == "postgresql":
        conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": _PG_CHAIN_LOCK})
    seq, prev = head(conn)
    ev = Event(seq + 1, utcnow(), who or actor(), action, run_id, revision, reason,
               detail or {}, digest, prev)  # fmt: skip
    conn.execute(insert(AuditEvent).values(**{k: getattr(ev, k) for k in _EVENT_FIELDS},
                                           hash=ev.hash()))  # fmt: skip
    return ev


def record_event(archive: Archive, action: str, **fields: Any) -> Event:
    """Append one event in a transaction of its own (`append_event`'s keywords)."""
    with archive.engine().execution_options(sqlite_begin="IMMEDIATE").begin() as conn:
        return append_event(conn, action, **fields)


def seal_calibration(
    conn: Connection,
    cal_id: int,
    action: str,
    *,
    files: dict[str, str] | None = None,
    reason: str | None = None,
    who: str | None = None,
) -> str:
    """Seal one calibration revision (rows already written) and chain the event; its digest."""
    record = records(conn, [cal_id], {cal_id: files or {}})[cal_id]
    digest = _insert_seal(conn, cal_id, record)
    append_event(
        conn, action, run_id=record["runs"]["run_id"],
        revision=record["calibrations"]["revision"], reason=reason, digest=digest, who=who,
    )  # fmt: skip
    return digest


def _insert_seal(conn: Connection, cal_id: int, record: dict[str, Any]) -> str:
    """Store the record (as the JSON it hashes to) in ``seals``; return its digest."""
    data = canonical(record)
    conn.execute(insert(Seal).values(calibration_id=cal_id, digest=sha256_hex(data),
                                     record=json.loads(data), created_at=utcnow()))  # fmt: skip
    return sha256_hex(data)


def seal_unsealed(conn: Connection, who: str) -> int:
    """Seal every calibration without a seal, in id order (migration 0004, bulk loads).

    The files of those revisions are not known (they were not recorded): their
    records have no ``files``. Run by migration 0004, before 0006 gave runs their
    own description (0006 copies it from the device row).
    Returns the number sealed.
    """
    per_run = "model" in {c["name"] for c in inspect(conn).get_columns("runs")}
    sealed = select(Seal.calibration_id)
    ids = conn.execute(
        select(schema.CalibrationRow.id).where(schema.CalibrationRow.id.not_in(sealed)).order_by(schema.CalibrationRow.id)
    ).scalars().all()  # fmt: skip
    for chunk in _chunks(list(ids)):
        recs = records(conn, chunk, per_run_description=per_run)
        for cal_id in chunk:
            rec = recs[cal_id]
            digest = _insert_seal(conn, cal_id, rec)
            append_event(conn, "sealed", run_id=rec["runs"]["run_id"],
                         revision=rec["calibrations"]["revision"], digest=digest, who=who,
                         reason="sealed when the archive was upgraded")  # fmt: skip
    return len(ids)


def _chunks(ids: list[int], n: int = _CHUNK) -> Iterator[list[int]]:
    for i in range(0, len(ids), n):
        yield ids[i : i + n]


# --- checking --------------------------------------------------------------------


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
    for chunk in _chunks(list(seal_ids)):
        # The sealed record itself is read only where the rows no longer give its digest.
        seals = conn.execute(
            select(Seal.id, Seal.calibration_id, Seal.digest, Seal.record["files"].label("files"))
            .where(Seal.id.in_(chunk))
        ).all()  # fmt: skip
        files = {s.calibration_id: rehash_files(root, s.files or {}) for s in seals}
        now = records(conn, [s.calibration_id for s in seals], files)
        for s in seals:
            rec = now.get(s.calibration_id)
            if rec is not None:
                key = (rec["runs"]["run_id"], rec["calibrations"]["revision"])
                digests_now[key] = digest_of(rec)
                if digests_now[key] == s.digest == sealing.get(key):
                    del sealing[key]
                    continue
            sealed = conn.execute(select(Seal.record).where(Seal.id == s.id)).scalar_one()
            findings += _check_seal(s.digest, sealed, rec, sealing)
    for (run_id, rev), digest in sorted(sealing.items()):
        findings.append(Finding("chain", "seals", [run_id],
                                f"revision {rev} was sealed (digest {digest[:12]}...) but its seal "
                                "row is gone"))  # fmt: skip
    unsealed = conn.execute(
        select(schema.Run.run_id, schema.CalibrationRow.revision)
        .join(schema.Run, schema.Run.id == schema.CalibrationRow.run_id)
        .where(schema.CalibrationRow.id.not_in(select(Seal.calibration_id)))
    ).all()
    for run_id, rev in unsealed:
        findings.append(
            Finding(
                "chain",
                "calibrations",
                [run_id],
                f"revision {rev} has no seal: added behind the archive's back",
            )
        )
    return ChainCheck(findings, head(conn), len(seal_ids), digests_now)


def rehash_files(root: Path, files: dict[str, str]) -> dict[str, str]:
    """The SHA-256 of each file (paths relative to `root`) now; "(missing)" if gone."""
    out = {}
    for rel in files:
        p = (root / rel).resolve()
        ok = p.is_relative_to(root.resolve()) and p.is_file()
        out[rel] = hash_and_size(p)[0] if ok else "(missing)"
    return out


def _check_chain(conn: Connection) -> tuple[list[Finding], dict[tuple[str, int], str]]:
    """The chain's links; also (run_id, revision) -> digest of every sealing event."""
    findings: list[Finding] = []
    sealing: dict[tuple[str, int], str] = {}
    prev_seq, prev_hash = 0, GENESIS
    rows = conn.execution_options(yield_per=5000).execute(
        select(AuditEvent).order_by(AuditEvent.seq)
    )
    for row in rows:
        ev = Event(**{k: getattr(row, k) for k in _EVENT_FIELDS})
        where = f"event {ev.seq} ({ev.action}{' of ' + ev.run_id if ev.run_id else ''})"
        if ev.seq != prev_seq + 1:
            findings.append(Finding("chain", "audit_events", [ev.run_id] if ev.run_id else [],
                                    f"events {prev_seq + 1}..{ev.seq - 1} are missing before "
                                    f"{where}"))  # fmt: skip
        if ev.prev_hash != prev_hash:
            findings.append(
                Finding(
                    "chain",
                    "audit_events",
                    [ev.run_id] if ev.run_id else [],
                    f"{where} does not follow the event before it: "
                    f"expected previous hash {prev_hash}, found {ev.prev_hash}",
                )
            )
        if ev.hash() != row.hash:
            findings.append(Finding("chain", "audit_events", [ev.run_id] if ev.run_id else [],
                                    f"{where} was changed: its fields hash to {ev.hash()}, "
                                    f"stored hash {row.hash}"))  # fmt: skip
        if ev.action in SEALING and ev.run_id and ev.digest:
            sealing[(ev.run_id, ev.revision)] = ev.digest
        prev_seq, prev_hash = ev.seq, row.hash
    return findings, sealing


def _check_seal(
    digest: str,
    sealed: dict[str, Any],
    now: dict[str, Any] | None,
    sealing: dict[tuple[str, int], str],
) -> list[Finding]:
    run_id = sealed.get("runs", {}).get("run_id", "?")
    rev = sealed.get("calibrations", {}).get("revision")
    where = f"{run_id} revision {rev}"
    out: list[Finding] = []
    chained = sealing.pop((run_id, rev), None)
    if digest_of(sealed) != digest or chained != digest:
        out.append(Finding("chain", "seals", [run_id],
                           f"the seal of {where} was changed: it no longer matches the digest "
                           f"in the audit chain ({(chained or 'none')[:12]}...)"))  # fmt: skip
    if now is None:
        return [
            *out,
            Finding(
                "record",
                "calibrations",
                [run_id],
                f"{where} is sealed but its rows are gone (deleted)",
            ),
        ]
    if digest_of(now) == digest:
        return out
    for path, expected, found in differences(sealed, now):
        out.append(
            Finding(
                "record", path, [run_id], f"{where}: sealed {_show(expected)}, found {_show(found)}"
            )
        )
    return out


_ABSENT = object()


def differences(sealed: Any, now: Any, path: str = "") -> list[tuple[str, Any, Any]]:
    """(path, sealed value, value now) of every leaf that differs; absent is `_ABSENT`."""
    if isinstance(sealed, dict) and isinstance(now, dict):
        out = []
        for key in sorted(set(sealed) | set(now), key=str):
            sub = f"{path}/{key}" if path else str(key)
            out += differences(sealed.get(key, _ABSENT), now.get(key, _ABSENT), sub)
        return out
    if canonical_or_none(sealed) == canonical_or_none(now):
        return []
    return [(path, sealed, now)]


def canonical_or_none(value: Any) -> bytes | None:
    return None if value is _ABSENT else canonical(value)


def _show(value: Any) -> str:
    if value is _ABSENT:
        return "(absent)"
    text_ = canonical(value).decode()
    return text_ if len(text_) <= 120 else text_[:117] + "..."
