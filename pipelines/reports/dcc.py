"""The Digital Calibration Certificate (PTB DCC, schema 3.x structure) of one archived run.

`dcc_xml(archived)` builds the document from the archived run the certificate reads
(`pipelines.reports.run_reports.ArchivedRun`: the summary, the lab profile): ``administrativeData``
(dccSoftware, coreData with the certificate number and performance dates, the item with its
manufacturer, model and serial, calibrationLaboratory, respPersons, customer, statements: the
decision rule, the results-relate-only statement and the uncertainty label) and
``measurementResults`` (usedMethods, measuringEquipments, influenceConditions, one result per
parameter as a D-SI ``si:real`` with value, unit and ``si:expandedUnc`` U, k and coverage
probability). Values are SI as archived.

The document is valid against PTB's DCC 3.3.0 schema (the tests validate every DCC they make
against the schema set vendored in tests/schemas). What the schema requires and the archive
cannot know comes from the lab profile or the document is refused naming the field
(`DccRefusedError`): the customer's location (``[customer] address`` of lab.toml) and, for a
run whose manifest lists no equipment, the lab's reference equipment (``[[equipment]]`` of
lab.toml). Each result refers (``refId``) to the method and equipment (``id``) it was
measured with.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING, Any

from calib_core import params
from pipelines.reports import iso17025

if TYPE_CHECKING:
    from pipelines.reports.run_reports import ArchivedRun
    from storage.queries.records import Revision, Unit

DCC_NS = "https://ptb.de/dcc"
SI_NS = "https://ptb.de/si"
SCHEMA_VERSION = "3.3.0"
LANG = "en"
_DECLARATION = "<?xml version='1.0' encoding='utf-8'?>\n"
METHOD_ID = "method"  # the id of the used method, which each result refers to
# D-SI unit of each SI unit string of calib_core.params.UNITS.
D_SI = {
    "m/s^2": r"\metre\second\tothe{-2}",
    "rad/s": r"\radian\second\tothe{-1}",
    "1": r"\one",
    "1/(m/s^2)": r"\metre\tothe{-1}\second\tothe{2}",
    "1/(m/s^2)^2": r"\metre\tothe{-2}\second\tothe{4}",
    "(rad/s)/(m/s^2)": r"\radian\metre\tothe{-1}\second",
}

ET.register_namespace("dcc", DCC_NS)
ET.register_namespace("si", SI_NS)


class DccRefusedError(ValueError):
    """A DCC that would lack an element the schema requires; the message names the field."""


def _el(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    ns, name = tag.split(":")
    el = ET.SubElement(parent, f"{{{DCC_NS if ns == 'dcc' else SI_NS}}}{name}", attrib)
    if text is not None:
        el.text = text
    return el


def _text(parent: ET.Element, tag: str, text: str) -> ET.Element:
    """A DCC text element: <tag><dcc:content lang="en">text</dcc:content></tag>."""
    el = _el(parent, tag)
    _el(el, "dcc:content", text, lang=LANG)
    return el


def dcc_xml(archived: ArchivedRun) -> bytes:
    """The DCC of the run as UTF-8 XML bytes."""
    root = ET.Element(
        f"{{{DCC_NS}}}digitalCalibrationCertificate", {"schemaVersion": SCHEMA_VERSION}
    )
    _administrative(_el(root, "dcc:administrativeData"), archived)
    _results(_el(root, "dcc:measurementResults"), archived)
    ET.indent(root)
    # Serialised as text, then encoded once: ElementTree's own UTF-8 output encodes each
    # piece apart, a third slower; the declaration is the one it writes.
    return (_DECLARATION + ET.tostring(root, encoding="unicode")).encode("utf-8")


def _administrative(admin: ET.Element, archived: ArchivedRun) -> None:
    lab, run = archived.lab or {}, archived.run
    software = _el(_el(admin, "dcc:dccSoftware"), "dcc:software")
    _text(software, "dcc:name", "calib (IMU calibration pipeline)")
    _el(software, "dcc:release", run.calibration.software_version)
    core = _el(admin, "dcc:coreData")
    laboratory = lab.get("laboratory", {})
    _el(core, "dcc:countryCodeISO3166_1", laboratory.get("country", "ZZ"))  # ZZ: not recorded
    _el(core, "dcc:usedLangCodeISO639_1", LANG)
    _el(core, "dcc:mandatoryLangCodeISO639_1", LANG)
    _el(core, "dcc:uniqueIdentifier", iso17025.certificate_number(archived))
    day = f"{run.started_at:%Y-%m-%d}"
    _el(core, "dcc:beginPerformanceDate", day)
    _el(core, "dcc:endPerformanceDate", day)
    _el(core, "dcc:performanceLocation", "laboratory")
    _item(_el(admin, "dcc:items", id="items"), run.device)
    _contact(_el(_el(admin, "dcc:calibrationLaboratory"), "dcc:contact"), laboratory, "address")
    person = _el(_el(admin, "dcc:respPersons"), "dcc:respPerson")
    who = lab.get("authorised_by", {})
    _text(_el(person, "dcc:person"), "dcc:name", who.get("name", iso17025.NOT_RECORDED))
    _el(person, "dcc:role", who.get("function", "authorised by"))
    _contact(_el(admin, "dcc:customer", id="customer"), _customer(lab), "address")
    statements = _el(admin, "dcc:statements")
    for said in _statements(run.calibration):
        _text(_el(statements, "dcc:statement"), "dcc:declaration", said)


def _item(items: ET.Element, device: Unit) -> None:
    item = _el(items, "dcc:item")
    _text(item, "dcc:name", f"IMU {device.model}")
    _text(_el(item, "dcc:manufacturer"), "dcc:name", device.manufacturer)
    _el(item, "dcc:model", device.model)
    ident = _el(_el(item, "dcc:identifications"), "dcc:identification")
    _el(ident, "dcc:issuer", "manufacturer")
    _el(ident, "dcc:value", device.serial)
    _text(ident, "dcc:name", "Serial number")


def _customer(lab: dict[str, Any]) -> dict[str, str]:
    """The customer of the lab profile with its location, which DCC 3.3.0 requires."""
    customer = lab.get("customer", {})
    if not customer.get("address"):
        raise DccRefusedError(
            'DCC 3.3.0 requires the customer\'s location: add address = "..." to [customer] '
            "of the lab profile lab.toml"
            + ("" if lab else " (no lab.toml found in the profile folders, CALIB_PROFILES)")
        )
    return customer


def _contact(contact: ET.Element, entry: dict[str, str], where: str) -> None:
    """The name and location of a DCC contact (the laboratory's, the customer)."""
    _text(contact, "dcc:name", entry.get("name", iso17025.NOT_RECORDED))
    _text(_el(contact, "dcc:location"), "dcc:further", entry.get(where, iso17025.NOT_RECORDED))


def _statements(cal: Revision) -> list[str]:
    rule = cal.step_settings("check").get("decision_rule", "Decision rule: not recorded")
    labels = sorted({b["label"] for b in cal.budgets().values()}) or ["not evaluated"]
    return [
        rule,
        iso17025.ONLY_ITEMS,
        "Uncertainty budget: " + "; ".join(labels),
        f"Overall verdict: {cal.verdict}",
    ]


def _results(results_root: ET.Element, archived: ArchivedRun) -> None:
    run = archived.run
    result = _el(results_root, "dcc:measurementResult")
    _text(result, "dcc:name", "IMU error model parameters")
    method = _el(_el(result, "dcc:usedMethods"), "dcc:usedMethod", id=METHOD_ID)
    _text(method, "dcc:name", f"procedure {run.procedure}")
    equipment = _el(result, "dcc:measuringEquipments")
    ids = [METHOD_ID]
    for i, (name, serial) in enumerate(_equipment(archived), start=1):
        ids.append(f"equipment-{i}")
        eq = _el(equipment, "dcc:measuringEquipment", id=ids[-1])
        _text(eq, "dcc:name", name)
        ident = _el(_el(eq, "dcc:identifications"), "dcc:identification")
        _el(ident, "dcc:issuer", "manufacturer")
        _el(ident, "dcc:value", serial)
        _text(ident, "dcc:name", "Serial number")
    if (temperature := run.temperature_c) is not None:
        cond = _el(_el(result, "dcc:influenceConditions"), "dcc:influenceCondition")
        _text(cond, "dcc:name", "Ambient temperature")
        quantity = _el(_el(cond, "dcc:data"), "dcc:quantity")
        _real(quantity, float(temperature) + 273.15, r"\kelvin")
    _parameters(_el(result, "dcc:results"), run.calibration, " ".join(ids))


def _equipment(archived: ArchivedRun) -> list[tuple[str, str]]:
    """(name, serial) of the run's equipment, else of the lab profile's references: the
    schema requires at least one measuring equipment."""
    if archived.run.equipment:
        return [(f"{e.kind} {e.model or ''}".strip(), e.serial) for e in archived.run.equipment]
    listed = (archived.lab or {}).get("equipment", [])
    if not listed:
        raise DccRefusedError(
            "DCC 3.3.0 requires at least one measuring equipment: the run's manifest lists "
            "none ([[equipment]] of run.toml) and the lab profile lab.toml has no [[equipment]]"
        )
    said = " (the lab's reference from lab.toml: the run's manifest lists no equipment)"
    return [
        (f"{e.get('kind', 'reference')} {e.get('model') or ''}".strip() + said, e["serial"])
        for e in listed
    ]


def _parameters(results: ET.Element, cal: Revision, used: str) -> None:
    budgets = cal.budgets()
    for p in cal.parameters:
        res = _el(results, "dcc:result", id=f"result-{p.name}", refId=used)
        _text(res, "dcc:name", p.name)
        quantity = _el(_el(res, "dcc:data"), "dcc:quantity")
        _text(quantity, "dcc:name", p.name)
        _real(quantity, p.value, D_SI[params.unit_of(p.name)], budgets.get(p.name))


def _real(parent: ET.Element, value: float, unit: str, budget: dict | None = None) -> None:
    real = _el(parent, "si:real")
    _el(real, "si:value", repr(float(value)))
    _el(real, "si:unit", unit)
    if budget is not None:
        unc = _el(real, "si:expandedUnc")
        _el(unc, "si:uncertainty", repr(float(budget["U"])))
        _el(unc, "si:coverageFactor", repr(float(budget["k"])))
        _el(unc, "si:coverageProbability", repr(float(budget["coverage"])))


def write_dcc(archived: ArchivedRun, folder: Path) -> Path:
    """Write `<serial>_<run>_dcc.xml` into `folder`; returns its path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{archived.run.device.serial}_{archived.run.run_id}_dcc.xml"
    path.write_bytes(dcc_xml(archived))
    return path
