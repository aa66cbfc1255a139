"""Checkpoints: the audit chain's head written down outside the archive, checked later.

A hash chain shows an event changed or removed in its middle, but not a chain
rewritten as a whole (a value, its document and seal changed, every later event
rehashed with calib's own code) nor the newest runs removed together with their
seals and events (a rollback): only the head differs. A *checkpoint* records
the head at one time (sequence number, hash, time, counts of runs and seals)
with the first 16 hex digits of every event's hash before it, optionally signed
with an approval key (storage.approval). Kept where the archive's writers cannot
reach it (docs/archive.md), it lets `check` say whether the chain now extends it
exactly, and if not, which event is the first to differ.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from sqlalchemy import Connection, func, select

from calib_core.settings import Setting, SettingError, Settings, checked, refusal
from storage import seal, seal_check, seal_record
from storage.db import Archive
from storage.schema import AuditEvent, Run, Seal, utcnow

KIND = "calib-checkpoint"
VERSION = 1
PREFIX = 16  # hex digits of each event's hash kept: enough to name the first that differs
_SIGNED = ("signer", "public_key", "signature")
# What `load` reads of a checkpoint file (a JSON object); its other keys (archive, at,
# runs, seals, the signature's) are read where they are used.
CHECKPOINT = Settings(
    Setting("kind", "text", "", None, "calib-checkpoint (calib checkpoint -o FILE)"),
    Setting("version", "integer", "", None, "the format's version (VERSION)"),
    Setting("seq", "integer", "", None, "the head's sequence number", low=0),
    Setting("hash", "text", "", None, "the head's hash (hex)"),
    Setting("events", "list", "", None, "each event's hash prefix up to seq, oldest first"),
    name="CheckpointHead",
    noun="field",
)


def make(
    archive: Archive, key: Ed25519PrivateKey | None = None, signer: str | None = None
) -> dict[str, Any]:
    """The checkpoint document of the archive's chain now, signed with `key` if given."""
    with archive.engine().connect() as conn:
        hashes = conn.execute(select(AuditEvent.hash).order_by(AuditEvent.seq)).scalars().all()
        seq, head = seal.head(conn)
        runs = conn.execute(select(func.count()).select_from(Run)).scalar_one()
        seals = conn.execute(select(func.count()).select_from(Seal)).scalar_one()
    doc: dict[str, Any] = {
        "kind": KIND,
        "version": VERSION,
        "archive": archive.display_url,
        "seq": seq,
        "hash": head,
        "at": utcnow().isoformat(),
        "runs": runs,
        "seals": seals,
        "events": [h[:PREFIX] for h in hashes],
    }
    if key is not None:
        from storage.approval import public_key_hex

        if not signer:
            raise ValueError("a signed checkpoint needs the signer's name")
        doc["signer"], doc["public_key"] = signer, public_key_hex(key.public_key())
        doc["signature"] = key.sign(_message(doc)).hex()
    return doc


def _message(doc: dict[str, Any]) -> bytes:
    return seal_record.canonical({k: v for k, v in doc.items() if k != "signature"})


def write(doc: dict[str, Any], path: Path) -> None:
    """Write `doc` to a new file `path` (never overwritten: a checkpoint is kept as made)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(json.dumps(doc, indent=1) + "\n")
            f.flush()
            os.fsync(f.fileno())
    except OSError:  # a full disk: no partial checkpoint stays to be taken for one
        Path(path).unlink(missing_ok=True)
        raise


def load(path: Path) -> dict[str, Any]:
    """A checkpoint file's document, its keys checked (`CHECKPOINT`); ValueError naming the
    file, the key (a JSON document: by its key path, no line), what was expected and what
    was found (calib_core.settings.refusal)."""
    path = Path(path)
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ValueError(f"checkpoint {path}: cannot be read ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise ValueError(f"checkpoint {path}: not JSON ({exc})") from None
    try:
        return _checked(doc)
    except SettingError as exc:
        raise refusal("checkpoint", path, None, exc) from None


def _checked(doc: Any) -> dict[str, Any]:
    """`doc` if it is a checkpoint this calib reads; SettingError naming the key if not."""
    if not isinstance(doc, dict):
        raise SettingError("(top level)", f"expected an object of kind {KIND!r}, got {doc!r}", "")
    if doc.get("kind") != KIND:
        problem = f"expected {KIND!r} (a file of calib checkpoint -o FILE), got {doc.get('kind')!r}"
        raise SettingError("kind", problem, "")
    checked(CHECKPOINT, doc, "", tuple(CHECKPOINT.items), others=True)
    if doc["version"] != VERSION:
        problem = f"expected {VERSION} (the version this calib reads), got {doc['version']!r}"
        raise SettingError("version", problem, "")
    seq, events = doc["seq"], doc["events"]
    if len(events) != seq:
        problem = f"expected one hash prefix per event up to seq {seq}, got {len(events)}"
        raise SettingError("events", problem, "")
    for i, prefix in enumerate(events):
        if not isinstance(prefix, str):
            raise SettingError(f"events[{i}]", f"expected a hash prefix (text), got {prefix!r}", "")
    return doc


def signature_error(doc: dict[str, Any]) -> str | None:
    """Why a signed checkpoint's signature does not verify (None: it does, or unsigned)."""
    if not any(k in doc for k in _SIGNED):
        return None
    from storage import approval

    return approval.signature_error(doc, lambda: _message(doc))


def check(conn: Connection, doc: dict[str, Any], source: str) -> list[seal_check.Finding]:
    """Whether the chain now extends the checkpoint `doc` (read from `source`) exactly;
    a finding naming the first event that differs, or the events gone, if not."""
    when = f"the checkpoint {source} of {str(doc.get('at', '?'))[:19]}"
    error = signature_error(doc)
    if error is not None:
        problem = f"the signature of {when} does not verify ({error}): the file was altered; "
        return [seal_check.Finding("checkpoint", source, [], problem + "it is not compared")]
    rows = conn.execution_options(yield_per=5000).execute(
        select(AuditEvent.seq, AuditEvent.hash, AuditEvent.action, AuditEvent.run_id)
        .where(AuditEvent.seq <= doc["seq"])
        .order_by(AuditEvent.seq)
    )
    expected = 1  # the next event's seq
    for seq, hash_, action, run_id in rows:
        if seq != expected:
            return [_gone(when, expected, seq - 1, doc)]
        kept = doc["events"][seq - 1]
        full = doc["hash"] if seq == doc["seq"] else None
        if hash_[:PREFIX] != kept or (full is not None and hash_ != full):
            what = f"event {seq} ({action}{' of ' + run_id if run_id else ''})"
            problem = f"{what} differs from {when}: hash {hash_[:PREFIX]}... now, {kept}... "
            problem += "then; the chain was rewritten from this event on"
            runs = [run_id] if run_id else []
            return [seal_check.Finding("checkpoint", "audit_events", runs, problem)]
        expected = seq + 1
    return [_gone(when, expected, doc["seq"], doc)] if expected <= doc["seq"] else []


def _gone(when: str, first: int, last: int, doc: dict[str, Any]) -> seal_check.Finding:
    return seal_check.Finding(
        "checkpoint",
        "audit_events",
        [],
        f"events {first}..{last} of {when} are gone (it held {doc['seq']} events, "
        f"{doc.get('runs', '?')} runs, {doc.get('seals', '?')} seals): a rollback or truncation "
        "of the chain",
    )


def chain_head(archive: Archive) -> tuple[int, str]:
    """(seq, hash) of the archive's newest audit event (what a certificate prints)."""
    with archive.engine().connect() as conn:
        return seal.head(conn)


def untrusted_signer(doc: dict[str, Any], approvers: Any) -> str:
    """Why the signer of a signed checkpoint is not one the lab's approvers file trusts on
    its date ("" when it is, or when the checkpoint is not signed)."""
    if "signature" not in doc:
        return ""
    from storage.approval import Approval

    signed = Approval(
        0,
        "",
        0,
        "reviewed",
        str(doc.get("signer", "")),
        str(doc.get("public_key", "")),
        str(doc.get("at", "")),
    )
    why = approvers.judge(signed)
    return f"the checkpoint is signed by {signed.signer}, not trusted: {why}" if why else ""
