"""The lab profile: what a certificate states that the archive cannot know (ISO/IEC 17025 7.8).

``lab.toml`` in the profile folders (``CALIB_PROFILES`` first, pipelines.tolerances) holds the
laboratory's name and address, the customer, who authorises certificates and the calibration
certificates of the reference equipment (traceability, 7.8.4.1 c)::

    [laboratory]
    name = "IMU Lab GmbH"
    address = "Musterstrasse 1, 80331 Muenchen, Germany"
    accreditation = "D-K-12345-01-00"          # optional
    country = "DE"                             # optional, ISO 3166-1 (the DCC's coreData)

    [customer]
    name = "Example Drones AG"
    contact = "qa@example.com"
    address = "Hangar 3, 12345 Somewhere"     # the DCC's customer location (DCC 3.3.0 needs it)

    [authorised_by]
    name = "Dr. A. Metrologist"
    function = "Head of calibration laboratory"

    [[equipment]]                             # one per reference, by its serial
    serial = "CUBE-7"
    certificate = "DAkkS 4711-2026"
    issued_by = "PTB"
    kind = "cube"                             # optional: the DCC lists the lab's references
    model = "Precision cube PC-100"           # when a run's manifest records no equipment

    [[equipment]]                             # the rate table, with its pre-check before runs
    serial = "RT-2"
    certificate = "DAkkS 4712-2026"
    [equipment.precheck]                      # measured value and the equipment's limit
    table_angle_accuracy_arcsec = { value = 1.5, limit = 3.0 }
    table_axis_perpendicularity_arcsec = { value = 2.0, limit = 5.0 }

    [site]                                    # local gravity by Helmert (the MPU-6000 manual)
    latitude_deg = 48.137                     # for runs whose manifest gives no site
    height_m = 519.0

    [trust]                                   # the approvers the lab trusts (pipelines.trust)
    approvers = "approvers"                   # a file of calib keygen .pub lines, beside lab.toml

    [signing]                                 # signed DCC / PDF (pipelines.reports.signing)
    certificate = "lab-cert.pem"              # the lab's X.509 certificate, beside lab.toml
    key = "lab-key.pem"                       # its private key: read to sign, never archived

    [navigation]                              # the certificate's "Navigation performance"
    profiles = ["land-vehicle-outage-60s"]    # mission profiles by name (docs/navigation.md)

Each table is declared with `calib_core.settings` (LABORATORY, CUSTOMER, AUTHORISED_BY,
EQUIPMENT with its pre-check, SITE, TRUST, SIGNING, NAVIGATION: `TABLES`), as a manifest's
and a tolerance profile's are, and refused alike: the file, the line of the key, the dotted
key, what was expected and what was found. A certificate made without the file says so
where the items belong.
"""

from __future__ import annotations

import functools
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from calib_core.settings import Setting, SettingError, Settings, refusal, typed
from pipelines.tolerances import LAB_FILE_STEM, profile_dirs
from storage.naming import check_safe_name, is_one_line

LAB_PROFILE = f"{LAB_FILE_STEM}.toml"
TEXT_MAX_CHARS = 200  # each text of the lab profile: one line, as a certificate prints it


def _texts(**meanings: str) -> tuple[Setting, ...]:
    return tuple(Setting(key, "text", "", None, meaning) for key, meaning in meanings.items())


def _text_table(type_name: str, /, **meanings: str) -> Settings:
    """A table of one-line texts, its values' type named `type_name`."""
    return Settings(*_texts(**meanings), name=type_name, noun="field")


# Each table of lab.toml (its keys' meanings are the documentation above).
LABORATORY = _text_table(
    "Laboratory",
    name="the laboratory's name",
    address="its address",
    accreditation="its accreditation",
    country="ISO 3166-1 alpha-2 code, e.g. 'DE' (the DCC's coreData)",
)
CUSTOMER = _text_table(
    "Customer", name="the customer's name", contact="how to reach it", address="its location"
)
AUTHORISED_BY = _text_table(
    "AuthorisedBy", name="who authorises certificates", function="their function"
)
TRUST = _text_table(
    "Trust", approvers="the approvers file (calib keygen .pub lines), beside lab.toml"
)
SIGNING = _text_table(
    "Signing",
    certificate="the lab's X.509 certificate (PEM), beside lab.toml",
    key="its private key (PEM): read to sign, never archived",
)
SITE = Settings(
    Setting("latitude_deg", "number", "deg", None, "geodetic latitude", low=-90.0, high=90.0),
    Setting("height_m", "number", "m", None, "height above the ellipsoid"),
    name="LabSite",
    noun="field",
)
NAVIGATION = Settings(
    Setting("profiles", "list", "", None, "mission profiles by name (docs/navigation.md)"),
    name="Navigation",
    noun="field",
)
EQUIPMENT = Settings(
    *_texts(
        serial="the reference's serial",
        certificate="its calibration certificate",
        issued_by="who issued it",
        kind="cube, rate_table, ... (the DCC's lab references)",
        model="its model",
    ),
    Setting("precheck", "table", "", None, "`precheck_table`: measured before runs"),
    name="LabEquipment",
    noun="field",
)
# One pre-check item: the value measured and the equipment's own limit, in the key's unit.
READING = Settings(
    Setting("value", "number", "", None, "measured", low=0.0),
    Setting("limit", "number", "", None, "the equipment's (its data sheet or class)", low=0.0),
    name="Reading",
    noun="field",
)
# Each table: its declaration and the keys it must give.
TABLES: dict[str, tuple[Settings, tuple[str, ...]]] = {
    "laboratory": (LABORATORY, ("name", "address")),
    "customer": (CUSTOMER, ("name",)),
    "authorised_by": (AUTHORISED_BY, ("name",)),
    "site": (SITE, ("latitude_deg", "height_m")),
    "trust": (TRUST, ("approvers",)),
    "signing": (SIGNING, ("certificate", "key")),
    "navigation": (NAVIGATION, ("profiles",)),
}
LAB = Settings(
    *(Setting(k, "table", "", None, f"[{k}]") for k in TABLES),
    Setting("equipment", "list", "", None, "[[equipment]]: EQUIPMENT, one per reference"),
    name="LabProfile",
    noun="table",
)


@functools.cache
def precheck_table() -> Settings:
    """``[equipment.precheck]``: calib_core.conditions.PRECHECK_KEYS, each a `READING`
    (declared when first read: the conditions load the science stack)."""
    from calib_core.conditions import PRECHECK_KEYS

    items = (Setting(k, "table", "", None, "READING: { value, limit }") for k in PRECHECK_KEYS)
    return Settings(*items, name="Precheck", noun="pre-check item")


def load_lab_profile() -> tuple[dict[str, Any], Path] | None:
    """The lab profile (its tables as written, each checked) and its file, or None when no
    folder holds one.

    Raises ValueError naming the file, the line of the key, the key, what was expected and
    what was found.
    """
    for folder in profile_dirs():
        path = folder / LAB_PROFILE
        if path.is_file():
            text = path.read_text(encoding="utf-8")
            try:
                return checked(tomllib.loads(text)), path
            except tomllib.TOMLDecodeError as exc:
                raise ValueError(f"lab profile {path}: {exc}") from exc
            except SettingError as exc:
                raise refusal("lab profile", path, text, exc) from None
    return None


def checked(doc: dict[str, Any]) -> dict[str, Any]:
    """`doc`, a lab profile's TOML tables, checked against their declarations (`TABLES`,
    `EQUIPMENT`); SettingError naming the dotted key."""
    typed(LAB, doc, "")
    for name, value in doc.items():
        if name in TABLES:
            table, required = TABLES[name]
            _table(table, value, name, required)
    country = doc.get("laboratory", {}).get("country")
    if country is not None and not (len(country) == 2 and country.isascii() and country.isupper()):
        problem = f"expected an ISO 3166-1 alpha-2 code such as 'DE', got {country!r}"
        raise SettingError("country", problem, "laboratory")
    profiles = doc.get("navigation", {}).get("profiles")
    if profiles == []:
        problem = "expected a list of mission profile names, got []"
        raise SettingError("profiles", problem, "navigation")
    for i, name in enumerate(profiles or []):
        try:
            check_safe_name(name, "mission profile name")
        except ValueError as exc:
            raise SettingError(f"profiles[{i}]", str(exc), "navigation") from None
    seen: dict[str, str] = {}  # pre-check key -> the entry that gave it
    for i, entry in enumerate(doc.get("equipment", [])):
        _equipment(entry, f"equipment[{i}]", seen)
    return doc


def _table(table: Settings, given: Any, root: str, required: tuple[str, ...] = ()) -> Any:
    """`given` typed by `table` (calib_core.settings.typed); each text as written one line
    of 1 .. TEXT_MAX_CHARS characters (SettingError naming ``root.key``)."""
    for key, value in given.items() if isinstance(given, Mapping) else ():
        if key in table and isinstance(value, str) and not is_one_line(value, TEXT_MAX_CHARS):
            problem = f"expected one line of text (1..{TEXT_MAX_CHARS} characters), got {value!r}"
            raise SettingError(key, problem, root)
    return typed(table, given, root, required)


def _equipment(entry: Any, where: str, seen: dict[str, str]) -> None:
    """One ``[[equipment]]`` entry (`EQUIPMENT`) and its pre-check, each pre-check key given
    by one entry only."""
    item = _table(EQUIPMENT, entry, where, ("serial", "certificate"))
    if item.precheck is None:
        return
    _table(precheck_table(), item.precheck, f"{where}.precheck")
    for key, reading in item.precheck.items():
        _table(READING, reading, f"{where}.precheck.{key}", ("value",))
        if key in seen:
            problem = f"given twice: also in {seen[key]}.precheck"
            raise SettingError(f"precheck.{key}", problem, where)
        seen[key] = where


def lab_precheck() -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """The equipment pre-check of the lab profile's ``[equipment.precheck]`` tables:
    (key -> value measured, key -> {"high": the equipment's limit}), as
    `calib_core.conditions.check_conditions` takes `recorded` and `overrides`; empty
    without a lab file or pre-check (each condition is then "not recorded")."""
    found = load_lab_profile()
    values: dict[str, float] = {}
    limits: dict[str, dict[str, float]] = {}
    for entry in [] if found is None else found[0].get("equipment", []):
        for key, item in entry.get("precheck", {}).items():
            values[key] = float(item["value"])
            if "limit" in item:
                limits[key] = {"high": float(item["limit"])}
    return values, limits


def lab_navigation_profiles() -> tuple[list[str], Path | None]:
    """The mission profiles the lab's certificates show (``[navigation] profiles``) and the
    lab profile's file."""
    found = load_lab_profile()
    if found is None:
        return [], None
    return list(found[0].get("navigation", {}).get("profiles", [])), found[1]


def lab_site() -> tuple[dict[str, float], Path] | None:
    """The lab's site (latitude_deg, height_m) from the lab profile's ``[site]`` and the
    file, or None: runs whose manifest gives no site take local gravity by Helmert's
    formula there, as the MPU-6000 manual does (pipelines.ingest.run_loader.with_lab_site).
    """
    found = load_lab_profile()
    if found is None or "site" not in found[0]:
        return None
    doc, path = found
    return {k: float(doc["site"][k]) for k in ("latitude_deg", "height_m")}, path


def customer_name() -> str | None:
    """The customer of the lab profile, the one place it is recorded; None without a lab
    profile. A bad lab profile raises ValueError naming its file and field (never read as
    "not recorded")."""
    found = load_lab_profile()
    return None if found is None else found[0].get("customer", {}).get("name")
