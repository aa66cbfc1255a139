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
it is is a matter of the lab's key list (compare the public key shown by
``calib audit``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from sqlalchemy import Connection, select

from storage import seal
from storage.db import Archive
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


def _public_hex(key: Ed25519PublicKey) -> str:
    return key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw).hex()


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
    public = _public_hex(key.public_key())
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
    if not name.strip() or len(name) > 200 or any(ord(c) < 32 for c in name):
        raise ValueError(f"signer name: 1..200 characters without control characters, got {name!r}")


def message(
    run_id: str, revision: int, digest: str, meaning: str, signer: str, public: str
) -> bytes:
    """The bytes that are signed."""
    return seal.canonical({"run_id": run_id, "revision": revision, "digest": digest,
                           "meaning": meaning, "signer": signer, "public_key": public})  # fmt: skip


def approve(
    archive: Archive,
    run_id: str,
    key: Ed25519PrivateKey,
    *,
    signer: str,
    meaning: Meaning = "approved",
    revision: int | None = None,
) -> seal.Event:
    """Sign the seal of `run_id`'s current (or given) revision and chain the approval event.

    Refused (ApprovalError) when the run or revision is unknown, has no seal, or its
    rows no longer match the seal: a changed record is never signed.
    """
    if meaning not in MEANINGS:
        raise ValueError(f"meaning: expected one of {MEANINGS}, got {meaning!r}")
    _check_name(signer)
    engine = archive.engine().execution_options(sqlite_begin="IMMEDIATE")
    with engine.begin() as conn:
        cal_id, rev, digest, sealed = _sealed_revision(conn, run_id, revision)
        files_now = seal.rehash_files(archive.root, sealed.get("files", {}))
        if seal.digest_now(conn, cal_id, files_now, sealed.get("format")) != digest:
            raise ApprovalError(
                f"run {run_id} revision {rev}: its rows no longer match its seal; "
                "run `calib verify` to see what changed; not signed"
            )
        public = _public_hex(key.public_key())
        signature = key.sign(message(run_id, rev, digest, meaning, signer, public)).hex()
        detail = {"meaning": meaning, "signer": signer, "public_key": public,
                  "signature": signature}  # fmt: skip
        return seal.append_event(conn, "approved", run_id=run_id, revision=rev, detail=detail,
                                 digest=digest)  # fmt: skip


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
    q = q.where(CalibrationRow.superseded_by.is_(None) if revision is None
                else CalibrationRow.revision == revision)  # fmt: skip
    row = conn.execute(q).one_or_none()
    if row is None:
        which = "current revision" if revision is None else f"revision {revision}"
        raise ApprovalError(f"run {run_id}: no {which} in the archive")
    if row.digest is None:
        raise ApprovalError(f"run {run_id} revision {row.revision} has no seal; not signed")
    return row.id, row.revision, row.digest, row.record


def _signature_error(ev: Any) -> str | None:
    """Why the signature of approval event `ev` does not verify (None: it does)."""
    d = ev.detail or {}
    try:
        public = Ed25519PublicKey.from_public_bytes(bytes.fromhex(d["public_key"]))
        public.verify(
            bytes.fromhex(d["signature"]),
            message(ev.run_id, ev.revision, ev.digest, d["meaning"], d["signer"], d["public_key"]),
        )
    except (InvalidSignature, KeyError, ValueError, TypeError) as exc:
        return type(exc).__name__
    return None


def check(conn: Connection, digests_now: dict[tuple[str, int], str]) -> list[seal.Finding]:
    """Every approval's signature, and whether the record it signed is unchanged."""
    found: list[seal.Finding] = []
    for ev in conn.execute(select(AuditEvent).where(AuditEvent.action == "approved")):
        d = ev.detail or {}
        who = f"{d.get('meaning', '?')} by {d.get('signer', '?')} (event {ev.seq})"
        where = f"{ev.run_id} revision {ev.revision}"
        error = _signature_error(ev)
        if error is not None:
            found.append(seal.Finding("signature", "audit_events", [ev.run_id],
                                      f"{where}: the signature of the approval {who} does not "
                                      f"verify ({error}): the event was altered"))  # fmt: skip
            continue
        now = digests_now.get((ev.run_id, ev.revision))
        if now != ev.digest:
            found.append(seal.Finding("signature", "audit_events", [ev.run_id],
                                      f"{where}: the approval {who} no longer holds: the record "
                                      f"was signed with digest {ev.digest}, its rows now give "
                                      f"{now or '(rows gone)'}"))  # fmt: skip
    return found


def approval_status(archive: Archive, run_id: str, revision: int) -> list[tuple[Approval, bool]]:
    """The approvals of one revision, each with whether it holds now: its signature
    verifies and the revision's rows and files still give the digest it signed.
    A revision without a seal has no approval that holds."""
    with archive.engine().connect() as conn:
        try:
            cal_id, _, _, sealed = _sealed_revision(conn, run_id, revision)
        except ApprovalError:
            return []
        files_now = seal.rehash_files(archive.root, sealed.get("files", {}))
        now = seal.digest_now(conn, cal_id, files_now, sealed.get("format"))
        events = conn.execute(
            select(AuditEvent).where(AuditEvent.action == "approved",
                                     AuditEvent.run_id == run_id, AuditEvent.revision == revision)
            .order_by(AuditEvent.seq)
        ).all()  # fmt: skip
    return [(_approval(ev), _signature_error(ev) is None and ev.digest == now) for ev in events]


def _approval(ev: Any) -> Approval:
    d = ev.detail or {}
    return Approval(ev.seq, ev.run_id, ev.revision, d.get("meaning", ""), d.get("signer", ""),
                    d.get("public_key", ""), ev.at.isoformat())  # fmt: skip


def approvals(archive: Archive, run_id: str) -> list[Approval]:
    """The approvals of a run, oldest first."""
    with archive.engine().connect() as conn:
        rows = conn.execute(
            select(AuditEvent).where(AuditEvent.action == "approved", AuditEvent.run_id == run_id)
            .order_by(AuditEvent.seq)
        ).all()  # fmt: skip
    return [_approval(ev) for ev in rows]
