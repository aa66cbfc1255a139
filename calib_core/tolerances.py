"""Tolerance profiles, the science side: a device type's limits parsed into SI.

A tolerance profile is data, not code: the lab keeps one file per device type
(TOML; `pipelines.tolerances` finds and reads the files), parsed here into SI
limits. Parameter limits are matched to canonical names by glob patterns, first
match wins, so a specific pattern ("acc.bias.z") listed before a general one
("acc.bias.*") overrides it. Residual limits bound the per-segment residual
statistics (docs/methods.md 3.6: accel residual std <= 0.002 g, gyro residual std
<= 0.1 deg/s, residual mean near zero). `calib_core.checks` judges a
calibration against a profile.
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field
from typing import Any

from calib_core import decision, params, units
from calib_core.condition_rules import parse_conditions
from calib_core.decision import DecisionRule
from calib_core.settings import Setting, SettingError, Settings

# Every canonical name a limit pattern may match.
ALL_NAMES: list[str] = (
    params.ACC_LINEAR
    + params.GYR_LINEAR
    + params.GSENS
    + [f"{s}.noise.{a}" for s in ("acc", "gyr") for a in params.AXES]
    + [f"acc.{k}.{a}" for k in ("k2", "k3") for a in params.AXES]
)


# Physical dimension of each parameter family (what a limit's unit must be).
_FAMILY_DIMENSION = {
    "acc.bias": "acceleration",
    "acc.noise": "acceleration",
    "acc.scale": "dimensionless",
    "acc.misalign": "dimensionless",
    "acc.k2": "1/acceleration",
    "acc.k3": "1/acceleration^2",
    "gyr.bias": "angular rate",
    "gyr.noise": "angular rate",
    "gyr.scale": "dimensionless",
    "gyr.misalign": "dimensionless",
    "gyr.gsens": "angular rate/acceleration",
}
_DIMENSIONLESS = {"1": 1.0, "": 1.0, "%": 1e-2, "ppm": 1e-6}

RESIDUAL_KEYS = ("acc_std", "gyr_std", "acc_mean", "gyr_mean")
# docs/methods.md 3.6; a residual mean as large as the allowed noise: the model misses something.
DEFAULT_RESIDUAL_LIMITS: dict[str, float] = {
    "acc_std": 0.002 * units.STANDARD_GRAVITY,
    "gyr_std": 0.1 * units.DEG,
    "acc_mean": 0.002 * units.STANDARD_GRAVITY,
    "gyr_mean": 0.1 * units.DEG,
}
_RESIDUAL_DIMENSION = {"acc": "acceleration", "gyr": "angular rate"}

# docs/methods.md 3.8, accuracy verification on points not used in the fit.
VERIFICATION_KEYS = ("acc", "gyr")
DEFAULT_VERIFICATION_LIMITS: dict[str, float] = {
    "acc": 0.01 * units.STANDARD_GRAVITY,
    "gyr": 0.5 * units.DEG,
}
_FRACTION = {"low": 0.0, "high": 1.0, "low_open": True, "high_open": True}
_POSITIVE = {"low": 0.0, "low_open": True}
# ``[recall]``: how the recalibration interval is set (calib_core.interval, docs/interval.md);
# ``[protocol]``: the names the test protocol prints.
RECALL_METHODS = ("variables", "fixed")
PROTOCOL_NAMES = ("canonical", "manual")
# docs/methods.md 3.7, repeatability: three complete runs, CV <= 1 %.
REPEATABILITY = Settings(
    Setting("cv_max", "number", "1", 0.01, "largest coefficient of variation", **_FRACTION),
    Setting("alpha", "number", "1", 0.01, "family-wise false-alarm rate of the "
            "scatter-vs-uncertainty rule, where a CV is meaningless", **_FRACTION),
    Setting("min_runs", "integer", "1", 3, "fewest complete runs of a group", low=2),
    Setting("max_runs", "integer", "1", 5, "most runs of a group (the latest)", low=2),
    Setting("temperature_tol_c", "number", "degC", 2.0, "runs within this of each other count "
            "as the same conditions (the lab's 20 +- 2 deg C)", low=0.0),
)  # fmt: skip
RECALL = Settings(
    Setting("method", "text", "", "variables", "from the unit's and its fleet's drift "
            "(variables) or fixed_months (fixed)", choices=RECALL_METHODS),
    Setting("reliability", "number", "1", 0.95, "in-tolerance probability at the interval's "
            "end", **_FRACTION),
    Setting("max_months", "number", "month", 60.0, "longest interval", **_POSITIVE),
    Setting("fixed_months", "number", "month", 12.0, "the fixed interval", **_POSITIVE),
)  # fmt: skip
PROTOCOL = Settings(Setting(
    "names", "text", "", "canonical", "the protocol also prints the MPU-6000 manual's names "
    "and signs (manual)", choices=PROTOCOL_NAMES))  # fmt: skip
DECISION = Settings(
    Setting("name", "text", "", "simple", "the ILAC-G8 rule", choices=decision.RULES),
    Setting("r", "number", "1", 1.0, "guard band in expanded uncertainties (guard_band_r)"),
)
# A profile's keys; name, version and device_model must be given (`REQUIRED`).
PROFILE = Settings(
    Setting("name", "text", "", None, "the profile's name"),
    Setting("version", ("text", "number"), "", None, "its version, archived with each verdict"),
    Setting("device_model", "text", "", None, "the device type it is written for"),
    Setting("limits", "list", "", None, "[[limits]]: pattern, unit, bound or low / high"),
    *(Setting(k, "table", "", None, f"the table {meaning}") for k, meaning in {
        "residual_limits": "of RESIDUAL_KEYS", "verification_limits": "of VERIFICATION_KEYS",
        "repeatability": "REPEATABILITY", "decision_rule": "DECISION",
        "conditions": "{ low, high } of each condition", "protocol": "PROTOCOL",
        "recall": "RECALL"}.items()),
    noun="field",
)  # fmt: skip
REQUIRED = ("name", "version", "device_model")
LIMIT = Settings(
    Setting("pattern", "text", "", None, "glob on canonical names, e.g. 'gyr.scale.*'"),
    Setting("unit", "text", "", None, "unit of the bounds (parse_unit)"),
    Setting("bound", "number", "", None, "symmetric limit -bound .. +bound"),
    Setting("low", "number", "", None, "lower limit (absent: unbounded)"),
    Setting("high", "number", "", None, "upper limit (absent: unbounded)"),
    noun="field",
)
VALUE = Settings(
    Setting("value", "number", "", None, "the limit", low=0.0, low_open=True),
    Setting("unit", "text", "", None, "its unit (parse_unit)"),
    noun="field",
)
RESIDUAL = Settings(*(Setting(k, "table", "", None, "{ value, unit }") for k in RESIDUAL_KEYS),
                    noun="key")  # fmt: skip
VERIFICATION = Settings(
    *(Setting(k, "table", "", None, "{ value, unit }") for k in VERIFICATION_KEYS), noun="key"
)
DEFAULT_REPEATABILITY: dict[str, float | int] = REPEATABILITY.defaults()
DEFAULT_RECALL: dict[str, str | float] = RECALL.defaults()


def _strip_parens(text: str) -> str:
    text = text.strip()
    if text.startswith("(") and text.endswith(")") and text.count("(") == 1:
        return text[1:-1].strip()
    return text


def parse_unit(unit: str) -> tuple[str, float]:
    """Dimension and SI factor of a lab unit string.

    Understands dimensionless ("1", "%", "ppm"), the acceleration and angular
    rate units of calib_core.units, g-sensitivity "<rate>/<acceleration>"
    (e.g. "(deg/s)/g", "deg/s/g", "(rad/s)/(m/s^2)") and "1/<acceleration>"
    and "1/<acceleration>^2" for the nonlinear terms.

    Returns
    -------
    (dimension name, factor): value_SI = value * factor.
    """
    u = unit.strip()
    if u in _DIMENSIONLESS:
        return "dimensionless", _DIMENSIONLESS[u]
    if u in units.ACCELERATION_UNITS:
        return "acceleration", units.ACCELERATION_UNITS[u]
    if u in units.ANGULAR_RATE_UNITS:
        return "angular rate", units.ANGULAR_RATE_UNITS[u]
    # A ratio: try every '/' as the main division ("deg/s/g", "(rad/s)/(m/s^2)").
    for i, ch in enumerate(u):
        if ch != "/":
            continue
        num, den = _strip_parens(u[:i]), u[i + 1 :].strip()
        if num == "1":
            base = _strip_parens(den[:-2]) if den.endswith("^2") else ""
            if base in units.ACCELERATION_UNITS:  # "1/g^2", "1/(m/s^2)^2"
                return "1/acceleration^2", 1.0 / units.ACCELERATION_UNITS[base] ** 2
            if _strip_parens(den) in units.ACCELERATION_UNITS:  # "1/g", "1/(m/s^2)"
                return "1/acceleration", 1.0 / units.ACCELERATION_UNITS[_strip_parens(den)]
        den_unit = _strip_parens(den)
        if num in units.ANGULAR_RATE_UNITS and den_unit in units.ACCELERATION_UNITS:
            factor = units.ANGULAR_RATE_UNITS[num] / units.ACCELERATION_UNITS[den_unit]
            return "angular rate/acceleration", factor
    raise ValueError(
        f"unknown unit {unit!r}; expected 1, %, ppm, an acceleration unit "
        f"({', '.join(units.ACCELERATION_UNITS)}), an angular rate unit "
        f"({', '.join(units.ANGULAR_RATE_UNITS)}) or a ratio like (deg/s)/g"
    )


_SI_UNIT = {
    "dimensionless": "1",
    "acceleration": "m/s^2",
    "angular rate": "rad/s",
    "angular rate/acceleration": "(rad/s)/(m/s^2)",
    "1/acceleration": "1/(m/s^2)",
    "1/acceleration^2": "1/(m/s^2)^2",
}


def family(name: str) -> str:
    """The parameter family of a canonical name: "acc.bias.z" -> "acc.bias"."""
    return name.rsplit(".", 1)[0]


@dataclass(frozen=True)
class ParameterLimit:
    """Allowed range of the parameters whose canonical name matches `pattern`.

    pattern : fnmatch glob on canonical names, e.g. "gyr.scale.*", "acc.bias.z".
    low, high : SI bounds (inclusive); -inf / inf for a one-sided limit.
    """

    pattern: str
    low: float
    high: float

    def matches(self, name: str) -> bool:
        return fnmatch.fnmatchcase(name, self.pattern)

    @property
    def limit(self) -> float:
        """The number a report prints: |bound| of a symmetric limit, else high (or low)."""
        return self.high if math.isfinite(self.high) else self.low


# The top-level fields of a profile document.
@dataclass
class ToleranceProfile:
    """Tolerances of one device type, SI units.

    Attributes
    ----------
    name, version : the profile's name and version (archived with every verdict).
    device_model : the device type it is written for.
    parameter_limits : ParameterLimit per parameter pattern, first match wins.
    residual_limits : "acc_std", "gyr_std", "acc_mean", "gyr_mean" in m/s^2
        and rad/s; missing keys take DEFAULT_RESIDUAL_LIMITS.
    verification_limits : "acc" (m/s^2) and "gyr" (rad/s), the largest error of
        the compensated output at a held-out point; missing keys take
        DEFAULT_VERIFICATION_LIMITS.
    repeatability : "cv_max", "alpha", "min_runs", "max_runs",
        "temperature_tol_c"; missing keys take DEFAULT_REPEATABILITY.
    decision_rule : ILAC-G8 rule of the statements of conformity (TOML
        ``decision_rule = { name = "guard_band_r", r = 0.5 }``); simple acceptance if absent.
    conditions : limits of the lab conditions and acquisition rules, key ->
        {"low", "high"} in the key's unit (calib_core.conditions); missing keys and sides
        take DEFAULT_CONDITIONS.
    protocol_names : "canonical" (default) or "manual": the protocol also prints each
        parameter under the MPU-6000 manual's name and sign (params.MANUAL_NAMES).
    """

    name: str
    version: str
    device_model: str
    parameter_limits: list[ParameterLimit]
    residual_limits: dict[str, float] = field(default_factory=dict)
    verification_limits: dict[str, float] = field(default_factory=dict)
    repeatability: dict[str, float | int] = field(default_factory=dict)
    decision_rule: DecisionRule = field(default_factory=DecisionRule)
    conditions: dict[str, dict[str, float]] = field(default_factory=dict)
    protocol_names: str = "canonical"
    recall: dict[str, str | float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.recall = {**DEFAULT_RECALL, **self.recall}
        self.residual_limits = {**DEFAULT_RESIDUAL_LIMITS, **self.residual_limits}
        self.verification_limits = {**DEFAULT_VERIFICATION_LIMITS, **self.verification_limits}
        self.repeatability = {**DEFAULT_REPEATABILITY, **self.repeatability}

    def limit_for(self, name: str) -> ParameterLimit | None:
        """The first limit whose pattern matches `name`, or None."""
        return next((lim for lim in self.parameter_limits if lim.matches(name)), None)

    def judge(self, name: str, value: float, U: float) -> str | None:
        """ILAC-G8 verdict of parameter `name` (SI value and expanded uncertainty) under the
        profile's decision rule; None when no limit applies."""
        lim = self.limit_for(name)
        if lim is None:
            return None
        return decision.decide(value, U, lim.low, lim.high, self.decision_rule)

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> ToleranceProfile:
        """Build a profile from a parsed TOML document (lab units, explicit unit per limit).

        Each ``[[limits]]`` entry has ``pattern``, ``unit`` and either ``bound``
        (symmetric, -bound .. +bound) or ``low`` and/or ``high`` (a missing side
        is unbounded). Residual limits are ``{value, unit}`` tables. Example
        (the MPU-6000 paper's tolerances)::

            name = "mpu6000"
            version = "1"
            device_model = "MPU-6000"

            [residual_limits]
            acc_std = { value = 2.0, unit = "mg" }
            gyr_std = { value = 0.1, unit = "deg/s" }

            [[limits]]
            pattern = "gyr.scale.*"
            bound = 0.03
            unit = "1"
            [[limits]]
            pattern = "gyr.misalign.*"
            bound = 0.02
            unit = "1"
            [[limits]]
            pattern = "gyr.bias.*"
            bound = 20
            unit = "deg/s"
            [[limits]]
            pattern = "gyr.gsens.*"
            bound = 0.1
            unit = "(deg/s)/g"
            [[limits]]
            pattern = "gyr.noise.*"
            high = 0.05
            unit = "deg/s"
            [[limits]]
            pattern = "acc.scale.*"
            bound = 0.03
            unit = "1"
            [[limits]]
            pattern = "acc.misalign.*"
            bound = 0.02
            unit = "1"
            [[limits]]
            pattern = "acc.bias.z"     # before acc.bias.*: first match wins
            bound = 0.8
            unit = "m/s^2"
            [[limits]]
            pattern = "acc.bias.*"
            bound = 0.5
            unit = "m/s^2"

        Raises
        ------
        ValueError naming the field (e.g. ``limits[3].unit``) and what was expected.
        """
        if not isinstance(doc, dict):
            raise ValueError(f"tolerance profile: expected a table, got {type(doc).__name__}")
        PROFILE.validate(doc, "", root="")
        for key in REQUIRED:
            if doc.get(key) in (None, ""):
                raise SettingError(key, "expected a non-empty string", root="")
        return cls(
            *(str(doc[key]) for key in REQUIRED),
            parameter_limits=[
                _limit(e, f"limits[{i}]") for i, e in enumerate(doc.get("limits", []))
            ],
            residual_limits=_positive_limits(doc, "residual_limits", RESIDUAL),
            verification_limits=_positive_limits(doc, "verification_limits", VERIFICATION),
            repeatability=_repeatability(doc),
            decision_rule=_decision_rule(doc.get("decision_rule", {})),
            conditions=parse_conditions(doc.get("conditions", {})),
            protocol_names=_section(doc, "protocol", PROTOCOL).get("names", "canonical"),
            recall={
                k: v if k == "method" else float(v)
                for k, v in _section(doc, "recall", RECALL).items()
            },
        )

    def to_dict(self) -> dict[str, Any]:
        """The profile as a TOML-able document in SI units (from_dict reads it back)."""
        limits = []
        for lim in self.parameter_limits:
            dims = {_FAMILY_DIMENSION[family(n)] for n in ALL_NAMES if lim.matches(n)}
            entry: dict[str, Any] = {"pattern": lim.pattern, "unit": _SI_UNIT[dims.pop()]}
            if math.isfinite(lim.low):
                entry["low"] = lim.low
            if math.isfinite(lim.high):
                entry["high"] = lim.high
            limits.append(entry)
        residual = {
            key: {"value": value, "unit": _SI_UNIT[_RESIDUAL_DIMENSION[key.split("_")[0]]]}
            for key, value in self.residual_limits.items()
        }
        verification = {
            key: {"value": value, "unit": _SI_UNIT[_RESIDUAL_DIMENSION[key]]}
            for key, value in self.verification_limits.items()
        }
        doc = {
            "name": self.name,
            "version": self.version,
            "device_model": self.device_model,
            "limits": limits,
            "residual_limits": residual,
            "verification_limits": verification,
            "repeatability": dict(self.repeatability),
        }
        if self.decision_rule != DecisionRule():  # absent means simple acceptance (older docs)
            doc["decision_rule"] = {"name": self.decision_rule.name, "r": self.decision_rule.r}
        if self.conditions:
            doc["conditions"] = {k: dict(v) for k, v in self.conditions.items()}
        if self.protocol_names != "canonical":
            doc["protocol"] = {"names": self.protocol_names}
        if self.recall != DEFAULT_RECALL:
            doc["recall"] = dict(self.recall)
        return doc


def _decision_rule(raw: dict[str, Any]) -> DecisionRule:
    """``decision_rule = { name = ..., r = ... }`` of a profile; simple acceptance when empty."""
    DECISION.validate(raw, "decision_rule", root="")
    values = DECISION.merged(raw)
    try:
        return DecisionRule(values["name"], float(values["r"]))
    except ValueError as exc:
        raise SettingError("decision_rule", str(exc), root="") from None


def _section(doc: dict[str, Any], name: str, table: Settings) -> dict[str, Any]:
    """A profile's table `name` as given, checked against its declaration (SettingError
    naming ``name.key``)."""
    raw = doc.get(name, {})
    table.validate(raw, name, root="")
    return dict(raw)


def _positive_limits(doc: dict[str, Any], name: str, table: Settings) -> dict[str, float]:
    """A table of positive limits as ``{value, unit}`` entries, keyed "acc..." / "gyr...", SI out.

    Used for ``[residual_limits]`` (acc_std, gyr_mean, ...) and ``[verification_limits]``
    (acc, gyr); the key's sensor prefix decides the unit's dimension.
    """
    out: dict[str, float] = {}
    for key, entry in _section(doc, name, table).items():
        where = f"{name}.{key}"
        VALUE.validate(entry, where, root="")
        if set(entry) != {"value", "unit"}:
            raise SettingError(where, "expected a table { value = <number>, unit = <string> }", "")
        dimension = _RESIDUAL_DIMENSION[key.split("_")[0]]
        dim, factor = _unit(entry["unit"], where)
        if dim != dimension:
            problem = f"{entry['unit']!r} is a unit of {dim}, expected a unit of {dimension}"
            raise SettingError(f"{where}.unit", problem, root="")
        out[key] = float(entry["value"]) * factor
    return out


def _repeatability(doc: dict[str, Any]) -> dict[str, float | int]:
    """``[repeatability]`` (`REPEATABILITY`), max_runs not below min_runs."""
    out = _section(doc, "repeatability", REPEATABILITY)
    merged = {**DEFAULT_REPEATABILITY, **out}
    if merged["max_runs"] < merged["min_runs"]:
        raise SettingError("repeatability.max_runs", "must not be below min_runs", root="")
    return {k: v if k in ("min_runs", "max_runs") else float(v) for k, v in out.items()}


def _unit(unit: str, where: str) -> tuple[str, float]:
    """`parse_unit` of an entry's ``unit`` field, errors naming ``<where>.unit``."""
    try:
        return parse_unit(unit)
    except ValueError as exc:
        raise SettingError(f"{where}.unit", str(exc), root="") from None


def _limit(entry: Any, where: str) -> ParameterLimit:
    """One ``[[limits]]`` entry (`LIMIT`) in SI."""
    if not isinstance(entry, dict):
        raise SettingError(where, "expected a table with pattern, unit and bound or low/high", "")
    LIMIT.validate(entry, where, root="")
    pattern = entry.get("pattern")
    if not pattern:
        raise SettingError(f"{where}.pattern", "expected a glob on names like 'gyr.scale.*'", "")
    dims = {_FAMILY_DIMENSION[family(n)] for n in ALL_NAMES if fnmatch.fnmatchcase(n, pattern)}
    if len(dims) != 1:
        problem = (f"{pattern!r} matches no canonical parameter name" if not dims else
                   f"{pattern!r} matches parameters of different units ({sorted(dims)}); "
                   "split it into one limit per kind")  # fmt: skip
        raise SettingError(f"{where}.pattern", problem, root="")
    if "unit" not in entry:
        raise SettingError(f"{where}.unit", "missing; the unit of the bounds must be given", "")
    dim, factor = _unit(entry["unit"], where)
    if dim != (expected := dims.pop()):
        problem = (
            f"{entry['unit']!r} is a unit of {dim}, but {pattern!r} needs a unit of {expected}"
        )
        raise SettingError(f"{where}.unit", problem, root="")
    sides = {"low", "high"} & set(entry)
    if ("bound" in entry) == bool(sides):
        problem = (
            "give either bound or low/high, not both" if sides else "missing bound (or low / high)"
        )
        raise SettingError(where, problem, root="")
    bound = abs(entry.get("bound", math.inf))
    low, high = float(entry.get("low", -bound)), float(entry.get("high", bound))
    if low > high:
        raise SettingError(where, f"low ({low}) is above high ({high})", root="")
    return ParameterLimit(pattern, low * factor, high * factor)
