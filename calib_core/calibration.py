"""Calibration results: typed, JSON round-trippable, applicable to data.

A `Calibration` is a set of canonical parameters (value, standard uncertainty,
unit) plus what is needed to judge it (residuals per segment, warnings). The
error model is the archive's matrix convention:

    f_meas = (I + M_a) f_true + b_a
    w_meas = (I + M_g) w_true + G f_true + b_g

`Calibration.apply` inverts it; parameters that are absent count as zero.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from calib_core import __version__, params
from calib_core.recording import Recording

JSON_SCHEMA_VERSION = 1


@dataclass(frozen=True)
class Parameter:
    """One estimated parameter: the one form solvers return, reports show and the archive keeps.

    Attributes
    ----------
    name : canonical name (`calib_core.params`), e.g. ``gyr.scale.x``.
    value : estimate in the SI unit `unit`.
    std : standard uncertainty (1 sigma) in `unit`, or None where the solver gives none.
    unit : SI unit; filled from the name when empty.
    cov_index : row/column of this parameter in its calibration's `covariance`,
        or None when the solver gives only the standard uncertainty.
    """

    name: str
    value: float
    std: float | None = None
    unit: str = ""
    cov_index: int | None = None

    def __post_init__(self) -> None:
        params.validate(self.name)
        if not self.unit:
            object.__setattr__(self, "unit", params.unit_of(self.name))
        if not math.isfinite(self.value):
            raise ValueError(f"parameter {self.name}: value is not finite ({self.value})")

    def to_dict(self) -> dict[str, Any]:
        """The document form ``{"value", "std", "unit"}`` (+ ``cov_index`` when set)."""
        doc: dict[str, Any] = {"value": self.value, "std": self.std, "unit": self.unit}
        if self.cov_index is not None:
            doc["cov_index"] = self.cov_index
        return doc

    @classmethod
    def from_dict(cls, name: str, doc: dict[str, Any]) -> Parameter:
        """Inverse of `to_dict`."""
        return cls(name, doc["value"], doc.get("std"), doc.get("unit", ""), doc.get("cov_index"))

    def to_row(self, temperature_c: float | None = None) -> dict[str, Any]:
        """The archive's row form: ``name`` + `to_dict` + the run's ``temperature_c`` (degC)."""
        return {"name": self.name, **self.to_dict(), "temperature_c": temperature_c}

    @classmethod
    def from_row(cls, row: dict[str, Any]) -> Parameter:
        """Inverse of `to_row` (``temperature_c`` belongs to the run, not the parameter)."""
        return cls.from_dict(row["name"], row)


def _fields_dict(record: Any) -> dict[str, Any]:
    """A dataclass's fields by name, the values as they are (no deep copy)."""
    return {f.name: getattr(record, f.name) for f in dataclasses.fields(record)}


@dataclass(frozen=True)
class SegmentResidual:
    """Residual statistics (measured - model) of one segment for one sensor.

    mean, std : (3,) per axis, in the sensor's SI unit.
    """

    segment: str
    sensor: str  # "acc" or "gyr"
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    n: int

    def to_dict(self) -> dict[str, Any]:
        """The fields as a dict (`dataclasses.asdict` without its deep copy)."""
        return _fields_dict(self)


# Statistics of a step that are wall times of this execution (s), not results of the
# run's bytes and settings: a run solved again differs only there (pipelines.recompute).
WALL_TIMES = frozenset({"seconds", "preprocess_seconds"})


@dataclass(frozen=True)
class StepRecord:
    """What one pipeline step did: archived so every number can be traced."""

    name: str
    settings: dict[str, Any] = field(default_factory=dict)
    statistics: dict[str, Any] = field(default_factory=dict)
    software_version: str = __version__

    def to_dict(self) -> dict[str, Any]:
        """The fields as a dict (`dataclasses.asdict` without its deep copy).

        `settings` and `statistics` (which can hold long lists, e.g. the indices of
        flagged samples) are the record's own dicts, not copies.
        """
        return _fields_dict(self)


@dataclass(frozen=True)
class CheckResult:
    """One check against a limit.

    Attributes
    ----------
    name : e.g. ``param:acc.bias.x``, ``residual:x_up:acc:std``.
    value : the checked value (SI), or None.
    limit : the limit (SI), or None for checks without a number.
    passed : the outcome.
    detail : the allowed range or the reason, for people.
    """

    name: str
    value: float | None
    limit: float | None
    passed: bool
    detail: str = ""

    def to_dict(self) -> dict[str, Any]:
        """The fields as a dict (`dataclasses.asdict` without its deep copy)."""
        return _fields_dict(self)

    @classmethod
    def at_most(cls, name: str, value: float, limit: float, detail: str = "") -> CheckResult:
        """A check that passes when ``value <= limit``."""
        return cls(name, value, limit, bool(value <= limit), detail)


@dataclass
class Calibration:
    """A solved calibration of one IMU (accelerometer and/or gyro triad).

    Attributes
    ----------
    procedure : the procedure that solved it (`calib_core.procedures.PROCEDURES`).
    gravity : local gravity used for the reference specific force, m/s^2.
    parameters : canonical name -> Parameter (value, std, unit; SI).
    residuals : SegmentResidual per segment and sensor.
    warnings : what the solver found doubtful.
    info : solver facts (condition number, turns, sample counts, ...).
    covariance : (P, P) covariance of the parameters with a ``cov_index``, SI.

    The error model is ``f_meas = (I + M_a) f_true + b_a``, ``w_meas = (I + M_g)
    w_true + G f_true + b_g``; `correct` and `apply` invert it.
    """

    procedure: str
    gravity: float  # m/s^2 used for the reference specific force
    parameters: dict[str, Parameter] = field(default_factory=dict)
    residuals: list[SegmentResidual] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)  # solver facts: condition number, turns...
    # (P, P) covariance of the parameters that have a cov_index (SI units); blocks of
    # separate fits are uncorrelated.
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    # --- building -------------------------------------------------------
    def add(self, name: str, value: float, std: float | None = None) -> None:
        self.parameters[name] = Parameter(name, float(value), None if std is None else float(std))

    def add_fit(self, names: list[str], values: dict[str, float], cov: np.ndarray) -> None:
        """Parameters of one least-squares fit with their (len(names), len(names)) covariance.

        Standard uncertainties are the square roots of the diagonal; the block is
        appended to `covariance` (uncorrelated with earlier fits). ValueError for a
        variance that is negative or not finite, naming the parameter.
        """
        cov = np.asarray(cov, dtype=float)
        var = np.diagonal(cov)
        bad = ~(np.isfinite(var) & (var >= 0))
        if bad.any():  # refused before the square root, which would make it NaN
            i = int(np.argmax(bad))
            raise ValueError(
                f"{names[i]}: the fit gives it the variance {var[i]:.3g}, not a finite "
                "number >= 0: its uncertainty is undefined (the inputs' uncertainties span "
                "more than the fit resolves, or one is zero)"
            )
        start = len(self.covariance)
        grown = np.zeros((start + len(names),) * 2)
        grown[:start, :start] = self.covariance
        grown[start:, start:] = cov
        self.covariance = grown
        for i, name in enumerate(names):
            std = float(np.sqrt(cov[i, i]))
            self.parameters[name] = Parameter(name, float(values[name]), std, cov_index=start + i)

    def merged(self, other: Calibration) -> Calibration:
        """This calibration with `other`'s parameters, residuals and warnings added."""
        shift = len(self.covariance)
        theirs = {
            n: p if p.cov_index is None else replace(p, cov_index=p.cov_index + shift)
            for n, p in other.parameters.items()
        }
        covariance = np.zeros((shift + len(other.covariance),) * 2)
        covariance[:shift, :shift] = self.covariance
        covariance[shift:, shift:] = other.covariance
        return replace(
            self,
            covariance=covariance,
            parameters={**self.parameters, **theirs},
            residuals=[*self.residuals, *other.residuals],
            warnings=[*self.warnings, *other.warnings],
            info=_merged_info(self.info, other.info),
        )

    # --- reading --------------------------------------------------------
    def value(self, name: str, default: float = 0.0) -> float:
        p = self.parameters.get(name)
        return default if p is None else p.value

    def vector(self, sensor: str, kind: str) -> np.ndarray:
        """(3,) vector of e.g. ("acc", "bias"); absent entries are 0."""
        return np.array([self.value(f"{sensor}.{kind}.{a}") for a in params.AXES])

    def matrix(self, sensor: str) -> np.ndarray:
        """(3, 3) M of the sensor (scale errors on the diagonal); absent entries are 0."""
        return np.array([[self.value(n) for n in row] for row in params.matrix_names(sensor)])

    def gsens(self) -> np.ndarray:
        """(3, 3) G, (rad/s)/(m/s^2); absent entries are 0."""
        return np.array([[self.value(n) for n in row] for row in params.gsens_names()])

    # --- applying -------------------------------------------------------
    def correct(self, acc: np.ndarray, gyr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Invert the error model.

        Parameters
        ----------
        acc : (N, 3) measured specific force, m/s^2.
        gyr : (N, 3) measured angular rate, rad/s.

        Returns
        -------
        (acc_true, gyr_true), each (N, 3).
        """
        acc_true = np.linalg.solve(
            np.eye(3) + self.matrix("acc"), (np.asarray(acc) - self.vector("acc", "bias")).T
        ).T
        gyr_rhs = np.asarray(gyr) - self.vector("gyr", "bias") - acc_true @ self.gsens().T
        gyr_true = np.linalg.solve(np.eye(3) + self.matrix("gyr"), gyr_rhs.T).T
        return acc_true, gyr_true

    def apply(self, recording: Recording) -> Recording:
        """The recording with calibrated acc and gyr."""
        acc, gyr = self.correct(recording.acc, recording.gyr)
        return replace(recording, acc=acc, gyr=gyr)

    # --- JSON -------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "schema_version": JSON_SCHEMA_VERSION,
            "software_version": __version__,
            "procedure": self.procedure,
            "gravity": self.gravity,
            "parameters": {n: p.to_dict() for n, p in sorted(self.parameters.items())},
            **({"covariance": self.covariance.tolist()} if self.covariance.size else {}),
            "residuals": [r.to_dict() for r in self.residuals],
            "warnings": list(self.warnings),
            "info": self.info,
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Calibration:
        version = doc.get("schema_version")
        if version != JSON_SCHEMA_VERSION:
            raise ValueError(
                f"calibration JSON schema_version {version!r} is not supported "
                f"(this software reads {JSON_SCHEMA_VERSION})"
            )
        cal = cls(procedure=doc["procedure"], gravity=float(doc["gravity"]))
        for name, p in doc["parameters"].items():
            cal.parameters[name] = Parameter.from_dict(name, p)
        if "covariance" in doc:
            cal.covariance = np.asarray(doc["covariance"], dtype=float)
        cal.residuals = [
            SegmentResidual(r["segment"], r["sensor"], tuple(r["mean"]), tuple(r["std"]), r["n"])
            for r in doc.get("residuals", [])
        ]
        cal.warnings = list(doc.get("warnings", []))
        cal.info = dict(doc.get("info", {}))
        return cal


def _merged_info(mine: dict[str, Any], theirs: dict[str, Any]) -> dict[str, Any]:
    """`theirs` on top of `mine`, except the checks and altered-sample counts both made:
    "solver_checks" lists are joined, "replaced_samples" tables (step -> ...) united."""
    out = {**mine, **theirs}
    if "solver_checks" in mine and "solver_checks" in theirs:
        out["solver_checks"] = [*mine["solver_checks"], *theirs["solver_checks"]]
    if "replaced_samples" in mine and "replaced_samples" in theirs:
        out["replaced_samples"] = {**mine["replaced_samples"], **theirs["replaced_samples"]}
    return out
