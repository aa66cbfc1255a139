"""The audit trail (storage.seal): who changed what in the archive, when and why; each
revision of a run as its seal records it."""

from __future__ import annotations

from datetime import date, datetime
from typing import Any

from sqlalchemy import select

from storage.db import Archive
from storage.queries._common import as_instant, check_serial, reading
from storage.queries.runs import full_run_id
from storage.schema import AuditEvent, CalibrationRow, Device, Run, Seal
from storage.seal import EVENT_FIELDS, ISSUED

# An event's fields as hashed, but the previous hash, and its own hash.
AUDIT_COLUMNS = [*(f for f in EVENT_FIELDS if f != "prev_hash"), "hash"]


def audit_trail(
    archive: Archive, target: str | None = None, since: date | datetime | str | None = None
) -> list[dict[str, Any]]:
    """Audit events, oldest first.

    Parameters
    ----------
    archive : the archive.
    target : None (every event), a unit serial (the events of its runs) or a run id
        or unique prefix of one (its events). A serial wins over a run id prefix.
    since : only events at or after this instant (a date means 00:00 UTC).

    Raises
    ------
    ValueError, LookupError naming the target or date when they name nothing.
    """
    q = select(*(getattr(AuditEvent, c) for c in AUDIT_COLUMNS)).order_by(AuditEvent.seq)
    start = as_instant(since, "since", end_of_day=False)
    if start is not None:
        q = q.where(AuditEvent.at >= start)
    if target is not None:
        q = q.where(AuditEvent.run_id.in_(_run_ids(archive, target)))
    with reading(archive) as conn:
        return [dict(r._mapping) for r in conn.execute(q)]


def certificate_issues(archive: Archive, run_id: str) -> list[dict[str, Any]]:
    """The ``certificate issued`` events of a run (revision, detail, at), oldest first."""
    q = (
        select(AuditEvent.revision, AuditEvent.detail, AuditEvent.at)
        .where(AuditEvent.run_id == run_id, AuditEvent.action == ISSUED)
        .order_by(AuditEvent.seq)
    )
    with reading(archive) as conn:
        return [dict(r._mapping) for r in conn.execute(q)]


def _run_ids(archive: Archive, target: str) -> list[str]:
    with reading(archive) as conn:
        serial_runs = (
            conn.execute(
                select(Run.run_id)
                .join(Device, Device.id == Run.device_id)
                .where(Device.serial == check_serial(target))
            )
            .scalars()
            .all()
        )
    return list(serial_runs) or [full_run_id(archive, target)]


def archived_revisions(archive: Archive, run_id: str) -> list[dict[str, Any]]:
    """Each revision of the run as its rows hold it (`storage.seal_record.records`, every
    value decoded), its files as its seal lists them, oldest first; ``cal_id`` added.
    Raises LookupError for an unknown run."""
    from storage import seal_record

    with reading(archive) as conn:
        ids = list(
            conn.execute(
                select(CalibrationRow.id)
                .join(Run, Run.id == CalibrationRow.run_id)
                .where(Run.run_id == run_id)
                .order_by(CalibrationRow.revision)
            ).scalars()
        )
        if not ids:
            raise LookupError(f"no run {run_id} in the archive")
        sealed = select(Seal.calibration_id, Seal.record).where(Seal.calibration_id.in_(ids))
        files = {cal: (record or {}).get("files") or {} for cal, record in conn.execute(sealed)}
        found = seal_record.records(conn, ids, files, form=1)
    return [{**found[i], "cal_id": i} for i in ids]
