"""Tolerance profiles: versioned data files per device type, shipped in pipelines/profiles/.

A lab adds its own profiles in a folder named by the CALIB_PROFILES environment
variable; those take precedence over the shipped ones.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

from calib_core.checks import ToleranceProfile
from storage.naming import check_safe_name

SHIPPED = Path(__file__).resolve().parent / "profiles"


def profile_dirs() -> list[Path]:
    extra = os.environ.get("CALIB_PROFILES")
    return ([Path(extra)] if extra else []) + [SHIPPED]


def load_profile(name: str) -> ToleranceProfile:
    """Load the tolerance profile `name` (file `<name>.toml`).

    Parameters
    ----------
    name : the profile, e.g. "mpu6000"; a lab's folder in env ``CALIB_PROFILES``
        is searched before the shipped profiles (pipelines/profiles/).

    Returns
    -------
    ToleranceProfile (SI units).

    Raises
    ------
    ValueError naming the profile, the folders searched, and for a bad file the
    file and the field.
    """
    check_safe_name(name, "tolerance profile name")
    if f"{name}.toml" == LAB_FILE:
        raise ValueError(f"{LAB_FILE} holds the lab's site, not a tolerance profile")
    for folder in profile_dirs():
        path = folder / f"{name}.toml"
        if path.is_file():
            try:
                doc = tomllib.loads(path.read_text(encoding="utf-8"))
                return ToleranceProfile.from_dict(doc)
            except (tomllib.TOMLDecodeError, ValueError, KeyError, TypeError) as exc:
                raise ValueError(f"tolerance profile {path}: {exc}") from exc
    searched = ", ".join(str(d) for d in profile_dirs())
    raise ValueError(f"tolerance profile {name!r} not found (looked for {name}.toml in {searched})")


LAB_FILE = "lab_site.toml"  # not a tolerance profile: load_profile refuses the name


def load_lab_site() -> tuple[dict[str, float], Path] | None:
    """The lab's site from ``lab_site.toml`` in the profile folders (CALIB_PROFILES first).

    The file holds ``[site] latitude_deg = ..., height_m = ...``: runs whose manifest
    gives no latitude (and every MPU-6000 folder without a manifest) take local gravity
    by Helmert's formula at that site, as the MPU-6000 manual does. None without a file.

    Raises ValueError naming the file and field of a bad entry.
    """
    for folder in profile_dirs():
        path = folder / LAB_FILE
        if not path.is_file():
            continue
        try:
            site = tomllib.loads(path.read_text(encoding="utf-8")).get("site")
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"lab file {path}: {exc}") from exc
        if not isinstance(site, dict) or set(site) - {"latitude_deg", "height_m"}:
            raise ValueError(f"lab file {path}: expected [site] with latitude_deg and height_m")
        for key in ("latitude_deg", "height_m"):
            value = site.get(key)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"lab file {path}: site.{key}: expected a number, got {value!r}")
        if not -90.0 <= site["latitude_deg"] <= 90.0:
            raise ValueError(f"lab file {path}: site.latitude_deg: expected -90 .. 90 degrees")
        return {k: float(site[k]) for k in ("latitude_deg", "height_m")}, path
    return None
