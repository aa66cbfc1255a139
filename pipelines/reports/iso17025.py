"""The certificate's ISO/IEC 17025:2017 7.8 items the other sections do not carry.

From the archive: the certificate number (run id and revision: unique per calibration
revision), the dates of calibration and issue, the method, the equipment with its due dates.
From the lab profile (`pipelines.lab`, ``summary["lab"]``): the laboratory, the customer, the
authoriser and the calibration certificates of the reference equipment. An item neither knows
is printed as "not recorded", never left out.
"""

from __future__ import annotations

from datetime import UTC, date, datetime
from typing import Any

from pipelines.reports.render import Section

NOT_RECORDED = "not recorded (lab profile lab.toml)"
ONLY_ITEMS = "The results relate only to the item calibrated, as received (7.8.2.1 l)."


def certificate_number(summary: dict[str, Any]) -> str:
    """Unique per calibration revision and issue: "<run id>-<revision>", then
    "<run id>-<revision>-<issue>" for a re-issue (`pipelines.reports.issue`)."""
    number = f"{summary['run_id']}-{summary['calibration']['revision']}"
    issue = summary.get("issue") or 1
    return number if issue == 1 else f"{number}-{issue}"


def _lab(summary: dict[str, Any], table: str) -> dict[str, str]:
    return (summary.get("lab") or {}).get(table) or {}


def _text(entry: dict[str, str], *keys: str) -> str:
    said = [entry[k] for k in keys if entry.get(k)]
    return ", ".join(said) if said else NOT_RECORDED


def issue_date(summary: dict[str, Any]) -> date:
    """The date of issue: given by the report writer, else today (UTC)."""
    return summary.get("issued") or datetime.now(UTC).date()


def deviations(procedure: str, settings: dict[str, Any]) -> str:
    """The settings that depart from the method as documented (docs/procedures.md): those
    given with another value than the procedure's default, and any it does not declare.
    A setting at its default, or one that says what the method otherwise infers (a full
    scale, a count: declared without a default), is the method as written."""
    from calib_core import procedures

    try:
        declared = {s.name: s for s in procedures.get(procedure).settings}
    except ValueError:  # a procedure this software no longer has: every setting said
        declared = {}
    departed = [
        f"{k}={v}"
        for k, v in settings.items()
        if k not in declared or declared[k].default not in (None, v)
    ]
    return ", ".join(departed) or "none"


def administrative_section(summary: dict[str, Any]) -> Section:
    """Laboratory, customer, certificate number, dates, method, place (7.8.2.1 b-k, n, p)."""
    lab, customer = _lab(summary, "laboratory"), _lab(summary, "customer")
    started: datetime = summary["started_at"]
    settings = summary["calibration"].get("settings") or {}
    return Section(
        "Certificate",
        pairs=[
            ("Certificate number", certificate_number(summary)),
            ("Calibration laboratory", _text(lab, "name", "address")),
            ("Accreditation", lab.get("accreditation") or "-"),
            ("Customer", _text(customer, "name", "contact")),
            ("Place of calibration", "the laboratory's site (run manifest [site])"),
            (
                "Item",
                f"{summary['device']['model']}, serial {summary['device']['serial']}, "
                f"made by {summary['device']['manufacturer']}",
            ),
            ("Date of receipt", "not recorded"),
            ("Date of calibration", f"{started:%Y-%m-%d}"),
            ("Date of issue", issue_date(summary).isoformat()),
            (
                "Method",
                f"procedure {summary['procedure']} (docs/procedures.md), "
                f"software {summary['calibration']['software_version']}",
            ),
            ("Deviations from the method", deviations(summary["procedure"], settings)),
            ("Sampling", "not applicable (one item)"),
            ("External providers", "none: every result was measured by the laboratory"),
        ],
        paragraphs=[ONLY_ITEMS],
    )


def traceability_section(summary: dict[str, Any]) -> Section:
    """The reference equipment with its calibration certificates and due dates (7.8.4.1 c)."""
    certificates = {e["serial"]: e for e in (summary.get("lab") or {}).get("equipment", [])}
    started: datetime = summary["started_at"]
    rows = []
    for e in summary["equipment"]:
        cert = certificates.get(e["serial"], {})
        due = e.get("calibration_due")
        due = None if due is None else date.fromisoformat(str(due))
        rows.append(
            [
                e["kind"],
                e["serial"],
                cert.get("certificate") or NOT_RECORDED,
                cert.get("issued_by") or "-",
                "-" if due is None else due.isoformat(),
                "-" if due is None else ("valid" if due >= started.date() else "LAPSED"),
            ]
        )
    return Section(
        "Metrological traceability (ISO/IEC 17025:2017 7.8.4.1 c)",
        header=["kind", "serial", "calibration certificate", "issued by", "due", "at calibration"],
        rows=rows,
        paragraphs=[
            "The results are traceable to the SI units through the reference equipment above, "
            "calibrated as its certificates state, and through local gravity (site model as "
            "in the run section)."
            if rows
            else "No reference equipment recorded: traceability rests on local gravity alone.",
        ],
    )


def authorisation_pairs(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """Who authorises the certificate (7.8.2.1 o) and the clear end of the certificate."""
    who = _lab(summary, "authorised_by")
    return [
        ("Authorised by", _text(who, "name", "function")),
        ("Signature", "______________________   Date: __________"),
    ]
