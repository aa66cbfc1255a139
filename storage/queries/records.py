"""The typed records of a run's summary (`runs.run_summary`): frozen dataclasses whose
fields are the archive's columns, read by attribute; `to_dict` is their JSON form
(`calib show --json`), fields in declaration order. Checks are calib_core's CheckResult."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from datetime import date, datetime
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy: not for `calib verify`, which reads validation records
    from calib_core.calibration import CheckResult


class Record:
    def to_dict(self) -> dict[str, Any]:
        """The fields (nested records too) as a dict, in order."""
        return asdict(self)  # type: ignore[call-overload]  # subclasses are dataclasses


@dataclass(frozen=True)
class Unit(Record):
    """The unit as its run describes it (the run's own model, manufacturer, specification)."""

    serial: str
    model: str
    manufacturer: str
    specification: str | None


@dataclass(frozen=True)
class EquipmentUse(Record):
    """Equipment a run used, its calibration dates as they were at the run (due: last day)."""

    kind: str
    model: str | None
    serial: str
    accuracy_class: str | None
    calibration_due: date | None
    calibrated_on: date | None


@dataclass(frozen=True)
class ArchivedFile(Record):
    """A raw file of a run (`stored_path` relative to the archive root)."""

    name: str
    sha256: str
    size: int  # bytes
    format: str
    stored_path: str


@dataclass(frozen=True)
class ParameterValue(Record):
    """An archived parameter value (SI; one per temperature when temperature-dependent)."""

    name: str
    value: float
    std: float | None
    unit: str
    temperature_c: float | None


@dataclass(frozen=True)
class Step(Record):
    """A processing step of a revision, in order (`seq`)."""

    seq: int
    name: str
    settings: dict[str, Any]
    statistics: dict[str, Any]
    software_version: str
    source_revision: str | None


@dataclass(frozen=True)
class Revision(Record):
    """A calibration revision: what made and judged it, its parameters, checks (in the
    order written), steps and calibration document (`Calibration.to_dict`)."""

    calibration_id: int
    revision: int
    created_at: datetime
    settings_hash: str
    settings: dict[str, Any] | None
    software_version: str
    source_revision: str | None
    verdict: str
    profile_name: str
    profile_version: str
    superseded_by: int | None  # calibration id of the revision that replaced it
    parameters: list[ParameterValue]
    checks: list[CheckResult]
    steps: list[Step]
    document: dict[str, Any]

    def step(self, name: str) -> Step | None:
        """The step `name`; None when the revision has none (archived before it existed)."""
        return next((s for s in self.steps if s.name == name), None)

    def step_settings(self, name: str) -> dict[str, Any]:
        """The settings of step `name` ({} without it)."""
        return step.settings if (step := self.step(name)) else {}

    def step_statistics(self, name: str) -> dict[str, Any]:
        """The statistics of step `name` ({} without it)."""
        return step.statistics if (step := self.step(name)) else {}

    def budgets(self) -> dict[str, dict[str, Any]]:
        """The GUM budgets by parameter (step "uncertainty"; {} for revisions before it)."""
        return self.step_statistics("uncertainty").get("budgets", {})


@dataclass(frozen=True)
class DatedRevision(Revision):
    """A revision with its run and unit (`latest_calibration`, `calibration_revision`)."""

    run_id: str
    started_at: datetime
    serial: str


@dataclass(frozen=True)
class Validation(Record):
    """A validation record of a revision (`calib validate`, storage.validation)."""

    id: int
    created_at: datetime
    software_version: str
    revision: int
    digest: str
    document: dict[str, Any]


@dataclass(frozen=True)
class RunSummary(Record):
    """Everything about one run and its current calibration revision."""

    run_id: str
    started_at: datetime
    operator: str | None
    procedure: str
    site: dict[str, Any] | None
    gravity: float  # m/s^2
    environment: dict[str, Any] | None
    tolerance_profile: str | None
    raw_hash: str
    run_dir: str
    samples_path: str | None
    manifest_text: str | None
    created_at: datetime
    device: Unit
    equipment: list[EquipmentUse]
    raw_files: list[ArchivedFile]
    revisions: int  # how many the run has
    calibration: Revision  # the current one
    validations: list[Validation]  # of the current revision

    @property
    def temperature_c(self) -> float | None:
        """The run's recorded lab temperature (deg C), None if not recorded."""
        return (self.environment or {}).get("temperature_c")
