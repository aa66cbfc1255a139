"""Method validation, the archive: a run's comparison with independent implementations kept
as a sealed record (table ``validations``, docs/validation.md).

Each record holds the comparison document (`pipelines.validation.compare.validate_run`)
with the calibration revision it compared. Its digest, the SHA-256 of the canonical JSON
of the record (run, revision, when, software version, document), is carried by the
"validated" event of the audit chain written in the same transaction, so a record
changed or removed behind the archive's back is a finding of `calib verify`
(storage.seal_check calls `check_records`).
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import Connection, select
from sqlalchemy.orm import Session

from storage import seal
from storage.current import CURRENT
from storage.db import Archive
from storage.queries.records import Validation
from storage.schema import AuditEvent, CalibrationRow, Run, ValidationRow, utcnow
from storage.seal_record import canonical, sha256_hex

VALIDATED = "validated"  # the audit action that seals a validation record


def digest_of(
    run_id: str, revision: int, created_at: datetime, software_version: str, document: Any
) -> str:
    """The SHA-256 a validation record is sealed with."""
    return sha256_hex(
        canonical(
            {
                "run_id": run_id,
                "revision": revision,
                "created_at": created_at,
                "software_version": software_version,
                "document": document,
            }
        )
    )


def archive_validation(
    archive: Archive, run_id: str, document: dict[str, Any], software_version: str
) -> int:
    """Keep one comparison of the current revision of `run_id`, sealed; the record's id.

    Raises LookupError for an unknown run, ValueError when the document compared
    another revision than the current one.
    """
    engine = archive.engine().execution_options(sqlite_begin="IMMEDIATE")
    with Session(engine) as s, s.begin():
        row = s.execute(
            select(CalibrationRow.id, CalibrationRow.revision)
            .join(Run, Run.id == CalibrationRow.run_id)
            .where(Run.run_id == run_id, CURRENT)
        ).one_or_none()
        if row is None:
            raise LookupError(f"no calibration of run {run_id!r}")
        if document.get("revision") != row.revision:
            raise ValueError(
                f"run {run_id}: the comparison is of revision {document.get('revision')}, "
                f"the current revision is {row.revision}"
            )
        created = utcnow()
        digest = digest_of(run_id, row.revision, created, software_version, document)
        rec = ValidationRow(
            calibration_id=row.id,
            created_at=created,
            software_version=software_version,
            document=document,
            digest=digest,
        )
        s.add(rec)
        s.flush()
        peers = [p["peer"] for p in document.get("peers", [])]
        seal.append_event(
            s.connection(),
            VALIDATED,
            run_id=run_id,
            revision=row.revision,
            digest=digest,
            detail={"validation_id": rec.id, "peers": peers},
        )
        return rec.id


# Every column of a record with its run id and revision.
_RECORDS = (
    select(*ValidationRow.__table__.columns, CalibrationRow.revision, Run.run_id)
    .join(CalibrationRow, CalibrationRow.id == ValidationRow.calibration_id)
    .join(Run, Run.id == CalibrationRow.run_id)
)


def validations(archive: Archive, run_id: str, revision: int | None = None) -> list[Validation]:
    """The validation records of a run (of one revision if given), oldest first."""
    stmt = _RECORDS.where(Run.run_id == run_id)
    if revision is not None:
        stmt = stmt.where(CalibrationRow.revision == revision)
    with archive.engine().connect() as conn:
        rows = conn.execute(stmt.order_by(ValidationRow.id)).all()
    return [
        Validation(r.id, r.created_at, r.software_version, r.revision, r.digest, r.document)
        for r in rows
    ]


def check_records(conn: Connection) -> list[tuple[str, str]]:
    """Every "validated" event against its record now: (run_id, what is wrong) for a record
    whose content no longer hashes to its event's digest, or that is gone."""
    events = conn.execute(
        select(AuditEvent.run_id, AuditEvent.detail, AuditEvent.digest)
        .where(AuditEvent.action == VALIDATED)
        .order_by(AuditEvent.seq)
    ).all()
    rows = {r.id: r for r in conn.execute(_RECORDS).all()}
    out = []
    for run_id, detail, digest in events:
        vid = (detail or {}).get("validation_id")
        r = rows.pop(vid, None)
        if r is None:
            out.append((run_id or "?", f"validation record {vid} was sealed but is gone"))
            continue
        now = digest_of(r.run_id, r.revision, r.created_at, r.software_version, r.document)
        if now != digest or r.digest != digest:
            out.append((r.run_id, f"validation record {vid} changed since it was sealed"))
    for vid, r in sorted(rows.items()):
        out.append(
            (r.run_id, f"validation record {vid} has no seal: added behind the archive's back")
        )
    return out
