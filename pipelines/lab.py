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

Every key is checked; a certificate made without the file says so where the items belong.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from pipelines.tolerances import LAB_FILE_STEM, line_of, profile_dirs

LAB_PROFILE = f"{LAB_FILE_STEM}.toml"
TABLES = {
    "laboratory": ({"name", "address"}, {"accreditation", "country"}),
    "customer": ({"name"}, {"contact", "address"}),
    "authorised_by": ({"name"}, {"function"}),
    "trust": ({"approvers"}, set()),
    "signing": ({"certificate", "key"}, set()),
}
EQUIPMENT_KEYS = ({"serial", "certificate"}, {"issued_by", "kind", "model"})


def load_lab_profile() -> tuple[dict[str, Any], Path] | None:
    """The lab profile and its file, or None when no folder holds one.

    Raises ValueError naming the file, the line of the key and the field of a bad entry.
    """
    for folder in profile_dirs():
        path = folder / LAB_PROFILE
        if path.is_file():
            text = path.read_text(encoding="utf-8")
            try:
                return _checked(tomllib.loads(text), path), path
            except tomllib.TOMLDecodeError as exc:
                raise ValueError(f"lab profile {path}: {exc}") from exc
            except ValueError as exc:  # "lab profile <path>: <field>: <problem>"
                problem = str(exc).removeprefix(f"lab profile {path}: ")
                raise ValueError(f"lab profile {path}{line_of(text, problem)}: {problem}") from None
    return None


def _checked(doc: dict[str, Any], path: Path) -> dict[str, Any]:
    known = {*TABLES, "equipment", "site", "navigation"}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise ValueError(
            f"lab profile {path}: unknown table(s) {unknown}; expected {sorted(known)}"
        )
    if "site" in doc:
        _check_site(doc["site"], path)
    if "navigation" in doc:
        _check_navigation(doc["navigation"], path)
    for table, keys in TABLES.items():
        if table in doc:
            _check_table(doc[table], keys, path, table)
    country = doc.get("laboratory", {}).get("country")
    if country is not None and not (len(country) == 2 and country.isascii() and country.isupper()):
        raise ValueError(
            f"lab profile {path}: laboratory.country: expected an ISO 3166-1 "
            f"alpha-2 code such as 'DE', got {country!r}"
        )
    equipment = doc.get("equipment", [])
    if not isinstance(equipment, list):
        raise ValueError(f"lab profile {path}: equipment: expected an array of tables")
    seen: set[str] = set()
    for i, entry in enumerate(equipment):
        where = f"equipment[{i}]"
        if isinstance(entry, dict) and "precheck" in entry:
            entry = {k: v for k, v in entry.items() if k != "precheck"}
            found = _check_precheck(doc["equipment"][i]["precheck"], path, where)
            twice = sorted(seen & set(found))
            if twice:
                raise ValueError(f"lab profile {path}: {where}.precheck: {twice} given twice")
            seen |= set(found)
        _check_table(entry, EQUIPMENT_KEYS, path, where)
    return doc


def _check_precheck(table: Any, path: Path, where: str) -> dict[str, dict[str, float]]:
    """``[equipment.precheck]``: key (calib_core.conditions.PRECHECK_KEYS) -> {value, limit},
    numbers in the key's unit; the limit is the equipment's own (its data sheet or class)."""
    from calib_core.conditions import PRECHECK_KEYS

    unknown = sorted(set(table) - set(PRECHECK_KEYS)) if isinstance(table, dict) else None
    if unknown is None or unknown:
        raise ValueError(
            f"lab profile {path}: {where}.precheck: expected a table of {list(PRECHECK_KEYS)}"
            + (f", got unknown {unknown}" if unknown else "")
        )
    for key, entry in table.items():
        at = f"lab profile {path}: {where}.precheck.{key}"
        fields = set(entry) if isinstance(entry, dict) else set()
        if "value" not in fields or fields - {"value", "limit"}:
            raise ValueError(f"{at}: expected {{ value = <number>, limit = <number> }}")
        bad = [(k, v) for k, v in entry.items() if isinstance(v, bool) or not _non_negative(v)]
        if bad:
            raise ValueError(f"{at}.{bad[0][0]}: expected a number >= 0, got {bad[0][1]!r}")
    return table


def _non_negative(value: Any) -> bool:
    return isinstance(value, int | float) and value >= 0


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


def _check_table(table: Any, keys: tuple[set[str], set[str]], path: Path, where: str) -> None:
    required, optional = keys
    if not isinstance(table, dict):
        raise ValueError(f"lab profile {path}: {where}: expected a table")
    missing, unknown = sorted(required - set(table)), sorted(set(table) - required - optional)
    if missing or unknown:
        raise ValueError(
            f"lab profile {path}: {where}: missing {missing}, unknown {unknown}; "
            f"expected {sorted(required)} and optionally {sorted(optional)}"
        )
    for key, value in table.items():
        if (
            not isinstance(value, str)
            or not value.strip()
            or len(value) > 200
            or any(ord(ch) < 32 for ch in value)
        ):
            raise ValueError(
                f"lab profile {path}: {where}.{key}: expected one line of text "
                f"(1..200 characters), got {value!r}"
            )


def _check_navigation(table: Any, path: Path) -> None:
    """``[navigation]``: profiles, a list of mission-profile names (that each exists is
    checked where they are read: `pipelines.reports.navigation`)."""
    from storage.naming import check_safe_name

    profiles = table.get("profiles") if isinstance(table, dict) else None
    if set(table) != {"profiles"} or not isinstance(profiles, list) or not profiles:
        raise ValueError(
            f"lab profile {path}: navigation: expected a table with profiles = [names], "
            f"got {table!r}"
        )
    for i, name in enumerate(profiles):
        try:
            check_safe_name(name, "mission profile name")
        except (TypeError, ValueError) as exc:
            raise ValueError(f"lab profile {path}: navigation.profiles[{i}]: {exc}") from None


def lab_navigation_profiles() -> tuple[list[str], Path | None]:
    """The mission profiles the lab's certificates show (``[navigation] profiles``) and the
    lab profile's file."""
    found = load_lab_profile()
    if found is None:
        return [], None
    return list(found[0].get("navigation", {}).get("profiles", [])), found[1]


def _check_site(site: Any, path: Path) -> None:
    """``[site]``: latitude_deg (-90 .. 90) and height_m, numbers."""
    if not isinstance(site, dict) or set(site) != {"latitude_deg", "height_m"}:
        raise ValueError(
            f"lab profile {path}: site: expected a table with latitude_deg and "
            f"height_m, got {site!r}"
        )
    for key, value in site.items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"lab profile {path}: site.{key}: expected a number, got {value!r}")
    if not -90.0 <= site["latitude_deg"] <= 90.0:
        raise ValueError(f"lab profile {path}: site.latitude_deg: expected -90 .. 90 degrees")


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
