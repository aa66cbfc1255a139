"""Lab conditions, the catalogue: each condition's limits, severity, wording, the quantity it
judges and the document it comes from; one value judged; the status of an archived check.

Which conditions apply to a run is its procedure's declaration (`calib_core.procedures`); how
each is measured on a run's data is `calib_core.conditions`. A check is named
``condition:<key>``; its value is in the unit the key names (deg C, %, hPa, min, Hz, bit, s,
deg/s), not SI, so the line reads as the procedure writes it.

Severity, from the procedure's wording:

- warning (the verdict stands, the line says WARNING): the environment, which docs/methods.md 3.10
  asks to be *recorded* with each run with *targets* (ambient 20 +- 2 deg C, drift
  <= 0.5 deg C/h, humidity 40-60 %, pressure, warm-up time), and local gravity by the
  standard value instead of the site's (the MPU-6000 manual computes it by Helmert).
- failure (the run fails): the acquisition rules the numbers rest on, written as
  requirements: "settle >= 20 s then record >= 10 s at >= 100 Hz" (rate points),
  ">= 30 s settle for positions", the resolution, the chamber's temperature spread during
  a static-bias run, and the table's rate from its feedback channel (stability and
  deviation per plateau): a wrong reference rate is a wrong scale factor.
- info (never fails): a quantity recorded for every run because it is useful elsewhere,
  such as the sensor's own temperature trend (the thermal model), judged by no rule.

A condition the run does not record is "not recorded": not a pass (``passed`` false) and
not a failure (the verdict stands); the line says so.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from calib_core.calibration import CheckResult
from calib_core.settings import Setting, SettingError, Settings

CONDITION_PREFIX = "condition:"
NOT_RECORDED = "not recorded"
# A check the run alone cannot judge (the unit's description needs the archive's earlier
# runs): listed, so every view of a run counts the same checks, never counted as a failure.
NOT_JUDGED = "not judged"
WARNING, FAILURE, INFO = "warning", "failure", "info"


@dataclass(frozen=True)
class Condition:
    """One condition: its limits (inclusive, in the key's unit), severity and wording."""

    key: str
    low: float
    high: float
    severity: str
    text: str  # what the line says is checked
    unit: str

    def allowed(self) -> str:
        """The requirement as the line prints it: '18 .. 22 deg C', '>= 100 Hz', 'recorded'."""
        lo, hi = math.isfinite(self.low), math.isfinite(self.high)
        if lo and hi:
            return f"{self.low:g} .. {self.high:g} {self.unit}"
        if lo or hi:
            return f"{'>=' if lo else '<='} {self.low if lo else self.high:g} {self.unit}"
        return "to be recorded"


_INF = math.inf
# key: (low, high, severity, text, unit); docs/methods.md 2.4, 2.5 and 3.10.
DEFAULT_CONDITIONS: dict[str, tuple[float, float, str, str, str]] = {
    "ambient_temperature_c": (18.0, 22.0, WARNING, "ambient temperature", "deg C"),
    "temperature_drift_c_per_h": (-_INF, 0.5, WARNING, "ambient temperature drift", "deg C/h"),
    "humidity_pct": (40.0, 60.0, WARNING, "relative humidity", "%"),
    "pressure_hpa": (-_INF, _INF, WARNING, "air pressure", "hPa"),
    "warmup_min": (10.0, _INF, WARNING, "warm-up time", "min"),
    "gravity": (-_INF, _INF, WARNING, "local gravity from the site", "m/s^2"),
    "sample_rate_hz": (100.0, _INF, FAILURE, "sampling rate (slowest segment)", "Hz"),
    "resolution_bits": (16.0, _INF, FAILURE, "sensor resolution", "bit"),
    "settle_s": (30.0, _INF, FAILURE, "settle time before each attitude", "s"),
    "settle_rate_s": (20.0, _INF, FAILURE, "settle time of each rate plateau", "s"),
    "record_s": (10.0, _INF, FAILURE, "record time per attitude (shortest)", "s"),
    "static_record_min": (60.0, _INF, FAILURE, "static-bias record", "min"),
    "static_temperature_spread_c": (
        -_INF, 0.2, FAILURE, "chamber temperature spread over the static-bias record", "deg C"),
    "sensor_temperature_spread_c": (
        -_INF, _INF, INFO, "sensor temperature spread over the run (for the thermal model)",
        "deg C"),
    "table_rate_stability_dps": (
        -_INF, 0.1, FAILURE, "table rate stability (feedback std, worst plateau)", "deg/s"),
    "table_rate_deviation_dps": (
        -_INF, 0.5, FAILURE, "table rate deviation from nominal (worst plateau)", "deg/s"),
    "zero_position_min": (
        3.0, _INF, WARNING, "centrifuge zero output per table position (shortest)", "min"),
    "g_step_min": (5.0, _INF, WARNING, "centrifuge g step record (shortest)", "min"),
    # The rate-table procedure's equipment pre-check: the limit is the equipment record's
    # (lab.toml) unless the profile sets one; unbounded, it is to be recorded.
    "table_angle_accuracy_arcsec": (
        -_INF, _INF, FAILURE, "rate table angle accuracy (equipment pre-check)", "arcsec"),
    "table_axis_perpendicularity_arcsec": (
        -_INF, _INF, FAILURE, "rate table axis perpendicularity (equipment pre-check)",
        "arcsec"),
    "power_stability_pct": (
        -_INF, _INF, FAILURE, "power supply stability (equipment pre-check)", "%"),
    "imu_table_parallelism_arcsec": (
        -_INF, _INF, FAILURE, "IMU-to-table axis parallelism (equipment pre-check)", "arcsec"),
    "table_position_arcsec": (
        -_INF, 5.0, FAILURE, "table position deviation while held (feedback, worst segment)",
        "arcsec"),
}  # fmt: skip
# A profile's [conditions]: each key's table of limits in the key's unit.
CONDITIONS = Settings(
    *(Setting(k, "table", v[4], None, v[3]) for k, v in DEFAULT_CONDITIONS.items()),
    noun="condition",
)
BOUNDS = Settings(
    Setting("low", "number", "", None, "lowest value allowed"),
    Setting("high", "number", "", None, "highest value allowed"),
    noun="field",
)


@dataclass(frozen=True)
class ConditionUse:
    """A condition as a procedure applies it: the key (`DEFAULT_CONDITIONS`), the quantity it
    judges in that procedure and the document the rule comes from."""

    key: str
    quantity: str
    source: str

    def __post_init__(self) -> None:
        if self.key not in DEFAULT_CONDITIONS:
            raise ValueError(f"condition {self.key!r}: not in {sorted(DEFAULT_CONDITIONS)}")


def conditions(overrides: Mapping[str, Mapping[str, float]] | None = None) -> dict[str, Condition]:
    """The conditions with a profile's ``[conditions]`` limits (``{low, high}``) applied."""
    out = {}
    for key, (low, high, severity, text, unit) in DEFAULT_CONDITIONS.items():
        given = (overrides or {}).get(key, {})
        out[key] = Condition(
            key, float(given.get("low", low)), float(given.get("high", high)), severity, text, unit
        )
    return out


def parse_conditions(raw: Mapping[str, Any]) -> dict[str, dict[str, float]]:
    """Validate a profile's ``[conditions]`` table: key -> {low, high} numbers.

    Raises SettingError naming ``conditions.<key>`` and what was expected.
    """
    CONDITIONS.validate(raw, "conditions", root="")
    out: dict[str, dict[str, float]] = {}
    for key, entry in raw.items():
        where = f"conditions.{key}"
        BOUNDS.validate(entry, where, root="")
        if not entry:
            raise SettingError(where, "expected a table { low = <number>, high = <number> }", "")
        if entry.get("low", -_INF) > entry.get("high", _INF):
            raise SettingError(where, f"low ({entry['low']}) is above high ({entry['high']})", "")
        out[key] = {k: float(v) for k, v in entry.items()}
    return out


def judge(cond: Condition, value: float | None, note: str = "") -> CheckResult:
    """One condition's check: ``value`` None is "not recorded"."""
    finite = [v for v in (cond.high, cond.low) if math.isfinite(v)]
    limit = finite[0] if finite else None
    if cond.severity == INFO:
        text = "information, not judged" + (f"; {note}" if note else "")
        if value is None:
            return CheckResult(
                CONDITION_PREFIX + cond.key, None, None, False, f"{NOT_RECORDED}; {text}"
            )
        return CheckResult(CONDITION_PREFIX + cond.key, float(value), None, True, text)
    if value is None:
        detail = f"{NOT_RECORDED}; required {cond.allowed()}" + (f"; {note}" if note else "")
        return CheckResult(CONDITION_PREFIX + cond.key, None, limit, False, detail)
    ok = bool(cond.low <= value <= cond.high)
    detail = f"required {cond.allowed()}" + (f"; {note}" if note else "")
    return CheckResult(CONDITION_PREFIX + cond.key, float(value), limit, ok, detail)


def status(check: CheckResult) -> str:
    """ "pass", "fail", "warning", "info", "not recorded" or "not judged" of a check (any
    check); "info" is a recorded condition that no rule judges, "not judged" a check
    that needs what the run was judged without (`pipelines.judge` with no archive)."""
    name, detail = check.name, check.detail or ""
    if not check.passed and detail.startswith(f"{NOT_JUDGED}:"):
        return NOT_JUDGED
    entry = DEFAULT_CONDITIONS.get(name.removeprefix(CONDITION_PREFIX))
    info = name.startswith(CONDITION_PREFIX) and entry is not None and entry[2] == INFO
    if check.passed:
        return INFO if info else "pass"
    if not name.startswith(CONDITION_PREFIX):
        return "fail"
    if check.value is None and detail.startswith(NOT_RECORDED):
        return NOT_RECORDED
    return WARNING if entry is not None and entry[2] in (WARNING, INFO) else "fail"


def requirement(check: CheckResult) -> str:
    """A condition check's detail without the "not recorded" its result already says."""
    return (check.detail or "").removeprefix(f"{NOT_RECORDED}; ")


def counts_against_verdict(check: CheckResult) -> bool:
    """True for a failed check that counts against the verdict: not a condition's
    warning, not "not recorded"."""
    return not check.passed and status(check) == "fail"
