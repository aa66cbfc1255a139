"""What the archive keeps of one processed run (`RunIn`, its `RawFileIn` files), the
identities derived from it (raw hash, run id, settings hash) and its validation before
anything touches the disk (storage.archive writes it).
"""

from __future__ import annotations

import contextlib
import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import date, datetime
from pathlib import Path
from typing import Any

import pyarrow as pa

from calib_core.calibration import CheckResult, Parameter, StepRecord
from calib_core.settings import Setting, SettingError, Settings, typed
from storage import rawstore
from storage.naming import check_safe_name
from storage.settings_hash import canonical_json, settings_hash


@dataclass
class RawFileIn:
    """A raw input file as read by the ingest step."""

    path: Path  # where the bytes are now
    name: str  # original file name, kept in the archive
    sha256: str  # of the bytes, 64 lowercase hex digits
    size: int  # bytes
    format: str  # "mpu6000-txt", "csv", "mat", "mcap", "manifest"...


# A piece of reference equipment a run used (the manifest's [[equipment]] entry): kind and
# serial identify it; its dates are those recorded with the run.
EQUIPMENT = Settings(
    *(Setting(key, "text", "", None, meaning) for key, meaning in {
        "kind": "rate_table, cube, daq... (required)", "serial": "its serial (required)",
        "model": "its model", "accuracy_class": "its accuracy class, e.g. '0.01%'"}.items()),
    Setting("calibration_due", "date", "", None, "when its own calibration is due"),
    Setting("calibrated_on", "date", "", None, "when it was last calibrated"),
    name="EquipmentIn",
    noun="field",
)  # fmt: skip
EquipmentIn = EQUIPMENT.type


def equipment_in(entry: Any, where: str, required: tuple[str, ...] = ()) -> EquipmentIn:
    """`entry` (an EquipmentIn, or a mapping of its keys; dates as dates or ISO text) typed;
    SettingError naming `where` and the key for a refused value or a missing kind, serial
    or other `required` key."""
    if isinstance(entry, Mapping):
        entry = {k: _iso_date(v) if k.startswith("calibra") else v for k, v in entry.items()}
    return typed(EQUIPMENT, entry, where, ("kind", "serial", *required))


def _iso_date(value: Any) -> Any:
    with contextlib.suppress(ValueError, TypeError):  # else refused by name as not a date
        return date.fromisoformat(value)
    return value


# A run's site and lab conditions as the manifest states them ([site], [environment]), SI
# units but for the lab's customary degC, %, hPa and minutes, named in each key.
GRAVITY_MODELS = ("standard", "helmert", "wgs84", "measured")


class SiteRules:
    """What a `Site` says beyond its values: the gravity model in use and its source."""

    @property
    def model(self) -> str:
        """The gravity model in use: as given, else helmert with a latitude, else standard."""
        if self.gravity_model is not None:
            return self.gravity_model
        return "helmert" if self.latitude_deg is not None else "standard"

    def source(self) -> str | None:
        """How local gravity is obtained, for the run's checks; None for the standard value."""
        if self.model == "standard":
            return None
        if self.model == "measured":
            return f"measured {self.gravity} m/s^2"
        where = f" (lab file {self.from_file})" if self.from_file else ""
        return f"{self.model} at latitude {self.latitude_deg} deg, height {self.height_m} m{where}"

    def check(self) -> None:
        """SettingError naming the key a gravity model needs, or a gravity not in m/s^2."""
        if self.gravity_model in ("helmert", "wgs84") and self.latitude_deg is None:
            raise SettingError("latitude_deg", f"gravity_model {self.gravity_model!r} needs "
                               "latitude_deg", "site")  # fmt: skip
        if self.gravity_model == "measured" and self.gravity is None:
            raise SettingError("gravity", "gravity_model 'measured' needs gravity (m/s^2)", "site")
        if self.gravity is not None and not 9.7 < self.gravity < 9.9:
            problem = f"gravity must be in m/s^2 (9.7 .. 9.9), got {self.gravity}"
            raise SettingError("gravity", problem, "site")


SITE = Settings(
    Setting("latitude_deg", "number", "deg", None, "geodetic latitude", low=-90.0, high=90.0),
    Setting("height_m", "number", "m", 0.0, "height above the ellipsoid"),
    # None: Helmert's formula with the height correction when latitude_deg is known (the
    # MPU-6000 manual's choice), else the standard value, which the run's checks warn about.
    Setting("gravity_model", "text", "", None, "how local gravity is obtained",
            choices=GRAVITY_MODELS),
    Setting("gravity", "number", "m/s^2", None, "measured local gravity"),
    Setting("from_file", "text", "", None, "the lab file latitude and height came from"),
    name="Site",
    base=SiteRules,
)  # fmt: skip
ENVIRONMENT = Settings(
    Setting("temperature_c", "number", "degC", None, "lab temperature"),
    Setting("temperature_drift_c_per_h", "number", "degC/h", None, "ambient drift in the run"),
    Setting("humidity_pct", "number", "%", None, "relative humidity", low=0.0, high=100.0),
    Setting("pressure_hpa", "number", "hPa", None, "air pressure", low=0.0, low_open=True),
    Setting("vibration", ("number", "text"), "m/s^2", None, "a level (rms) or a description"),
    Setting("warmup_min", "number", "min", None, "the unit's warm-up before the run", low=0.0),
    name="Environment",
)  # fmt: skip
Site = SITE.type
Environment = ENVIRONMENT.type


@dataclass
class RunIn:
    """Everything the archive keeps about one processed run (SI units): plain data, and the
    parameters, checks and steps as calib_core objects, from which the archive writes its
    rows and the sealed calibration document."""

    serial: str
    device_model: str
    manufacturer: str
    specification: str | None
    started_at: datetime  # time zone aware
    operator: str | None
    procedure: str
    # Site, Environment, EquipmentIn: or mappings of their fields, typed when the RunIn is made
    site: Site
    gravity: float  # m/s^2 used by the solver
    environment: Environment
    equipment: list[EquipmentIn]
    manifest_text: str | None
    tolerance_profile: str | None
    raw_files: list[RawFileIn]
    settings: dict[str, Any]
    software_version: str
    source_revision: str | None
    steps: list[StepRecord]  # in order; the rows of processing_steps
    calibration: dict[str, Any]  # Calibration.to_dict(); its "parameters" come from `parameters`
    parameters: list[Parameter]  # the parameters rows and the document's, in this order
    checks: list[CheckResult]  # the check_results rows
    verdict: str  # "pass", "needs review" or "fail"
    profile_name: str | None
    profile_version: str | None
    samples: pa.Table | rawstore.SamplesFile | None = None  # a SamplesFile: written already
    # The temperature the parameters belong to (deg C; None: not recorded), kept on
    # every parameter row (the run's lab temperature).
    parameter_temperature_c: float | None = None

    def __post_init__(self) -> None:
        self.site = typed(SITE, self.site, "site")
        self.environment = typed(ENVIRONMENT, self.environment, "environment")
        self.equipment = [equipment_in(e, f"equipment[{i}]") for i, e in enumerate(self.equipment)]


def run_row(run: RunIn) -> dict[str, Any]:
    """The values of the run's ``runs`` row that come from the run alone (the archive adds
    identities and paths)."""
    return {
        "started_at": run.started_at,
        "operator": run.operator,
        "procedure": run.procedure,
        "site": run.site.as_dict(),
        "gravity": run.gravity,
        "environment": run.environment.as_dict(),
        "manifest_text": run.manifest_text,
        "tolerance_profile": run.tolerance_profile,
    }


def calibration_document(run: RunIn) -> dict[str, Any]:
    """The stored calibration document: ``run.calibration`` with its parameters from
    ``run.parameters``.

    The archive writes both the ``parameters`` rows and the parameters of the stored
    calibration document from the same `Parameter` objects, so the two cannot disagree
    when written (`storage.verify` reports any later disagreement).
    """
    return {**run.calibration, "parameters": {p.name: p.to_dict() for p in run.parameters}}


# --- identities -------------------------------------------------------------


def raw_hash_of(sha256s: list[str]) -> str:
    """SHA-256 over the sorted file hashes, one per line: order of listing does not matter."""
    return hashlib.sha256("\n".join(sorted(sha256s)).encode()).hexdigest()


def run_id_of(raw_hash: str) -> str:
    """The run id derived from a raw hash ("R" + 12 hex digits = 48 bits)."""
    return "R" + raw_hash[:12]


def settings_hash_of(run: RunIn) -> str:
    """SHA-256 of the canonical JSON of what decides the result besides the raw bytes."""
    return settings_hash(run.settings, run.procedure, run.profile_name, run.profile_version)


# --- validation (before anything touches the disk) ---------------------------


def _number(value: Any, where: str, *, optional: bool) -> float | None:
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def validate(run: RunIn, extra_files: dict[str, bytes]) -> None:
    """Refuse (ValueError, TypeError naming the field) a run the archive cannot keep."""
    check_safe_name(run.serial, "serial")
    for name in extra_files:
        check_safe_name(name, "extra file name")
    if not isinstance(run.started_at, datetime) or run.started_at.utcoffset() is None:
        raise ValueError(f"started_at: expected a time-zone-aware datetime, got {run.started_at!r}")
    if not run.raw_files:
        raise ValueError(f"run of {run.serial}: no raw files")
    names = [f.name for f in run.raw_files]
    if len(set(names)) != len(names):
        raise ValueError(f"raw_files: file names repeat: {sorted(names)}")
    for f in run.raw_files:
        rawstore.object_path(Path("."), f.sha256)  # raises on a malformed hash
        if not isinstance(f.size, int) or f.size < 0:
            raise ValueError(f"raw file {f.name}: size {f.size!r} is not a byte count")
    for key in ("device_model", "manufacturer", "procedure", "software_version", "verdict"):
        if not isinstance(getattr(run, key), str) or not getattr(run, key):
            raise ValueError(f"{key}: expected a non-empty string, got {getattr(run, key)!r}")
    _number(run.gravity, "gravity", optional=False)
    _number(run.parameter_temperature_c, "parameter_temperature_c", optional=True)
    for what, items, kind in (
        ("parameters", run.parameters, Parameter),
        ("steps", run.steps, StepRecord),
        ("checks", run.checks, CheckResult),
    ):
        for i, item in enumerate(items):
            if not isinstance(item, kind):
                raise TypeError(
                    f"{what}[{i}]: expected a {kind.__name__}, got {type(item).__name__}"
                )
            if not isinstance(item.name, str) or not item.name:
                raise ValueError(f"{what}[{i}].name: expected a non-empty string")
    for i, p in enumerate(run.parameters):
        _number(p.value, f"parameters[{i}] ({p.name}).value", optional=False)
        _number(p.std, f"parameters[{i}] ({p.name}).std", optional=True)
    for i, c in enumerate(run.checks):
        _number(c.value, f"checks[{i}] ({c.name}).value", optional=True)
        _number(c.limit, f"checks[{i}] ({c.name}).limit", optional=True)
        if not isinstance(c.passed, bool):
            raise ValueError(f"checks[{i}].passed: expected true or false, got {c.passed!r}")
    for where, value in [
        ("calibration", run.calibration),
        ("steps", [st.to_dict() for st in run.steps]),
    ]:
        canonical_json(value, where)
    if run.samples is not None and not isinstance(run.samples, pa.Table | rawstore.SamplesFile):
        raise TypeError(
            f"samples: expected a pyarrow.Table or a SamplesFile, got {type(run.samples).__name__}"
        )


# --- planning ----------------------------------------------------------------
