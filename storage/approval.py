"""Approval of a calibration by an electronic signature (Ed25519, `cryptography`).

A named person reviews or approves one calibration revision by signing its seal:
the signed message is the canonical JSON of run id, revision, the record's digest
(storage.seal), the meaning ("reviewed" or "approved"), the signer's name and
public key. The approval is an event of the audit chain carrying the message's
fields and the signature, so `storage.verify` checks two things for each: the
signature verifies with the public key it names (the event was not forged or
edited), and the record's digest *now* is the one signed (a value changed after
the approval makes it fail).

Keys are per person, kept in a file: the private key as PKCS #8 PEM encrypted
with the person's passphrase (`generate_key`), the public key beside it as
``<file>.pub`` (name and 32-byte key in hex). The archive stores public keys
only; it proves that the holder of a key signed this exact record, and whose key
it is is the lab's to say: its *approvers file* (`Approvers`), kept outside the
archive in the manner of git's allowed-signers file, lists the public keys it
trusts, each with the signer's name and optionally the dates it is valid for and
a role. An approval made with a key the file does not hold for its date (a key
made by anyone with write access, under an approver's name) is *untrusted*:
`storage.verify` reports it and every display says so instead of "approved by".
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import date
from pathlib import Path
from typing import Any, Literal

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from sqlalchemy import Connection, select

from calib_core.settings import Setting, SettingError, Settings, checked, refusal
from storage import seal, seal_check, seal_record
from storage.current import CURRENT
from storage.db import Archive
from storage.naming import is_one_line
from storage.schema import AuditEvent, CalibrationRow, Run, Seal

Meaning = Literal["reviewed", "approved"]
MEANINGS = ("reviewed", "approved")
MIN_PASSPHRASE = 8  # characters


class ApprovalError(RuntimeError):
    """The approval was refused (reason in the message); nothing was written."""


@dataclass(frozen=True)
class Approval:
    """One approval event as `approvals` returns it."""

    seq: int
    run_id: str
    revision: int
    meaning: str
    signer: str
    public_key: str  # hex, 32 bytes
    at: str  # ISO 8601, UTC
    # Against the lab's approvers file: None not checked (no file), else why it is not
    # trusted ("" when it is).
    untrusted: str | None = None

    @property
    def trusted(self) -> bool | None:
        """True/False when checked against an approvers file, None when not checked."""
        return None if self.untrusted is None else not self.untrusted


def public_key_hex(key: Ed25519PublicKey) -> str:
    return key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw).hex()


def fingerprint(public_hex: str) -> str:
    """The key's fingerprint in OpenSSH's form, ``SHA256:`` and unpadded base64, of the
    SHA-256 of the raw 32-byte public key (OpenSSH hashes its own key encoding instead,
    so the two differ for the same key)."""
    try:
        raw = bytes.fromhex(public_hex)
    except (TypeError, ValueError):
        raw = str(public_hex).encode()
    return "SHA256:" + base64.b64encode(hashlib.sha256(raw).digest()).decode().rstrip("=")


def generate_key(path: Path, name: str, passphrase: str) -> str:
    """Write a new private key to `path` (encrypted) and ``<path>.pub``; return the public key hex.

    Refuses to overwrite an existing file and a passphrase shorter than 8 characters.
    """
    path = Path(path)
    if len(passphrase) < MIN_PASSPHRASE:
        raise ValueError(f"passphrase: at least {MIN_PASSPHRASE} characters")
    _check_name(name)
    pub_path = path.with_name(path.name + ".pub")
    for p in (path, pub_path):
        if p.exists():
            raise FileExistsError(f"{p}: exists already; a key is never overwritten")
    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.BestAvailableEncryption(passphrase.encode()),
    )
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    public = public_key_hex(key.public_key())
    pub_path.write_text(json.dumps({"name": name, "public_key": public}) + "\n")
    return public


def load_key(path: Path, passphrase: str) -> Ed25519PrivateKey:
    """The private key of `path`; ApprovalError naming the file if it cannot be read."""
    try:
        key = serialization.load_pem_private_key(Path(path).read_bytes(), passphrase.encode())
    except FileNotFoundError:
        raise ApprovalError(f"{path}: no such key file") from None
    except (ValueError, TypeError) as exc:
        raise ApprovalError(f"{path}: cannot read the key (wrong passphrase?): {exc}") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise ApprovalError(f"{path}: expected an Ed25519 key, found {type(key).__name__}")
    return key


def _check_name(name: str) -> None:
    if not is_one_line(name):
        raise ValueError(f"signer name: 1..200 characters without control characters, got {name!r}")


def message(
    run_id: str, revision: int, digest: str, meaning: str, signer: str, public: str
) -> bytes:
    """The bytes that are signed."""
    return seal_record.canonical(
        {
            "run_id": run_id,
            "revision": revision,
            "digest": digest,
            "meaning": meaning,
            "signer": signer,
            "public_key": public,
        }
    )


def approve(
    archive: Archive,
    run_id: str,
    key: Ed25519PrivateKey,
    *,
    signer: str,
    meaning: Meaning = "approved",
    revision: int | None = None,
    approvers: Approvers | None = None,
) -> seal.Event:
    """Sign the seal of `run_id`'s current (or given) revision and chain the approval event.

    Refused (ApprovalError) when the run or revision is unknown, has no seal, or its
    rows no longer match the seal: a changed record is never signed; and, with the lab's
    `approvers`, when the file does not hold the key for this signer, today and meaning
    (the message names the file).
    """
    if meaning not in MEANINGS:
        raise ValueError(f"meaning: expected one of {MEANINGS}, got {meaning!r}")
    _check_name(signer)
    if approvers is not None:
        today = seal.utcnow().date().isoformat()
        mine = Approval(0, run_id, 0, meaning, signer, public_key_hex(key.public_key()), today)
        if why := approvers.judge(mine):
            raise ApprovalError(f"{signer} may not sign ({meaning}): {why}; not signed")
    engine = archive.engine().execution_options(sqlite_begin="IMMEDIATE")
    with engine.begin() as conn:
        cal_id, rev, digest, sealed = _sealed_revision(conn, run_id, revision)
        files_now = seal_check.rehash_files(archive.root, sealed.get("files", {}))
        if seal_check.digest_now(conn, cal_id, files_now, sealed.get("format")) != digest:
            raise ApprovalError(
                f"run {run_id} revision {rev}: its rows no longer match its seal; "
                "run `calib verify` to see what changed; not signed"
            )
        public = public_key_hex(key.public_key())
        signature = key.sign(message(run_id, rev, digest, meaning, signer, public)).hex()
        detail = {
            "meaning": meaning,
            "signer": signer,
            "public_key": public,
            "signature": signature,
        }
        return seal.append_event(
            conn, "approved", run_id=run_id, revision=rev, detail=detail, digest=digest
        )


def _sealed_revision(
    conn: Connection, run_id: str, revision: int | None
) -> tuple[int, int, str, dict[str, Any]]:
    """(calibration id, revision, sealed digest, sealed record) of a run's revision."""
    q = (
        select(CalibrationRow.id, CalibrationRow.revision, Seal.digest, Seal.record)
        .join(Run, Run.id == CalibrationRow.run_id)
        .outerjoin(Seal, Seal.calibration_id == CalibrationRow.id)
        .where(Run.run_id == run_id)
    )
    q = q.where(CURRENT if revision is None else CalibrationRow.revision == revision)
    row = conn.execute(q).one_or_none()
    if row is None:
        which = "current revision" if revision is None else f"revision {revision}"
        raise ApprovalError(f"run {run_id}: no {which} in the archive")
    if row.digest is None:
        raise ApprovalError(f"run {run_id} revision {row.revision} has no seal; not signed")
    return row.id, row.revision, row.digest, row.record


def signature_error(doc: dict[str, Any], signed: Callable[[], bytes]) -> str | None:
    """Why the Ed25519 signature of `doc` (hex ``public_key`` and ``signature``) over the
    bytes `signed()` does not verify, by the name of what failed (a field missing or
    malformed, InvalidSignature); None: it verifies. Approvals and signed checkpoints."""
    try:
        public = Ed25519PublicKey.from_public_bytes(bytes.fromhex(doc["public_key"]))
        public.verify(bytes.fromhex(doc["signature"]), signed())
    except (InvalidSignature, KeyError, ValueError, TypeError) as exc:
        return type(exc).__name__
    return None


def _signature_error(ev: Any) -> str | None:
    """Why the signature of approval event `ev` does not verify (None: it does)."""
    d = ev.detail or {}
    return signature_error(
        d,
        lambda: message(
            ev.run_id, ev.revision, ev.digest, d["meaning"], d["signer"], d["public_key"]
        ),
    )


def check(conn: Connection, digests_now: dict[tuple[str, int], str]) -> list[seal_check.Finding]:
    """Every approval's signature, and whether the record it signed is unchanged."""
    found: list[seal_check.Finding] = []
    for ev in conn.execute(select(AuditEvent).where(AuditEvent.action == "approved")):
        d = ev.detail or {}
        who = f"{d.get('meaning', '?')} by {d.get('signer', '?')} (event {ev.seq})"
        where = f"{ev.run_id} revision {ev.revision}"
        error = _signature_error(ev)
        now = digests_now.get((ev.run_id, ev.revision))
        if error is not None:
            problem = f"the signature of the approval {who} does not verify ({error}): the event "
            problem += "was altered"
        elif now != ev.digest:
            problem = f"the approval {who} no longer holds: the record was signed with digest "
            problem += f"{ev.digest}, its rows now give {now or '(rows gone)'}"
        else:
            continue
        found.append(
            seal_check.Finding("signature", "audit_events", [ev.run_id], f"{where}: {problem}")
        )
    return found


def approval_status(
    archive: Archive, run_id: str, revision: int, approvers: Approvers | None = None
) -> list[tuple[Approval, bool]]:
    """The approvals of one revision, each with whether it holds now: its signature
    verifies and the revision's rows and files still give the digest it signed.
    A revision without a seal has no approval that holds. With `approvers`, each
    approval is marked trusted or not (`Approval.untrusted`); an untrusted one does
    not hold."""
    with archive.engine().connect() as conn:
        try:
            cal_id, _, _, sealed = _sealed_revision(conn, run_id, revision)
        except ApprovalError:
            return []
        events = conn.execute(
            select(AuditEvent)
            .where(
                AuditEvent.action == "approved",
                AuditEvent.run_id == run_id,
                AuditEvent.revision == revision,
            )
            .order_by(AuditEvent.seq)
        ).all()
        if not events:  # nothing to judge: the files are not read again
            return []
        files_now = seal_check.rehash_files(archive.root, sealed.get("files", {}))
        now = seal_check.digest_now(conn, cal_id, files_now, sealed.get("format"))
    out = []
    for ev in events:
        a = _approval(ev) if approvers is None else approvers.mark(_approval(ev))
        out.append((a, _signature_error(ev) is None and ev.digest == now and not a.untrusted))
    return out


def _approval(ev: Any) -> Approval:
    d = ev.detail or {}
    return Approval(
        ev.seq,
        ev.run_id,
        ev.revision,
        d.get("meaning", ""),
        d.get("signer", ""),
        d.get("public_key", ""),
        ev.at.isoformat(),
    )


def approvals(archive: Archive, run_id: str, approvers: Approvers | None = None) -> list[Approval]:
    """The approvals of a run, oldest first (marked trusted or not with `approvers`)."""
    with archive.engine().connect() as conn:
        rows = conn.execute(
            select(AuditEvent)
            .where(AuditEvent.action == "approved", AuditEvent.run_id == run_id)
            .order_by(AuditEvent.seq)
        ).all()
    found = [_approval(ev) for ev in rows]
    return found if approvers is None else [approvers.mark(a) for a in found]


# --- the lab's approvers file ----------------------------------------------------

APPROVERS_ENV = "CALIB_APPROVERS"
ROLES = {"approver": MEANINGS, "reviewer": ("reviewed",)}  # role -> meanings it may sign
# One line of an approvers file (a JSON object): its keys as `load_approvers` reads them.
APPROVER = Settings(
    Setting("name", "text", "", None, "the signer's name, one line of 1..200 characters"),
    Setting("public_key", "text", "", None, "the Ed25519 public key: 64 hex digits"),
    Setting("valid_from", "text", "", None, "the first day it is valid (YYYY-MM-DD)"),
    Setting("valid_until", "text", "", None, "the last day it is valid (YYYY-MM-DD)"),
    Setting("role", "text", "", "approver", "what it may sign (ROLES)", choices=tuple(ROLES)),
    name="ApproverEntry",
    noun="field",
)
NOT_CHECKED = (
    "approvals were not checked against a list of trusted approvers (give one with "
    "--approvers FILE, [trust] approvers in lab.toml or CALIB_APPROVERS)"
)


@dataclass(frozen=True)
class TrustedKey:
    """One line of an approvers file."""

    name: str
    public_key: str  # hex, 32 bytes
    valid_from: date | None = None
    valid_until: date | None = None  # inclusive
    role: str = "approver"


@dataclass(frozen=True)
class Approvers:
    """The public keys a lab trusts (`load_approvers`), and the file they came from."""

    source: Path
    keys: tuple[TrustedKey, ...]

    def judge(self, a: Approval) -> str:
        """Why approval `a` is not trusted ("" when it is): its key is not in the file, is
        another person's, is not valid on the approval's date, or its role may not sign
        this meaning."""
        fp = fingerprint(a.public_key)
        held = [k for k in self.keys if k.public_key == a.public_key.lower()]
        if not held:
            return f"key {fp} is not in the approvers file {self.source}"
        named = [k for k in held if k.name == a.signer]
        if not named:
            return f"key {fp} belongs to {held[0].name!r} in {self.source}, not to {a.signer!r}"
        try:
            day = date.fromisoformat(a.at[:10])
        except ValueError:
            return f"its date {a.at!r} is not a date"
        valid = [
            k
            for k in named
            if (k.valid_from is None or k.valid_from <= day)
            and (k.valid_until is None or day <= k.valid_until)
        ]
        if not valid:
            spans = ", ".join(f"{k.valid_from or '...'} to {k.valid_until or '...'}" for k in named)
            return f"key {fp} of {a.signer} is valid {spans} in {self.source}, not on {day}"
        if not any(a.meaning in ROLES[k.role] for k in valid):
            return (
                f"key {fp} of {a.signer} has role {valid[0].role} in {self.source}, "
                f"which may not sign {a.meaning!r}"
            )
        return ""

    def mark(self, a: Approval) -> Approval:
        return replace(a, untrusted=self.judge(a))


def load_approvers(path: Path) -> Approvers:
    """Read an approvers file: one JSON object a line (`APPROVER`), as `generate_key`
    writes ``.pub`` files (``name``, ``public_key``), optionally with ``valid_from`` and
    ``valid_until`` (YYYY-MM-DD, both days included) and ``role`` ("approver": approves and
    reviews, the default; "reviewer": reviews only). Blank lines and lines starting with
    ``#`` are skipped. ValueError naming the file, the line, the key, what was expected
    and what was found (calib_core.settings.refusal) for anything else."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise ValueError(f"approvers file {path}: cannot be read ({exc.strerror or exc})") from None
    keys = []
    for n, line in enumerate(lines, 1):
        if line.strip() and not line.lstrip().startswith("#"):
            try:
                keys.append(_trusted_key(line))
            except ValueError as exc:  # SettingError, or the line not JSON
                raise refusal("approvers file", path, None, exc, line=n) from None
    if not keys:
        raise ValueError(
            f"approvers file {path}: no key in it (expected lines of calib keygen .pub files)"
        )
    return Approvers(path, tuple(keys))


def _trusted_key(line: str) -> TrustedKey:
    """One line of an approvers file; SettingError naming its key, or ValueError when the
    line is not JSON."""
    try:
        d = json.loads(line)
    except ValueError as exc:
        raise ValueError(
            f"expected one JSON object (a calib keygen .pub line), got {line[:60]!r} ({exc})"
        ) from None
    checked(APPROVER, d, "", ("name", "public_key"))
    public, name = d["public_key"], d["name"]
    if len(public) != 64 or not _is_hex(public):
        raise SettingError("public_key", f"expected 64 hex digits, got {public!r}", "")
    if not is_one_line(name):
        problem = f"expected one line of 1..200 characters without control characters, got {name!r}"
        raise SettingError("name", problem, "")
    start, end = (_day(d.get(k), k) for k in ("valid_from", "valid_until"))
    if start and end and end < start:
        problem = f"expected a day on or after valid_from {start}, got {end}"
        raise SettingError("valid_until", problem, "")
    return TrustedKey(name, public.lower(), start, end, d.get("role", "approver"))


def _is_hex(text_: str) -> bool:
    try:
        bytes.fromhex(text_)
    except ValueError:
        return False
    return True


def _day(value: str | None, key: str) -> date | None:
    if value is None:
        return None
    try:
        if len(value) != 10:
            raise ValueError
        return date.fromisoformat(value)
    except ValueError:
        raise SettingError(key, f"expected a date YYYY-MM-DD, got {value!r}", "") from None


def check_trust(conn: Connection, approvers: Approvers) -> list[seal_check.Finding]:
    """Every approval whose key the lab's approvers file does not hold for its date,
    naming the run, the claimed signer and the key's fingerprint."""
    found: list[seal_check.Finding] = []
    for ev in conn.execute(
        select(AuditEvent).where(AuditEvent.action == "approved").order_by(AuditEvent.seq)
    ):
        a = _approval(ev)
        why = approvers.judge(a)
        if why:
            found.append(
                seal_check.Finding(
                    "untrusted",
                    "audit_events",
                    [a.run_id],
                    f"{a.run_id} revision {a.revision}: the approval ({a.meaning}) claimed by "
                    f"{a.signer} (event {a.seq}, key {fingerprint(a.public_key)}) is not trusted: "
                    f"{why}",
                )
            )
    return found
