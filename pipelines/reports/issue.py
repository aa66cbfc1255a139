"""Issued certificates: the HTML and PDF of a revision written into the archive, sealed.

A certificate is *issued* when its run is archived (`pipelines.process`): its HTML and
the PDF typeset from that HTML go into the revision's folder beside the protocol, and
an audit event ``certificate issued`` records the SHA-256 of each file, the issue
number and the certificate number, so `calib verify` sees a file changed or removed
behind the archive's back (`storage.seal_check.check`). The web pages and `calib report`
hand out these files; they never render a certificate of their own. A re-issue (after
an approval, a new lab profile) is a new document: the next issue number, its own
certificate number ("<run>-<revision>-<issue>") and files, and an event of its own;
the earlier issues stay as they were.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from storage import rawstore, seal
from storage.db import Archive

if TYPE_CHECKING:
    from storage.queries.records import RunSummary

ISSUED = seal.ISSUED  # the audit action
PROTOCOL = "protocol"


@dataclass(frozen=True)
class Issue:
    """One issued certificate of a calibration revision."""

    run_id: str
    revision: int
    issue: int  # 1 for the certificate issued when the revision was archived
    number: str  # the certificate number printed on every page
    files: dict[str, Path]  # "html", "pdf", "protocol" -> absolute path in the archive
    verdict: str


def _names(serial: str, run_id: str, issue: int) -> dict[str, str]:
    stem = f"{serial}_{run_id}_certificate" + ("" if issue == 1 else f"_issue-{issue}")
    return {"html": f"{stem}.html", "pdf": f"{stem}.pdf"}


def _folder(run: RunSummary) -> str:
    """The revision's folder, relative to the archive root (as `storage.archive` names it)."""
    revision = run.calibration.revision
    return run.run_dir if revision == 1 else f"{run.run_dir}/revision-{revision}"


def protocol_of(archive: Archive, run: RunSummary) -> Path | None:
    """The test protocol archived with the run's current revision (written when the run was
    archived, issued certificate or not), None if it is not there."""
    path = archive.root / _folder(run) / f"{run.device.serial}_result.txt"
    return path if path.is_file() else None


def issued(archive: Archive, run_id: str) -> Issue | None:
    """The latest issued certificate of the run's current revision, None if none was issued."""
    from storage import queries

    run = queries.run_summary(archive, run_id)
    revision = run.calibration.revision
    mine = [e for e in queries.certificate_issues(archive, run_id) if e["revision"] == revision]
    if not mine:
        return None
    detail = mine[-1]["detail"]
    files = {kind: archive.root / rel for kind, rel in detail["paths"].items()}
    if (protocol := protocol_of(archive, run)) is not None:
        files[PROTOCOL] = protocol
    verdict = run.calibration.verdict
    return Issue(run_id, revision, detail["issue"], detail["certificate"], files, verdict)


def issue(archive: Archive, run_id: str, *, reason: str | None = None) -> Issue:
    """Typeset the run's certificate (current revision) from the archive, write its HTML and
    PDF into the revision's folder and record the event that seals them: both, or neither
    (files whose event cannot be recorded are removed again).

    Parameters
    ----------
    archive : a writable archive.
    run_id : the full run id.
    reason : why it is issued again (kept in the audit event); None for the first issue.

    Returns
    -------
    Issue, with the paths of the files written.
    """
    from pipelines.reports.render import render_html
    from pipelines.reports.run_reports import archived_run, certificate_for
    from pipelines.reports.typeset import pdf_bytes

    seal.check_reason(reason)
    from storage import queries

    archived = archived_run(archive, run_id)
    run, revision = archived.run, archived.run.calibration.revision
    issues = queries.certificate_issues(archive, run_id)
    number = 1 + sum(e["revision"] == revision for e in issues)
    cert = certificate_for(archive, replace(archived, issue=number))
    data = {"pdf": pdf_bytes(cert), "html": render_html(cert).encode()}
    folder = _folder(run)
    rel = {k: f"{folder}/{name}" for k, name in _names(run.device.serial, run_id, number).items()}
    with rawstore.PendingFiles() as pending:
        for kind, path in rel.items():
            target = archive.root / path
            if target.exists():  # an archived file is never overwritten
                raise FileExistsError(
                    f"{target} exists already: the certificate of issue "
                    f"{number} was written but not recorded; move it away"
                )
            pending.write_bytes(target, data[kind])
        pending.commit()
    detail = {
        "issue": number,
        "certificate": cert.identifier,
        "paths": rel,
        "files": {rel[k]: hashlib.sha256(data[k]).hexdigest() for k in rel},
    }
    files = {k: archive.root / p for k, p in rel.items()}
    try:
        seal.record_event(
            archive, ISSUED, run_id=run_id, revision=revision, reason=reason, detail=detail
        )
    except BaseException:  # not recorded: not issued, so no file of it stays behind
        for path in files.values():
            path.unlink(missing_ok=True)
        raise
    if (protocol := protocol_of(archive, run)) is not None:
        files[PROTOCOL] = protocol
    return Issue(run_id, revision, number, cert.identifier, files, run.calibration.verdict)
