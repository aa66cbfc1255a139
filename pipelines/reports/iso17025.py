"""The certificate's ISO/IEC 17025:2017 7.8 items the other sections do not carry.

From the archive: the certificate number (run id and revision: unique per calibration
revision), the dates of calibration and issue, the method, the equipment with its due dates.
From the lab profile (`pipelines.lab`, ``ArchivedRun.lab``): the laboratory, the customer, the
authoriser and the calibration certificates of the reference equipment. An item neither knows
is printed as "not recorded", never left out.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from pipelines.reports.render import Section

NOT_RECORDED = "not recorded (lab profile lab.toml)"
if TYPE_CHECKING:
    from pipelines.reports.run_reports import ArchivedRun

ONLY_ITEMS = "The results relate only to the item calibrated, as received (7.8.2.1 l)."


def certificate_number(archived: ArchivedRun) -> str:
    """Unique per calibration revision and issue: "<run id>-<revision>", then
    "<run id>-<revision>-<issue>" for a re-issue (`pipelines.reports.issue`)."""
    number = f"{archived.run.run_id}-{archived.run.calibration.revision}"
    return number if archived.issue == 1 else f"{number}-{archived.issue}"


def _lab(lab: dict[str, Any] | None, table: str) -> dict[str, str]:
    return (lab or {}).get(table) or {}


def _text(entry: dict[str, str], *keys: str) -> str:
    said = [entry[k] for k in keys if entry.get(k)]
    return ", ".join(said) if said else NOT_RECORDED


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


def administrative_section(archived: ArchivedRun) -> Section:
    """Laboratory, customer, certificate number, dates, method, place (7.8.2.1 b-k, n, p)."""
    lab, customer = _lab(archived.lab, "laboratory"), _lab(archived.lab, "customer")
    run = archived.run
    return Section(
        "Certificate",
        pairs=[
            ("Certificate number", certificate_number(archived)),
            ("Calibration laboratory", _text(lab, "name", "address")),
            ("Accreditation", lab.get("accreditation") or "-"),
            ("Customer", _text(customer, "name", "contact")),
            ("Place of calibration", "the laboratory's site (run manifest [site])"),
            (
                "Item",
                f"{run.device.model}, serial {run.device.serial}, "
                f"made by {run.device.manufacturer}",
            ),
            ("Date of receipt", "not recorded"),
            ("Date of calibration", f"{run.started_at:%Y-%m-%d}"),
            ("Date of issue", datetime.now(UTC).date().isoformat()),
            (
                "Method",
                f"procedure {run.procedure} (docs/procedures.md), "
                f"software {run.calibration.software_version}",
            ),
            (
                "Deviations from the method",
                deviations(run.procedure, run.calibration.settings or {}),
            ),
            ("Sampling", "not applicable (one item)"),
            ("External providers", "none: every result was measured by the laboratory"),
        ],
        paragraphs=[ONLY_ITEMS],
    )


def traceability_section(archived: ArchivedRun) -> Section:
    """The reference equipment with its calibration certificates and due dates (7.8.4.1 c)."""
    certificates = {e["serial"]: e for e in (archived.lab or {}).get("equipment", [])}
    started = archived.run.started_at
    rows = []
    for e in archived.run.equipment:
        cert = certificates.get(e.serial, {})
        due = e.calibration_due
        rows.append(
            [
                e.kind,
                e.serial,
                cert.get("certificate") or NOT_RECORDED,
                cert.get("issued_by") or "-",
                "-" if due is None else due.isoformat(),
                "-" if due is None else ("valid" if due >= started.date() else "LAPSED"),
            ]
        )
    if rows:
        chain = (
            "The results are traceable to the SI units through the reference equipment above, "
            "calibrated as its certificates state, and through local gravity (site model as "
            "in the run section)."
        )
    else:
        chain = "No reference equipment recorded: traceability rests on local gravity alone."
    return Section(
        "Metrological traceability (ISO/IEC 17025:2017 7.8.4.1 c)",
        header=["kind", "serial", "calibration certificate", "issued by", "due", "at calibration"],
        rows=rows,
        paragraphs=[chain],
    )


def authorisation_pairs(lab: dict[str, Any] | None) -> list[tuple[str, str]]:
    """Who authorises the certificate (7.8.2.1 o) and the clear end of the certificate."""
    who = _lab(lab, "authorised_by")
    return [
        ("Authorised by", _text(who, "name", "function")),
        ("Signature", "______________________   Date: __________"),
    ]
