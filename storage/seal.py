"""Seals and the audit chain: what makes a change behind the archive's back visible.

Every calibration revision is *sealed* in the transaction that archives it: its
*record* is read back from the rows just written (run with the unit as it
describes it, device, equipment links, raw files, calibration with its document,
steps, parameters, checks) together with the SHA-256 of every file the revision
wrote (protocol...), serialised as canonical JSON, and hashed (the *digest*). The
record is kept in ``seals`` so a later mismatch can be shown field by field; the
digest goes into an event of the audit chain.

Record formats. Format 1 (the records of before, no ``format`` key) holds every
value as decoded from its row. Format 2 (``"format": 2``, written since) holds a
JSON column (the calibration document and settings, a step's settings and
statistics, a run's site and environment) as the SHA-256 of the text the database
stores (``"sha256:<hex>"``), and the seal keeps that text beside the record
(``seals.texts``, outside the digest) to show a change field by field. So verify
neither decodes nor re-encodes the large JSON values, which would cost more than
the rest of the verify. A migration that
rewrote a JSON column's text, even to equal JSON, would break format 2 seals:
that text is what they hold. Both formats verify; `records` builds either.

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
from functools import cache
from pathlib import Path
from typing import Any

from sqlalchemy import (
    JSON,
    Connection,
    Select,
    Text,
    bindparam,
    cast,
    insert,
    inspect,
    select,
    text,
)

from storage import schema
from storage.db import Archive
from storage.schema import AuditEvent, Seal, utcnow

ACTOR_ENV = "CALIB_USER"
GENESIS = "0" * 64  # prev_hash of the first event
# Actions whose event carries the digest of the record they sealed.
SEALING = ("archived", "revised", "sealed")
# The event of an issued certificate (pipelines.reports.issue): its detail's "files" maps
# each file (path relative to the root) to its SHA-256, rehashed by `check`.
ISSUED = "certificate issued"
_CHUNK = 500  # calibrations per round of record queries
# Any constant: held while appending to the chain, so PostgreSQL writers take turns.
_PG_CHAIN_LOCK = 0x63616C6963  # "calic"
MAX_REASON = 2000  # characters of a reason
FORMAT = 2  # record format of new seals (module docstring); 1: before it had a number
FORMATS = (1, 2)  # the record formats this version reads
TEXTS = "texts"  # a record's JSON texts (format 2): outside the digest, in seals.texts


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
    if reason is not None and (
        not isinstance(reason, str) or len(reason) > MAX_REASON or "\x00" in reason
    ):
        raise ValueError(
            f"reason: expected text of at most {MAX_REASON} characters without "
            f"NUL bytes, got {str(reason)[:40]!r}..."
        )


def canonical(value: Any) -> bytes:
    """Canonical JSON (sorted keys, no spaces, ISO dates) as UTF-8: what is hashed.

    Records are trees read from the database, never cyclic: the encoder's cycle
    check (a quarter of its time on a record) is off.
    """
    return json.dumps(
        value,
        sort_keys=True,
        separators=(",", ":"),
        ensure_ascii=False,
        default=_iso,
        check_circular=False,
    ).encode()


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
_CAL = (
    "revision",
    "settings_hash",
    "settings",
    "software_version",
    "source_revision",
    "created_at",
    "document",
    "verdict",
    "profile_name",
    "profile_version",
)
_DEVICE = ("serial", "model", "manufacturer", "specification")
_DESCRIPTION = ("model", "manufacturer", "specification")  # of the unit, kept per run
_RAW = ("name", "sha256", "size", "format", "stored_path")
_STEP = ("seq", "name", "settings", "statistics", "software_version", "source_revision")
_PARAM = ("name", "value", "std", "unit", "temperature_c")
_CHECK = ("name", "value", "limit", "passed", "detail", "profile_name", "profile_version")


class _Stored(str):
    """The text a JSON column holds, read so at format 2 (`_hash_stored` replaces it)."""


def _cols(model: type, names: tuple[str, ...], prefix: str = "", form: int = 1) -> list:
    """Columns `names` of `model` labelled ``prefix + name``; from format 2 on, a JSON
    column is read as the text it is stored as."""
    stored = _stored_names(model, names, form)
    return [_as_read(getattr(model, n), n in stored).label(prefix + n) for n in names]


def _as_read(col: Any, stored: bool) -> Any:
    return cast(col, Text) if stored else col


@cache
def _stored_names(model: type, names: tuple[str, ...], form: int) -> frozenset[str]:
    """The JSON columns among `names`: read as stored text from format 2 on."""
    if form < 2:
        return frozenset()
    return frozenset(n for n in names if isinstance(getattr(model, n).type, JSON))


def _fields(m: Any, names: tuple[str, ...], prefix: str, stored: frozenset[str]) -> dict:
    """{name: value} of one result row; a stored JSON text is marked `_Stored`."""
    return {n: _leaf(m[prefix + n], n in stored) for n in names}


def _leaf(value: Any, stored: bool) -> Any:
    return _Stored(value) if stored and value is not None else value


def records(
    conn: Connection,
    cal_ids: list[int],
    files: dict[int, dict[str, str]] | None = None,
    *,
    per_run_description: bool = True,
    form: int = FORMAT,
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
    form : record format (module docstring): 1 every value decoded, 2 JSON columns
        as the SHA-256 of their stored text, which goes under ``texts``.

    Returns
    -------
    calibration id -> record: one key per table (``runs``, ``devices``,
    ``run_equipment``, ``raw_files``, ``calibrations``, ``processing_steps``,
    ``parameters``, ``check_results``) plus ``files`` (and, format 2, ``format``
    and ``texts``: the stored texts, nested as the record). Rows of a table are keyed
    by a label (parameter name, step ``seq:name``...) so a difference names the row.

    ``devices`` is the unit's row (serial and registered description); the run's
    own description (``runs.model``, ``manufacturer``, ``specification``, migration
    0006) is in ``runs`` field by field where it differs from the registered one.
    So both are sealed, and a record sealed when they agreed (every record sealed
    before 0006, which copied the device row's description into the runs) keeps its
    digest; a run's field changed to differ shows as sealed "(absent)".
    """
    head = conn.execute(_head_query(form, per_run_description), {"ids": cal_ids}).mappings()
    run_stored = _stored_names(schema.Run, _RUN, form)
    cal_stored = _stored_names(schema.CalibrationRow, _CAL, form)
    out: dict[int, dict[str, Any]] = {}
    run_of: dict[int, int] = {}
    for m in head:
        run_of[m["cal_pk"]] = m["run_pk"]
        out[m["cal_pk"]] = {
            "runs": _fields(m, _RUN, "r_", run_stored) | _own_description(m, per_run_description),
            "calibrations": _fields(m, _CAL, "c_", cal_stored),
            "devices": {n: m["d_" + n] for n in _DEVICE},
            "files": dict(sorted((files or {}).get(m["cal_pk"], {}).items())),
        }
    by_run = _run_children(conn, sorted(set(run_of.values())))
    by_cal = _calibration_children(conn, list(out), form)
    for cal_pk, rec in out.items():
        rec.update(by_run[run_of[cal_pk]])
        rec.update(by_cal[cal_pk])
        if form >= 2:
            rec["format"] = form
            rec[TEXTS] = _hash_stored(rec)
    return out


# The queries of `records` are built once per process (they depend on the schema and the
# format only; their IN lists are expanding parameters ``ids``). Building them, the chain
# head and the two inserts for every revision was about half of the cost of sealing one.
_IDS = bindparam("ids", expanding=True)


@cache
def _head_query(form: int, per_run_description: bool) -> Select:
    """Each revision's run, calibration and device fields, for calibration ids ``ids``."""
    return (
        select(
            schema.CalibrationRow.id.label("cal_pk"),
            schema.Run.id.label("run_pk"),
            *_cols(schema.Run, _RUN, "r_", form),
            *_cols(schema.CalibrationRow, _CAL, "c_", form),
            *_cols(schema.Device, _DEVICE, "d_"),
            *(_cols(schema.Run, _DESCRIPTION, "u_") if per_run_description else ()),
        )
        .join(schema.Run, schema.Run.id == schema.CalibrationRow.run_id)
        .join(schema.Device, schema.Device.id == schema.Run.device_id)
        .where(schema.CalibrationRow.id.in_(_IDS))
    )


def _hash_stored(record: dict[str, Any]) -> dict[str, Any]:
    """Replace every stored JSON text of `record` by ``"sha256:<hex>"``, in place; return
    the texts, nested as the record is (``{table: {field: text}}`` or
    ``{table: {row: {field: text}}}``)."""
    texts: dict[str, Any] = {}
    for table in _JSON_TABLES:
        rows = record[table]
        found: dict[str, Any] = _hash_fields(rows)  # runs, calibrations: their fields
        for label, row in rows.items():
            if isinstance(row, dict) and (in_row := _hash_fields(row)):  # a child table's row
                found[label] = in_row
        if found:
            texts[table] = found
    return texts


def _hash_fields(fields: dict[str, Any]) -> dict[str, str]:
    """Hash the stored texts among `fields` in place; return them by field name."""
    texts = {}
    for name, leaf in fields.items():
        if isinstance(leaf, _Stored):
            texts[name] = str(leaf)
            fields[name] = text_digest(leaf)
    return texts


# The record's tables that have JSON columns: where `_hash_stored` looks.
_JSON_TABLES = tuple(
    table
    for table, model, names in (
        ("runs", schema.Run, _RUN),
        ("calibrations", schema.CalibrationRow, _CAL),
        ("processing_steps", schema.ProcessingStep, _STEP),
        ("parameters", schema.ParameterRow, _PARAM),
        ("check_results", schema.CheckResultRow, _CHECK),
    )
    if _stored_names(model, names, 2)
)


def text_digest(stored: str) -> str:
    """What a format 2 record holds for a JSON column's stored text."""
    return "sha256:" + sha256_hex(stored.encode())


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
    equipment_query, raw_query = _run_children_queries()
    for m in conn.execute(equipment_query, {"ids": run_pks}).mappings():
        row = {k: v for k, v in m.items() if k != "run_id"}
        eq_rows[m["run_id"]].append((f"{m['kind']}:{m['serial']}", row))
    raw_rows: dict[int, list] = defaultdict(list)
    for m in conn.execute(raw_query, {"ids": run_pks}).mappings():
        raw_rows[m["run_id"]].append((m["name"], {n: m[n] for n in _RAW}))
    return {
        pk: {"run_equipment": _labelled(eq_rows[pk]), "raw_files": _labelled(raw_rows[pk])}
        for pk in run_pks
    }


def _calibration_children(
    conn: Connection, cal_pks: list[int], form: int
) -> dict[int, dict[str, Any]]:
    out: dict[int, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for table, names, stored, query in _calibration_children_queries(form):
        # verify builds every row of the archive here: the row's dict made at once and
        # only its JSON columns marked spares a function call per value
        marked = [n for n in names if n in stored]
        for cal_pk, *values in conn.execute(query, {"ids": cal_pks}):
            row = dict(zip(names, values, strict=True))
            for n in marked:
                row[n] = _leaf(row[n], True)
            label = f"{row['seq']}:{row['name']}" if table == "processing_steps" else row["name"]
            out[cal_pk][table].append((label, row))
    return {pk: {t: _labelled(out[pk][t]) for t, *_ in _CHILD_TABLES} for pk in cal_pks}


# A revision's child tables: (record key, model, sealed columns, order within a revision).
_CHILD_TABLES = (
    ("processing_steps", schema.ProcessingStep, _STEP, schema.ProcessingStep.seq),
    ("parameters", schema.ParameterRow, _PARAM, schema.ParameterRow.name),
    ("check_results", schema.CheckResultRow, _CHECK, schema.CheckResultRow.name),
)


@cache
def _calibration_children_queries(form: int) -> list[tuple[str, tuple, frozenset, Select]]:
    """(record key, columns, stored JSON columns, query) of each child table of a revision."""
    return [
        (
            table,
            names,
            _stored_names(model, names, form),
            select(model.calibration_id, *_cols(model, names, form=form))
            .where(model.calibration_id.in_(_IDS))
            .order_by(model.calibration_id, order, model.id),
        )
        for table, model, names, order in _CHILD_TABLES
    ]


@cache
def _run_children_queries() -> tuple[Select, Select]:
    """The queries of a run's equipment and raw files, for run ids ``ids``."""
    equipment = (
        select(
            schema.RunEquipment.run_id,
            schema.Equipment.kind,
            schema.Equipment.serial,
            schema.Equipment.model,
            schema.Equipment.accuracy_class,
            schema.RunEquipment.calibration_due,
            schema.RunEquipment.calibrated_on,
        )
        .join(schema.Equipment, schema.Equipment.id == schema.RunEquipment.equipment_id)
        .where(schema.RunEquipment.run_id.in_(_IDS))
        .order_by(schema.RunEquipment.run_id, schema.Equipment.kind, schema.Equipment.serial)
    )
    raw = (
        select(schema.RawFileRow.run_id, *_cols(schema.RawFileRow, _RAW))
        .where(schema.RawFileRow.run_id.in_(_IDS))
        .order_by(schema.RawFileRow.run_id, schema.RawFileRow.name)
    )
    return equipment, raw


def digest_of(record: dict[str, Any]) -> str:
    """SHA-256 of the record's canonical JSON, its stored texts (format 2) left out."""
    return sha256_hex(canonical(_without_texts(record)))


def record_format(value: Any) -> int:
    """The format a sealed record's ``format`` value names (module docstring): 1 where it
    names none, 0 for a value no version of calib writes."""
    if value is None:
        return 1
    return value if type(value) is int and value >= 1 else 0


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


_EVENT_FIELDS = (
    "seq",
    "at",
    "actor",
    "action",
    "run_id",
    "revision",
    "reason",
    "detail",
    "digest",
    "prev_hash",
)
# Built once (see `_IDS`).
_HEAD = select(AuditEvent.seq, AuditEvent.hash).order_by(AuditEvent.seq.desc()).limit(1)
_INSERT_EVENT = insert(AuditEvent)
_INSERT_SEAL = insert(Seal)


def head(conn: Connection) -> tuple[int, str]:
    """(seq, hash) of the newest event; (0, GENESIS) for an empty chain."""
    row = conn.execute(_HEAD).one_or_none()
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
    pg = conn.dialect.name == "postgresql"
    if pg:
        conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": _PG_CHAIN_LOCK})
    seq, prev = head(conn)
    if PENDING_DETAIL and (more := _pending(conn)):
        detail = {**(detail or {}), **more}
    ev = Event(
        seq + 1,
        utcnow(),
        who or actor(),
        action,
        run_id,
        revision,
        reason,
        detail or {},
        digest,
        prev,
    )
    row = {**{k: getattr(ev, k) for k in _EVENT_FIELDS}, "hash": ev.hash()}
    if pg and _has_append_function(conn):
        conn.execute(_APPEND_EVENT, {**row, "detail": json.dumps(row["detail"])})
    else:
        conn.execute(_INSERT_EVENT, row)
    return ev


# Database URL -> what the next event appended there records besides its own detail: the
# file store of a PostgreSQL archive's first write (storage.store_identity).
PENDING_DETAIL: dict[str, dict[str, Any]] = {}


def _pending(conn: Connection) -> dict[str, Any] | None:
    return PENDING_DETAIL.pop(conn.engine.url.render_as_string(hide_password=False), None)


# PostgreSQL with roles (storage.roles.apply_roles): the writer and approver append only through
# this function, which checks the link to the head and the date (docs/archive.md).
_APPEND_EVENT = text(
    "SELECT calib_append_event(:at, :actor, :action, :run_id, :revision, :reason, "
    "CAST(:detail AS json), :digest, :prev_hash, :hash, :seq)"
)
_APPEND_FUNCTION = (
    "calib_append_event(timestamptz, text, text, text, integer, text, json, "
    "text, text, text, integer)"
)
_HAS_FUNCTION = text("SELECT to_regprocedure(:f) IS NOT NULL")


def _has_append_function(conn: Connection) -> bool:
    """Whether the database has it (made by storage.roles.apply_roles)."""
    return bool(conn.execute(_HAS_FUNCTION, {"f": _APPEND_FUNCTION}).scalar())


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
    record = records(conn, [cal_id], {cal_id: files or {}}, form=FORMAT)[cal_id]
    digest = _insert_seal(conn, cal_id, record)
    append_event(
        conn,
        action,
        run_id=record["runs"]["run_id"],
        revision=record["calibrations"]["revision"],
        reason=reason,
        digest=digest,
        who=who,
    )
    return digest


def _insert_seal(conn: Connection, cal_id: int, record: dict[str, Any]) -> str:
    """Store the record (as the JSON it hashes to; format 2's texts in ``seals.texts``) in
    ``seals``; return its digest."""
    data = canonical(_without_texts(record))
    digest = sha256_hex(data)
    row = {
        "calibration_id": cal_id,
        "digest": digest,
        "record": json.loads(data),
        "created_at": utcnow(),
    }
    if TEXTS in record:  # format 2 (a schema before 0008 has no such column: format 1 there)
        row["texts"] = record[TEXTS]
    conn.execute(_INSERT_SEAL, row)
    return digest


def seal_unsealed(conn: Connection, who: str) -> int:
    """Seal every calibration without a seal, in id order (migration 0004, bulk loads).

    The files of those revisions are not known (they were not recorded): their
    records have no ``files``. Run by migration 0004, before 0006 gave runs their
    own description (0006 copies it from the device row) and before 0008 gave
    seals their ``texts``: such seals are in record format 1.
    Returns the number sealed.
    """
    per_run = "model" in {c["name"] for c in inspect(conn).get_columns("runs")}
    form = FORMAT if "texts" in {c["name"] for c in inspect(conn).get_columns("seals")} else 1
    sealed = select(Seal.calibration_id)
    ids = (
        conn.execute(
            select(schema.CalibrationRow.id)
            .where(schema.CalibrationRow.id.not_in(sealed))
            .order_by(schema.CalibrationRow.id)
        )
        .scalars()
        .all()
    )
    for chunk in _chunks(list(ids)):
        recs = records(conn, chunk, per_run_description=per_run, form=form)
        for cal_id in chunk:
            rec = recs[cal_id]
            digest = _insert_seal(conn, cal_id, rec)
            append_event(
                conn,
                "sealed",
                run_id=rec["runs"]["run_id"],
                revision=rec["calibrations"]["revision"],
                digest=digest,
                who=who,
                reason="sealed when the archive was upgraded",
            )
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
    for (run_id, rev), digest in sorted(sealing.items()):
        findings.append(
            Finding(
                "chain",
                "seals",
                [run_id],
                f"revision {rev} was sealed (digest {digest[:12]}...) but its seal row is gone",
            )
        )
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
    findings += _check_issued(conn, root)
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
            findings.append(
                Finding(
                    "chain",
                    "audit_events",
                    [ev.run_id] if ev.run_id else [],
                    f"events {prev_seq + 1}..{ev.seq - 1} are missing before {where}",
                )
            )
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
            findings.append(
                Finding(
                    "chain",
                    "audit_events",
                    [ev.run_id] if ev.run_id else [],
                    f"{where} was changed: its fields hash to {ev.hash()}, stored hash {row.hash}",
                )
            )
        if ev.action in SEALING and ev.run_id and ev.digest:
            sealing[(ev.run_id, ev.revision)] = ev.digest
        prev_seq, prev_hash = ev.seq, row.hash
    return findings, sealing


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
    if digest_of(sealed) != digest or chained != digest:
        out.append(
            Finding(
                "chain",
                "seals",
                [run_id],
                f"the seal of {where} was changed: it no longer matches the digest "
                f"in the audit chain ({(chained or 'none')[:12]}...)",
            )
        )
    if record_format(sealed.get("format")) not in FORMATS:
        return [
            *out,
            Finding(
                "chain",
                "seals",
                [run_id],
                f"the seal of {where} is in record format {sealed.get('format')!r}, "
                f"which this version of calib (formats {FORMATS}) cannot read: "
                "verify with the version that wrote it",
            ),
        ]
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
    for keys, expected, found in _record_differences(sealed, now):
        out.append(
            Finding(
                "record",
                "/".join(keys),
                [run_id],
                f"{where}: sealed {_show(expected)}, found {_show(found)}",
            )
        )
    return out


_ABSENT = object()


def _record_differences(sealed: dict[str, Any], now: dict[str, Any]) -> list[tuple]:
    """(keys, sealed value, value now) of every field that differs. A JSON column's
    change (format 2: its hash) is followed into the JSON where both texts are at hand."""
    out = []
    for keys, expected, found in differences(_without_texts(sealed), _without_texts(now)):
        out += _into_json(keys, expected, found, sealed.get(TEXTS), now.get(TEXTS))
    return out


def _without_texts(record: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in record.items() if k != TEXTS}


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
