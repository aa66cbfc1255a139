"""Lab conditions and acquisition rules of a run, checked against the tolerance profile.

docs/methods.md 3.10 sets conditions a run must be made under; recording them is not enough, each
is judged and printed as one verdict line of the "conditions" section of the protocol and
the certificate. A check is named ``condition:<key>``; its value is in the unit the key
names (deg C, %, hPa, min, Hz, bit, s, deg/s), not SI, so the line reads as the procedure
writes it.

Severity, from the procedure's wording:

- warning (the verdict stands, the line says WARNING): the environment, which docs/methods.md 3.10
  asks to be *recorded* with each run with *targets* (ambient 20 +- 2 deg C, drift
  <= 0.5 deg C/h, humidity 40-60 %, pressure, warm-up time), and local gravity by the
  standard value instead of the site's (the MPU-6000 manual computes it by Helmert).
- failure (the run fails): the acquisition rules the numbers rest on, written as
  requirements: "settle >= 20 s then record >= 10 s at >= 100 Hz" (rate points),
  ">= 30 s settle for positions", the resolution, the temperature spread of the static
  records the biases come from, and the table's rate from its feedback channel
  (stability and deviation per plateau): a wrong reference rate is a wrong scale factor.

A condition the run does not record is "not recorded": not a pass (``passed`` false) and
not a failure (the verdict stands); the line says so.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib_core.calibration import CheckResult
from calib_core.recording import Recording
from calib_core.units import DEG

CONDITION_PREFIX = "condition:"
NOT_RECORDED = "not recorded"
WARNING, FAILURE = "warning", "failure"
ZERO_RATE = 1e-6  # rad/s: a plateau below this is a 0-rate (static) point


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
        -_INF, 0.2, FAILURE, "temperature spread over the static records", "deg C"),
    "table_rate_stability_dps": (
        -_INF, 0.1, FAILURE, "table rate stability (feedback std, worst plateau)", "deg/s"),
    "table_rate_deviation_dps": (
        -_INF, 0.5, FAILURE, "table rate deviation from nominal (worst plateau)", "deg/s"),
}  # fmt: skip


def conditions(overrides: Mapping[str, Mapping[str, float]] | None = None) -> dict[str, Condition]:
    """The conditions with a profile's ``[conditions]`` limits (``{low, high}``) applied."""
    out = {}
    for key, (low, high, severity, text, unit) in DEFAULT_CONDITIONS.items():
        given = (overrides or {}).get(key, {})
        out[key] = Condition(
            key, float(given.get("low", low)), float(given.get("high", high)), severity, text, unit
        )
    return out


def parse_conditions(raw: Any) -> dict[str, dict[str, float]]:
    """Validate a profile's ``[conditions]`` table: key -> {low, high} numbers.

    Raises ValueError naming ``conditions.<key>`` and what was expected.
    """
    if not isinstance(raw, dict):
        raise ValueError("tolerance profile field 'conditions': expected a table")
    out: dict[str, dict[str, float]] = {}
    for key, entry in raw.items():
        where = f"conditions.{key}"
        if key not in DEFAULT_CONDITIONS:
            known = list(DEFAULT_CONDITIONS)
            raise ValueError(f"{where}: unknown condition; expected one of {known}")
        if not isinstance(entry, dict) or not entry or set(entry) - {"low", "high"}:
            raise ValueError(f"{where}: expected a table {{ low = <number>, high = <number> }}")
        for side, value in entry.items():
            if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
                raise ValueError(f"{where}.{side}: expected a number, got {value!r}")
        if entry.get("low", -_INF) > entry.get("high", _INF):
            raise ValueError(f"{where}: low ({entry['low']}) is above high ({entry['high']})")
        out[key] = {k: float(v) for k, v in entry.items()}
    return out


def judge(cond: Condition, value: float | None, note: str = "") -> CheckResult:
    """One condition's check: ``value`` None is "not recorded"."""
    finite = [v for v in (cond.high, cond.low) if math.isfinite(v)]
    limit = finite[0] if finite else None
    if value is None:
        detail = f"{NOT_RECORDED}; required {cond.allowed()}" + (f"; {note}" if note else "")
        return CheckResult(CONDITION_PREFIX + cond.key, None, limit, False, detail)
    ok = bool(cond.low <= value <= cond.high)
    detail = f"required {cond.allowed()}" + (f"; {note}" if note else "")
    return CheckResult(CONDITION_PREFIX + cond.key, float(value), limit, ok, detail)


def status(check: Mapping[str, Any]) -> str:
    """"pass", "fail", "warning" or "not recorded" of an archived check dict (any check)."""
    if check["passed"]:
        return "pass"
    name = str(check["name"])
    if not name.startswith(CONDITION_PREFIX):
        return "fail"
    if check.get("value") is None and str(check.get("detail", "")).startswith(NOT_RECORDED):
        return NOT_RECORDED
    entry = DEFAULT_CONDITIONS.get(name.removeprefix(CONDITION_PREFIX))
    return WARNING if entry is not None and entry[2] == WARNING else "fail"


def requirement(check: Mapping[str, Any]) -> str:
    """A condition check's detail without the "not recorded" its result already says."""
    return str(check.get("detail") or "").removeprefix(f"{NOT_RECORDED}; ")


def counts_against_verdict(check: Any) -> bool:
    """True for a failed check (a CheckResult or any object with its fields) that counts
    against the verdict: not a condition's warning, not "not recorded"."""
    fields = {"name": check.name, "passed": check.passed,
              "value": getattr(check, "value", None), "detail": getattr(check, "detail", "")}
    return not check.passed and status(fields) == "fail"


def is_rotation(label: str) -> bool:
    """A turn of the integral method (``x_ccw``, ``z_cw``): not an attitude."""
    return label.endswith(("_cw", "_ccw"))


def plateau_rate(rec: Recording) -> float | None:
    """Mean table rate of a rate plateau from its feedback channel, rad/s; None if none."""
    ref = rec.reference.get("table_rate")
    return None if ref is None or not len(ref) else float(np.mean(ref))


def nominal_rate_dps(label: str) -> float | None:
    """The rate a plateau label names ("z_+100" -> 100.0 deg/s), None if it names none."""
    m = re.fullmatch(r"[xyz]_([+-]?\d+(?:\.\d+)?)", label)
    return None if m is None else float(m.group(1))


def _rate_hz(rec: Recording) -> float:
    return (len(rec) - 1) / rec.duration if len(rec) > 1 and rec.duration > 0 else 0.0


def _statics(segments: Mapping[str, Recording]) -> dict[str, Recording]:
    """Segments at rest: neither a turn nor a moving plateau."""
    out = {}
    for label, rec in segments.items():
        rate = plateau_rate(rec)
        if not is_rotation(label) and (rate is None or abs(rate) <= ZERO_RATE):
            out[label] = rec
    return out


def temperature_spread(statics: Mapping[str, Recording]) -> tuple[float | None, str]:
    """Largest minus smallest 1-s mean temperature over all static records, deg C.

    1-s means keep the sensor's temperature noise and its 0.1 deg C display step from
    counting as a spread. None when no static record has a temperature channel.
    """
    means: list[tuple[float, str]] = []
    for label, rec in statics.items():
        if rec.temp is None or not np.isfinite(rec.temp).any():
            continue
        block = max(1, int(round(_rate_hz(rec))))
        temp = rec.temp[np.isfinite(rec.temp)]
        k = max(1, len(temp) // block)
        means += [(float(chunk.mean()), label) for chunk in np.array_split(temp, k)]
    if not means:
        return None, "no temperature channel"
    lo, hi = min(means), max(means)
    return hi[0] - lo[0], f"{lo[0]:.2f} deg C ({lo[1]}) .. {hi[0]:.2f} deg C ({hi[1]})"


def temperature_drift(segments: Mapping[str, Recording]) -> tuple[float | None, str]:
    """Largest |slope| of the temperature over records of at least 10 min, deg C/h."""
    slopes = []
    for label, rec in segments.items():
        if rec.temp is None or rec.duration < 600.0 or not np.isfinite(rec.temp).all():
            continue
        slope = np.polyfit(rec.t - rec.t[0], rec.temp, 1)[0] * 3600.0
        slopes.append((abs(float(slope)), label))
    if not slopes:
        return None, "no temperature record of 10 min or more"
    worst = max(slopes)
    return worst[0], f"from the data, worst record {worst[1]}"


def _table_checks(
    plateaus: Mapping[str, Recording], settle: float, conds: dict[str, Condition]
) -> list[CheckResult]:
    """Rate stability (std) and deviation from the nominal rate of each plateau's feedback
    over its record window (after the settle); the worst plateau is judged."""
    stab, dev = [], []
    for label, rec in plateaus.items():
        keep = rec.t >= rec.t[0] + settle
        ref = np.asarray(rec.reference["table_rate"])[keep if keep.sum() > 1 else slice(None)]
        stab.append((float(np.std(ref, ddof=1)) / DEG if len(ref) > 1 else 0.0, label))
        nominal = nominal_rate_dps(label)
        if nominal is not None:
            dev.append((abs(float(np.mean(ref)) / DEG - nominal), label))
    out = [judge(conds["table_rate_stability_dps"], max(stab)[0], f"plateau {max(stab)[1]}")]
    if dev:
        out.append(judge(conds["table_rate_deviation_dps"], max(dev)[0], f"plateau {max(dev)[1]}"))
    else:
        out.append(judge(conds["table_rate_deviation_dps"], None, "labels name no rate"))
    return out


# Conditions the lab states (manifest [environment] / [acquisition], the model's data sheet).
RECORDED_KEYS = ("ambient_temperature_c", "humidity_pct", "pressure_hpa", "warmup_min")


def check_conditions(
    segments: Mapping[str, Recording],
    recorded: Mapping[str, float | None],
    *,
    procedure: str,
    settings: Mapping[str, Any],
    gravity: float,
    gravity_source: str | None,
    overrides: Mapping[str, Mapping[str, float]] | None = None,
) -> list[CheckResult]:
    """Every condition that applies to the run, one CheckResult ``condition:<key>`` each.

    Parameters
    ----------
    segments : the run's segments as acquired (before preprocessing), SI units.
    recorded : what the lab recorded: the RECORDED_KEYS, ``temperature_drift_c_per_h``,
        ``resolution_bits`` and ``settle_s`` (before each attitude); None or absent: not
        recorded.
    procedure : the run's procedure (``static_bias`` adds the 60-min record rule).
    settings : the run's settings; a rate table's ``settle_s`` / ``record_s`` are the
        plateau's settle and record times (the solver drops the settle).
    gravity : the gravity used, m/s^2.
    gravity_source : how it was obtained ("Helmert at 48.137 deg, 519 m"); None when it is
        the standard value for want of the site's (a warning).
    overrides : the profile's ``[conditions]`` limits.
    """
    conds = conditions(overrides)
    out = [judge(conds[k], recorded.get(k)) for k in RECORDED_KEYS]
    drift = recorded.get("temperature_drift_c_per_h")
    out.append(judge(conds["temperature_drift_c_per_h"], *(
        (abs(drift), "recorded") if drift is not None else temperature_drift(segments))))
    out.append(_gravity_check(conds["gravity"], gravity, gravity_source))
    out += _acquisition_checks(segments, recorded, procedure, settings, conds)
    return out


def _gravity_check(cond: Condition, gravity: float, source: str | None) -> CheckResult:
    if source is not None:
        return CheckResult(CONDITION_PREFIX + cond.key, gravity, None, True, source)
    return CheckResult(
        CONDITION_PREFIX + cond.key, gravity, None, False,
        "standard value: the site's latitude and height are not known (give them in the "
        "manifest's [site] or the lab file); the MPU-6000 manual uses Helmert's formula "
        "with the height correction",
    )  # fmt: skip


def _acquisition_checks(
    segments: Mapping[str, Recording],
    recorded: Mapping[str, float | None],
    procedure: str,
    settings: Mapping[str, Any],
    conds: dict[str, Condition],
) -> list[CheckResult]:
    """Sampling, resolution, settle and record times, static temperature spread, table rate."""
    if not segments:
        return []
    rate = min((_rate_hz(r), label) for label, r in segments.items())
    out = [judge(conds["sample_rate_hz"], rate[0], f"segment {rate[1]}"),
           judge(conds["resolution_bits"], recorded.get("resolution_bits"))]  # fmt: skip
    plateaus = {k: r for k, r in segments.items() if plateau_rate(r) is not None}
    attitudes = {k: r for k, r in segments.items() if k not in plateaus and not is_rotation(k)}
    settle = float(settings.get("settle_s", 20.0))
    records = [(r.duration, k) for k, r in attitudes.items()]
    if plateaus:
        out.append(judge(conds["settle_rate_s"], settle, "the solver drops it from each plateau"))
        window = settings.get("record_s")
        records += [(min(r.duration - settle, float(window or math.inf)), k)
                    for k, r in plateaus.items()]  # fmt: skip
        out += _table_checks(plateaus, settle, conds)
    if attitudes:
        out.append(judge(conds["settle_s"], recorded.get("settle_s")))
    if records:
        out.append(judge(conds["record_s"], min(records)[0], f"segment {min(records)[1]}"))
    if procedure == "static_bias":
        longest = max(r.duration for r in segments.values()) / 60.0
        out.append(judge(conds["static_record_min"], longest))
    spread, note = temperature_spread(_statics(segments))
    out.append(judge(conds["static_temperature_spread_c"], spread, note))
    return out
