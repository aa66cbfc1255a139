"""Tolerance profiles: versioned data files per device type, shipped in pipelines/profiles/.

A lab adds its own profiles in a folder named by the CALIB_PROFILES environment
variable; those take precedence over the shipped ones.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING

from calib_core.settings import refusal
from storage.naming import check_safe_name

if TYPE_CHECKING:  # the science stack is loaded by load_profile, not by profile_dirs' readers
    from calib_core.tolerances import ToleranceProfile

SHIPPED = Path(__file__).resolve().parent / "profiles"
LAB_FILE_STEM = "lab"  # lab.toml beside the profiles is the lab profile (pipelines.lab)


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
    file, the line of the key (as a manifest's errors do) and the field.
    """
    from calib_core.tolerances import ToleranceProfile

    check_safe_name(name, "tolerance profile name")
    if name == LAB_FILE_STEM:
        raise ValueError(
            f"tolerance profile name {name!r} is reserved: {name}.toml in the profile folders "
            "is the lab's own file (pipelines.lab); give the profile another name"
        )
    for folder in profile_dirs():
        path = folder / f"{name}.toml"
        if path.is_file():
            text = path.read_text(encoding="utf-8")
            try:
                return ToleranceProfile.from_dict(tomllib.loads(text))
            except (tomllib.TOMLDecodeError, ValueError, KeyError, TypeError) as exc:
                raise refusal("tolerance profile", path, text, exc) from exc
    searched = ", ".join(str(d) for d in profile_dirs())
    raise ValueError(f"tolerance profile {name!r} not found (looked for {name}.toml in {searched})")
