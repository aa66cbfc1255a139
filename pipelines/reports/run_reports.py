"""The reports of an archived run, from the archive alone: the summary a certificate is
built from (`archived_summary`: the run summary with the lab profile, the unit's interval,
its calibration as found and the audit chain's head), the approvals judged against the
lab's approvers (`trusted_approvals`), the certificate (`certificate_of`) and its files
written into a folder (`write_reports`, `report_run`; the DCC with ``form="dcc"``).
"""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path
from typing import Any

import pyarrow as pa

from calib_core.verification import PASS
from pipelines.reports.certificate import sections
from pipelines.reports.navigation import navigation_data
from pipelines.reports.render import Certificate, render_html
from pipelines.reports.typeset import render_pdf


def write_reports(
    summary: dict[str, Any],
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
    cert = sections(summary, samples, approvals)
    serial, run_id = summary["device"]["serial"], summary["run_id"]
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
    summary = archived_summary(archive, run_id)
    folder = folder if folder is not None else archive.root / summary["run_dir"]
    if form == "dcc":
        from pipelines.reports.dcc import write_dcc

        return {"verdict": summary["calibration"]["verdict"], "dcc": write_dcc(summary, folder)}
    from storage import queries

    samples = queries.run_samples(archive, run_id)
    approvals = trusted_approvals(archive, summary)
    written = write_reports(summary, samples, folder, pdf=pdf, approvals=approvals)
    return {"verdict": summary["calibration"]["verdict"], **written}


def archived_summary(archive, run_id: str) -> dict[str, Any]:  # noqa: ANN001 - Archive
    """`storage.queries.run_summary` of the run with what the certificate adds: the lab
    profile (``lab``), the unit's recalibration interval (``recall``, for a passed run),
    its calibration before this run (``as_found``) and the audit chain's head at issue
    (``chain_head``)."""
    from pipelines.lab import load_lab_profile
    from storage import queries
    from storage.checkpoint import chain_head

    summary = queries.run_summary(archive, run_id)
    lab = load_lab_profile()
    summary["lab"] = None if lab is None else lab[0]
    # the interval is stated for a released unit only (`_recommendations`)
    released = summary["calibration"]["verdict"] == PASS
    summary["recall"] = None
    if released:
        from pipelines.recall import unit_recall  # pandas and the fleet's trends: only then

        summary["recall"] = unit_recall(archive, summary["device"]["serial"], run_id)
    summary["as_found"] = queries.latest_calibration(
        archive, summary["device"]["serial"], summary["started_at"] - timedelta(microseconds=1)
    )
    summary["chain_head"] = chain_head(archive)
    summary["navigation"] = navigation_data(archive, run_id)  # lab.toml [navigation]
    return summary


def trusted_approvals(archive, summary: dict[str, Any]) -> list:  # noqa: ANN001 - Archive
    """The approvals of the summary's revision, each judged against the lab's approvers file
    (pipelines.trust; none given: marked as not checked against one)."""
    from pipelines.trust import lab_approvers
    from storage.approval import approval_status

    return approval_status(
        archive, summary["run_id"], summary["calibration"]["revision"], lab_approvers()
    )


def certificate_of(
    archive,
    run_id: str,
    *,
    issue: int = 1,  # noqa: ANN001 - Archive
) -> tuple[dict[str, Any], Certificate]:
    """(summary, certificate) of an archived run, from the archive alone, as issue `issue`
    (`pipelines.reports.issue`: a re-issue is a new document with its own number)."""
    summary = archived_summary(archive, run_id)
    summary["issue"] = issue
    return summary, certificate_for(archive, summary)


def certificate_for(archive, summary: dict[str, Any]) -> Certificate:  # noqa: ANN001 - Archive
    """The certificate of an `archived_summary` (its ``issue`` set), its samples and
    approvals read from the archive."""
    from storage import queries

    samples = queries.run_samples(archive, summary["run_id"])
    return sections(summary, samples, trusted_approvals(archive, summary))
