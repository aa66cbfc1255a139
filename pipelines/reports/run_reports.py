"""The reports of an archived run, from the archive alone: what a certificate is built from
(`ArchivedRun`, `archived_run`: the run summary with the lab profile, the unit's interval,
its calibration as found and the audit chain's head), the approvals judged against the
lab's approvers (`trusted_approvals`), the certificate (`certificate_of`) and its files
written into a folder (`write_reports`, `report_run`; the DCC with ``form="dcc"``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import Any

import pyarrow as pa

from calib_core.verification import PASS
from pipelines.reports.certificate import sections
from pipelines.reports.navigation import navigation_data
from pipelines.reports.render import Certificate, render_html
from pipelines.reports.typeset import render_pdf
from storage.queries.records import DatedRevision, RunSummary


@dataclass(frozen=True)
class ArchivedRun:
    """An archived run as its certificate and DCC state it: the run and what they add."""

    run: RunSummary  # storage.queries.run_summary
    lab: dict[str, Any] | None = None  # the lab profile (pipelines.lab), None without one
    recall: dict[str, Any] | None = None  # the unit's interval (pipelines.recall), passed runs
    as_found: DatedRevision | None = None  # its latest valid calibration before this run
    chain_head: tuple[int, str] | None = None  # (seq, hash) of the audit chain at issue
    navigation: list[dict[str, Any]] = field(default_factory=list)  # lab.toml [navigation]
    issue: int = 1  # the issue number (pipelines.reports.issue)


def write_reports(
    archived: ArchivedRun,
    samples: pa.Table,
    folder: Path,
    *,
    pdf: bool = True,
    approvals: list[tuple[Any, bool]] | None = None,
) -> dict[str, Path]:
    """Write `<serial>_result.txt`, `<serial>_<run>_certificate.html` (and `.pdf`) into `folder`.

    `approvals`: as for `sections`.

    Returns
    -------
    {"protocol": path, "html": path, "pdf": path (when written)}.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cert = sections(archived, samples, approvals)
    serial, run_id = archived.run.device.serial, archived.run.run_id
    out = {"protocol": folder / f"{serial}_result.txt"}
    out["protocol"].write_text(cert.protocol, encoding="utf-8")
    stem = f"{serial}_{run_id}_certificate"
    if pdf:
        out["pdf"] = render_pdf(cert, folder / f"{stem}.pdf")
    out["html"] = folder / f"{stem}.html"
    out["html"].write_text(render_html(cert), encoding="utf-8")
    return out


REPORT_FORMATS = ("certificate", "dcc")


def report_run(
    archive,
    run_id: str,
    folder: Path | None = None,
    *,
    pdf: bool = True,
    form: str = "certificate",
) -> dict:
    """Write the reports of an archived run, from the archive alone (run summary + samples).

    Parameters
    ----------
    archive : storage.db.Archive
    run_id : the archived run.
    folder : where to write; default the run's folder in the archive.
    pdf : also render the PDF certificate (the slowest part).
    form : "certificate" (protocol, HTML and PDF) or "dcc" (the Digital Calibration
        Certificate XML, `pipelines.reports.dcc`).

    Returns
    -------
    dict: ``verdict`` and the written paths ``protocol`` (``<serial>_result.txt``),
    ``html`` and (with `pdf`) ``pdf``; or ``dcc``.
    """
    if form not in REPORT_FORMATS:
        raise ValueError(f"report format {form!r}: expected one of {list(REPORT_FORMATS)}")
    archived = archived_run(archive, run_id)
    folder = folder if folder is not None else archive.root / archived.run.run_dir
    verdict = archived.run.calibration.verdict
    if form == "dcc":
        from pipelines.reports.dcc import write_dcc

        return {"verdict": verdict, "dcc": write_dcc(archived, folder)}
    from storage import queries

    samples = queries.run_samples(archive, run_id)
    approvals = trusted_approvals(archive, archived.run)
    written = write_reports(archived, samples, folder, pdf=pdf, approvals=approvals)
    return {"verdict": verdict, **written}


def archived_run(archive, run_id: str, issue: int = 1) -> ArchivedRun:  # noqa: ANN001 - Archive
    """`storage.queries.run_summary` of the run with what the certificate adds: the lab
    profile, the unit's recalibration interval (for a passed run), its calibration before
    this run (as found), the audit chain's head at issue and the navigation figures."""
    from pipelines.lab import load_lab_profile
    from storage import queries
    from storage.checkpoint import chain_head

    run = queries.run_summary(archive, run_id)
    lab = load_lab_profile()
    serial = run.device.serial
    recall = None
    if run.calibration.verdict == PASS:  # the interval is stated for a released unit only
        from pipelines.recall import unit_recall  # pandas and the fleet's trends: only then

        recall = unit_recall(archive, serial, run_id)
    return ArchivedRun(
        run,
        lab=None if lab is None else lab[0],
        recall=recall,
        as_found=queries.latest_calibration(
            archive, serial, run.started_at - timedelta(microseconds=1)
        ),
        chain_head=chain_head(archive),
        navigation=navigation_data(archive, run_id),
        issue=issue,
    )


def trusted_approvals(archive, run: RunSummary) -> list:  # noqa: ANN001 - Archive
    """The approvals of the run's revision, each judged against the lab's approvers file
    (pipelines.trust; none given: marked as not checked against one)."""
    from pipelines.trust import lab_approvers
    from storage.approval import approval_status

    return approval_status(archive, run.run_id, run.calibration.revision, lab_approvers())


def certificate_of(archive, run_id: str, *, issue: int = 1) -> tuple[ArchivedRun, Certificate]:  # noqa: ANN001 - Archive
    """(archived run, certificate) of an archived run, from the archive alone, as issue
    `issue` (`pipelines.reports.issue`: a re-issue is a new document with its own number)."""
    archived = archived_run(archive, run_id, issue)
    return archived, certificate_for(archive, archived)


def certificate_for(archive, archived: ArchivedRun) -> Certificate:  # noqa: ANN001 - Archive
    """The certificate of an archived run, its samples and approvals read from the archive."""
    from storage import queries

    samples = queries.run_samples(archive, archived.run.run_id)
    return sections(archived, samples, trusted_approvals(archive, archived.run))
