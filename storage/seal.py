"""Seals and the audit chain: what makes a change behind the archive's back visible.

Every calibration revision is *sealed* in the transaction that archives it: its
record (storage.seal_record) is read back from the rows just written and kept in
``seals`` so a later mismatch can be shown field by field; its digest goes into an
event of the audit chain.

The audit chain (``audit_events``) is append-only: every write to the archive
(run archived, revision, approval, repair, restore, thermal model, role change,
migration) is an event with who, when, what and why, numbered by ``seq`` and
hashed over its fields and the hash of the event before it. Changing, deleting or
reordering an event breaks the chain; changing a sealed row changes the record's
digest; deleting a run leaves a sealed event without its rows. storage.seal_check
reports each of these (storage.verify calls it). What a hash chain alone cannot show
is the removal of the *last* events: `head` gives the newest event's seq and hash,
to be written down elsewhere (the verify summary prints it) and compared later.
"""

from __future__ import annotations

import getpass
import json
import os
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, insert, select, text

from storage.db import Archive
from storage.schema import AuditEvent, Seal, utcnow
from storage.seal_record import (
    FORMAT,
    TEXTS,
    canonical,
    records,
    sha256_hex,
    without_texts,
)

ACTOR_ENV = "CALIB_USER"
GENESIS = "0" * 64  # prev_hash of the first event
# Actions whose event carries the digest of the record they sealed.
SEALING = ("archived", "revised", "sealed")
# The event of an issued certificate (pipelines.reports.issue): its detail's "files" maps
# each file (path relative to the root) to its SHA-256, rehashed by storage.seal_check.
ISSUED = "certificate issued"
# Any constant: held while appending to the chain, so PostgreSQL writers take turns.
PG_CHAIN_LOCK = 0x63616C6963  # "calic"
MAX_REASON = 2000  # characters of a reason


def os_user() -> str:
    """The OS user this process runs as."""
    try:
        return getpass.getuser()
    except (KeyError, OSError):  # no passwd entry (a container), no LOGNAME
        return f"uid {os.getuid()}"


def actor() -> str:
    """Who is writing: env ``CALIB_USER`` (the configured identity), else the OS user."""
    name = os.environ.get(ACTOR_ENV, "").strip() or os_user()
    if len(name) > 200 or any(ord(c) < 32 for c in name):
        raise ValueError(f"{ACTOR_ENV}: at most 200 characters and no control characters")
    return name


def db_user(conn: Connection) -> str:
    """Who writes as the database knows it: PostgreSQL's ``session_user`` (the role that
    logged in; asked once per connection), on SQLite (a file has no users of its own) the
    OS account of the process's user id, not the environment's LOGNAME or USER."""
    if conn.dialect.name != "postgresql":
        return process_user()[:200]
    info = conn.connection.info  # the driver connection's: its session user never changes
    if SESSION_USER_KEY not in info:
        info[SESSION_USER_KEY] = str(conn.execute(_SESSION_USER).scalar())
    return info[SESSION_USER_KEY]


def process_user() -> str:
    """The account name of this process's effective user id ("uid N" without one)."""
    try:
        import pwd

        return pwd.getpwuid(os.geteuid()).pw_name
    except (ImportError, AttributeError, KeyError):  # Windows (no pwd, no geteuid), no passwd entry
        return os_user()


def check_reason(reason: str | None) -> None:
    """A reason is free text of at most MAX_REASON characters without NUL bytes (ValueError)."""
    if reason is not None and (
        not isinstance(reason, str) or len(reason) > MAX_REASON or "\x00" in reason
    ):
        raise ValueError(
            f"reason: expected text of at most {MAX_REASON} characters without "
            f"NUL bytes, got {str(reason)[:40]!r}..."
        )


@dataclass(frozen=True)
class Event:
    """One audit event as it is hashed (``hash`` excluded). ``db_user`` (`db_user`) is
    hashed when there is one: events written before migration 0009 have none."""

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
    db_user: str | None = None

    def hash(self) -> str:
        fields = {k: getattr(self, k) for k in EVENT_FIELDS}
        if fields["db_user"] is None:
            del fields["db_user"]
        return sha256_hex(canonical(fields))


EVENT_FIELDS = (
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
    "db_user",
)
_SESSION_USER = text("SELECT session_user")
SESSION_USER_KEY = "calib_session_user"
# Built once (as the record queries of storage.seal_record).
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
        conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": PG_CHAIN_LOCK})
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
        db_user(conn),
    )
    row = {**{k: getattr(ev, k) for k in EVENT_FIELDS}, "hash": ev.hash()}
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
# The function's signature (storage.roles makes it; its grants name it).
APPEND_EVENT = (
    "calib_append_event(timestamptz, text, text, text, integer, text, json, text, "
    "text, text, integer, text)"
)
_APPEND_EVENT = text(
    "SELECT calib_append_event(:at, :actor, :action, :run_id, :revision, :reason, "
    "CAST(:detail AS json), :digest, :prev_hash, :hash, :seq, :db_user)"
)
_HAS_FUNCTION = text("SELECT to_regprocedure(:f) IS NOT NULL")


def _has_append_function(conn: Connection) -> bool:
    """Whether the database has it (made by storage.roles.apply_roles)."""
    return bool(conn.execute(_HAS_FUNCTION, {"f": APPEND_EVENT}).scalar())


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
    digest = insert_seal(conn, cal_id, record)
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


def insert_seal(conn: Connection, cal_id: int, record: dict[str, Any]) -> str:
    """Store the record (as the JSON it hashes to; format 2's texts in ``seals.texts``) in
    ``seals``; return its digest."""
    data = canonical(without_texts(record))
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
