"""The procedure object and its typed settings: what one calibration procedure declares.

A `Procedure` is everything the code knows about one procedure, in one place: the segments
it needs and how they are labelled or cut, its settings (`Setting`: name, type, unit,
default, bounds, meaning), the lab conditions that apply to it (`ConditionUse`: the quantity
each judges and the document it comes from), its solver, its uncertainty model, its
physical-bounds hint and the model checks its solver makes. `calib_core.procedures` holds
the one list of them; docs/procedures.md is generated from them.

The whole ``[run.settings]`` table of a run is checked against its procedure's settings, the
settings every procedure shares (`COMMON_SETTINGS`) and the keys of the preprocessing and
uncertainty tables (`TABLES`): an unknown key, a wrong type or a value out of bounds is a
`SettingError` naming the key, the value and what is allowed; nothing is ignored.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from calib_core.calibration import Calibration
from calib_core.condition_rules import ConditionUse
from calib_core.preprocess.chain import LOWPASS_KEYS, OUTLIER_KEYS, SEGMENTATION_KEYS, SYNC_KEYS
from calib_core.recording import Recording

# The value kinds a setting may take, as TOML writes them.
KINDS = ("number", "integer", "bool", "text", "table", "list")
Solver = Callable[[dict[str, Recording], float, dict[str, Any]], Calibration]
# (cal, segments, settings, spec) -> (solve closure or None, Type B inputs, notes); see
# calib_core.uncertainty_sources and calib_core.run_budget.
UncertaintyModel = Callable[..., tuple[Any, list[Any], tuple[str, ...]]]


class SettingError(ValueError):
    """A ``[run.settings]`` key refused: ``key`` is its dotted name under run.settings."""

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        self.problem = problem
        # "run.settings.k: expected a positive number, got -1"; "run.settings.x must be ..."
        super().__init__(f"run.settings.{key}{'' if problem.startswith('must') else ':'} {problem}")


def _is_kind(value: Any, kind: str) -> bool:
    if kind == "number":
        return isinstance(value, int | float) and not isinstance(value, bool)
    if kind == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, {"bool": bool, "text": str, "table": dict, "list": list}[kind])


@dataclass(frozen=True)
class Setting:
    """One setting of a procedure.

    name : the key in ``[run.settings]``.
    kind : "number", "integer", "bool", "text", "table" or "list"; a tuple for a setting
        that takes one of several kinds (e.g. "text" or "table").
    unit : the value's unit as the manifest writes it ("s", "deg/s", "deg", "1", "").
    default : the value when absent; None: absent means "not given" (inferred or unused).
    meaning : one line for the documentation.
    low, high : inclusive bounds of a number (None: unbounded); low_open excludes `low`.
    choices : the allowed texts of a "text" setting.
    length : the number of items of a "list" setting.
    """

    name: str
    kind: str | tuple[str, ...]
    unit: str
    default: Any
    meaning: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    choices: tuple[str, ...] = ()
    length: int | None = None

    @property
    def kinds(self) -> tuple[str, ...]:
        return self.kind if isinstance(self.kind, tuple) else (self.kind,)

    def allowed(self) -> str:
        """What the setting accepts, as a refusal and the documentation print it."""
        parts = []
        for kind in self.kinds:
            if kind == "text" and self.choices:
                parts.append("one of " + ", ".join(repr(c) for c in self.choices))
            elif kind in ("number", "integer"):
                parts.append(self._number(kind))
            elif kind == "list" and self.length is not None:
                parts.append(f"a list of {self.length} numbers")
            else:
                parts.append({"bool": "true or false", "table": "a table"}.get(kind, kind))
        return " or ".join(parts)

    def _number(self, kind: str) -> str:
        noun = "a number" if kind == "number" else "a whole number"
        lo, hi = self.low is not None, self.high is not None
        if lo and hi:
            return f"{noun} in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}]"
        if lo and self.low == 0.0:
            return noun.replace("a ", "a positive " if self.low_open else "a non-negative ")
        if lo:
            return f"{noun} {'>' if self.low_open else '>='} {self.low:g}"
        return f"{noun} <= {self.high:g}" if hi else noun

    def check(self, value: Any) -> None:
        """Raise SettingError naming the key, the value and what is allowed."""
        if value is None and self.default is None:
            return
        kind = next((k for k in self.kinds if _is_kind(value, k)), None)
        refused = kind is None or (
            (kind in ("number", "integer") and not self._inside(float(value)))
            or (kind == "list" and self.length is not None
                and (len(value) != self.length or not all(_is_kind(v, "number") for v in value)))
        )  # fmt: skip
        if kind == "text" and self.choices and value not in self.choices:
            raise SettingError(self.name, f"must be {self.allowed()}, got {value!r}")
        if refused:
            raise SettingError(self.name, f"expected {self.allowed()}, got {value!r}")

    def _inside(self, x: float) -> bool:
        if math.isnan(x):
            return False
        if self.low is not None and (x < self.low or (self.low_open and x == self.low)):
            return False
        return self.high is None or x <= self.high


class Settings:
    """A procedure's settings: the typed declaration its runs are validated against."""

    def __init__(self, *settings: Setting) -> None:
        self.items: dict[str, Setting] = {s.name: s for s in settings}

    def __iter__(self):
        return iter(self.items.values())

    def __contains__(self, name: object) -> bool:
        return name in self.items

    def defaults(self) -> dict[str, Any]:
        """name -> default of every setting."""
        return {s.name: s.default for s in self}

    def merged(self, given: Mapping[str, Any] | None) -> dict[str, Any]:
        """The declared settings with defaults filled in, each checked; other keys left out."""
        out = self.defaults()
        for key, value in (given or {}).items():
            if key in self.items:
                self.items[key].check(value)
                out[key] = value
        return out


# Settings every procedure shares: the sensor's full scale, used by ingest's range check.
GYRO_RANGE = Setting(
    "gyro_range_dps", "number", "deg/s", None,
    "gyro full scale (default: [unit] gyro_range_dps, else the model's); readings at it are "
    "refused as saturated", low=0.0, low_open=True)  # fmt: skip
COMMON_SETTINGS = Settings(GYRO_RANGE)

# Tables of [run.settings] read by preprocessing (calib_core.preprocess.chain) and by the
# uncertainty step (pipelines.uncertainty): their keys.
UNCERTAINTY_KEYS = {"gravity_expanded_mps2", "cube_angle_deg", "table_rate_rel", "turn_angle_deg"}
TABLES: dict[str, set[str]] = {
    "sync": SYNC_KEYS,
    "segmentation": SEGMENTATION_KEYS,
    "outliers": OUTLIER_KEYS,
    "lowpass": LOWPASS_KEYS,
    "uncertainty": UNCERTAINTY_KEYS,
}


# Conditions of every procedure (each adds its own): the environment methods.md 3 asks to be
# recorded, the site's gravity, sampling and resolution (methods.md 2.4), the sensor's
# temperature trend.
METHODS = "methods.md"
ENVIRONMENT = (
    ConditionUse("ambient_temperature_c", "ambient (lab) temperature, as recorded",
                 f"{METHODS} 3"),
    ConditionUse("temperature_drift_c_per_h", "ambient temperature drift (recorded, else the "
                 "sensor's over records of 10 min or more)", f"{METHODS} 3"),
    ConditionUse("humidity_pct", "relative humidity, as recorded", f"{METHODS} 3"),
    ConditionUse("pressure_hpa", "air pressure, as recorded", f"{METHODS} 3"),
    ConditionUse("warmup_min", "warm-up time before the run, as recorded", f"{METHODS} 3"),
    ConditionUse("gravity", "local gravity: from the site, not the standard value",
                 "MPU-6000 manual (Helmert's formula)"),
    ConditionUse("sample_rate_hz", "sampling rate of the slowest segment", f"{METHODS} 2.4"),
    ConditionUse("resolution_bits", "sensor resolution, as recorded", f"{METHODS} 2.4"),
    ConditionUse("sensor_temperature_spread_c", "sensor temperature (1-s means) over the "
                 "whole run: recorded for the thermal model, not judged", f"{METHODS} 3"),
)  # fmt: skip
ATTITUDES = (
    ConditionUse("settle_s", "settle time before each static attitude, as recorded",
                 f"{METHODS} 2.5"),
    ConditionUse("record_s", "record time of the shortest static attitude", f"{METHODS} 2.4"),
)  # fmt: skip
RATE_PLATEAUS = (
    ConditionUse("settle_rate_s", "settle time of each rate plateau (settings.settle_s, "
                 "dropped by the solver)", f"{METHODS} 2.4"),
    ConditionUse("record_s", "record time of the shortest plateau after its settle",
                 f"{METHODS} 2.4"),
    ConditionUse("table_rate_stability_dps", "table rate from its feedback channel: std over "
                 "the worst plateau's record", f"{METHODS} 2.4"),
    ConditionUse("table_rate_deviation_dps", "table rate from its feedback channel: mean "
                 "minus the plateau label's nominal rate, worst plateau", f"{METHODS} 2.4"),
)  # fmt: skip


@dataclass(frozen=True)
class Procedure:
    """Everything about one procedure (module docstring).

    name : as the manifest's ``run.procedure`` writes it.
    summary : one line: what it calibrates from what.
    segments : the segments it needs and how they are labelled or cut (documentation).
    labels : the labels hand-listed segments may carry (empty: any label); a run with
        ``[run.settings.segmentation]`` is cut and labelled automatically instead.
    required : labels it needs (missing ones are named before the solve).
    settings : its typed settings.
    solver : labelled segments, gravity (m/s^2), settings -> Calibration.
    conditions : the lab conditions that apply, each with the quantity it judges and source.
    uncertainty : its Type B model (None: Type A only, said so in each budget).
    bounds_hint : what to check when a parameter is beyond physical bounds.
    model_checks : the checks its solver makes of its own model (documentation).
    reference : the document the procedure follows.
    """

    name: str
    summary: str
    segments: str
    solver: Solver
    settings: Settings
    conditions: tuple[ConditionUse, ...]
    reference: str
    labels: tuple[str, ...] = ()
    required: tuple[str, ...] = ()
    uncertainty: UncertaintyModel | None = None
    bounds_hint: str = (
        "check the segment labels (which axis was up, the rotation sense), the units and "
        "the axis order of the columns"
    )
    model_checks: str = "residuals per segment against the profile's limits"
    missing_rule: Callable[[set[str], Mapping[str, Any]], list[str]] | None = field(
        default=None, repr=False
    )

    def all_settings(self) -> Settings:
        """Its own settings and the shared ones it does not redefine."""
        shared = [s for s in COMMON_SETTINGS if s.name not in self.settings]
        return Settings(*self.settings, *shared)

    def condition_keys(self) -> tuple[str, ...]:
        return tuple(c.key for c in self.conditions)

    def missing(self, labels: set[str], settings: Mapping[str, Any]) -> list[str]:
        """Labels it needs that `labels` lacks ("x_ccw or x_cw" where one suffices)."""
        if self.missing_rule is not None:
            return self.missing_rule(labels, settings)
        return [label for label in self.required if label not in labels]

    def validate(self, settings: Mapping[str, Any]) -> dict[str, Any]:
        """Check a whole ``[run.settings]`` table; returns its own settings, defaults filled.

        Raises SettingError for an unknown key (naming the closest valid one), a wrong type
        or a value out of bounds (naming key, value and allowed range), in a table too.
        """
        declared = self.all_settings()
        known = [*declared.items, *TABLES]
        for key, value in settings.items():
            if key in declared:
                declared.items[key].check(value)
            elif key in TABLES:
                _check_table(key, value, TABLES[key])
            else:
                hint = _did_you_mean(key, known)
                raise SettingError(key, f"unknown setting of {self.name}{hint}")
        return self.settings.merged(settings)


def _did_you_mean(key: str, known: list[str]) -> str:
    near = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    if near:
        return f"; did you mean {near[0]}?"
    return f"; expected one of {', '.join(sorted(known))}"


def _check_table(name: str, value: Any, keys: set[str]) -> None:
    if not isinstance(value, dict):
        raise SettingError(name, f"expected a table of settings, got {value!r}")
    for key in value:
        if key not in keys:
            raise SettingError(
                f"{name}.{key}", f"unknown setting of [run.settings.{name}]"
                f"{_did_you_mean(key, sorted(keys))}",
            )  # fmt: skip
