"""The procedure object and its typed settings: what one calibration procedure declares.

A `Procedure` is everything the code knows about one procedure, in one place: the segments
it needs and how they are labelled or cut, its settings (`Setting`: name, type, unit,
default, bounds, meaning), the lab conditions that apply to it (`ConditionUse`: the quantity
each judges and the document it comes from), its solver, its uncertainty model, its
physical-bounds hint and the model checks its solver makes. `calib_core.procedures` holds
the one list of them; docs/procedures.md is generated from them.

The whole ``[run.settings]`` table of a run is checked against its procedure's settings, the
settings every procedure shares (`COMMON_SETTINGS`) and the typed preprocessing and
uncertainty tables (`tables.TABLES`): an unknown key, a wrong type or a value out of bounds
is a `SettingError` naming the key, the value and what is allowed; nothing is ignored.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from calib_core.calibration import Calibration
from calib_core.condition_rules import ConditionUse
from calib_core.procedures.tables import TABLES
from calib_core.recording import Recording
from calib_core.settings import Setting, SettingError, Settings, did_you_mean

# (segments, gravity, the procedure's typed settings: `Procedure.settings.parse`) -> Calibration
Solver = Callable[[dict[str, Recording], float, Any], Calibration]
# (cal, segments, settings, spec) -> (solve closure or None, Type B inputs, notes); see
# calib_core.uncertainty_sources and calib_core.run_budget.
UncertaintyModel = Callable[..., tuple[Any, list[Any], tuple[str, ...]]]
StaticSegments = Literal["all", "all but turns", "none"]


# Settings every procedure shares: the sensor's full scale, used by ingest's range check.
GYRO_RANGE = Setting(
    "gyro_range_dps", "number", "deg/s", None,
    "gyro full scale (default: [unit] gyro_range_dps, else the model's); readings at it are "
    "refused as saturated", low=0.0, low_open=True)  # fmt: skip
COMMON_SETTINGS = Settings(GYRO_RANGE)

# Conditions of every procedure (each adds its own): the environment docs/methods.md 3.10 asks to be
# recorded, the site's gravity, sampling and resolution (docs/methods.md 2.4), the sensor's
# temperature trend.
METHODS = "docs/methods.md"
ENVIRONMENT = (
    ConditionUse("ambient_temperature_c", "ambient (lab) temperature, as recorded",
                 f"{METHODS} 3.10"),
    ConditionUse("temperature_drift_c_per_h", "ambient temperature drift (recorded, else the "
                 "sensor's over records of 10 min or more)", f"{METHODS} 3.10"),
    ConditionUse("humidity_pct", "relative humidity, as recorded", f"{METHODS} 3.10"),
    ConditionUse("pressure_hpa", "air pressure, as recorded", f"{METHODS} 3.10"),
    ConditionUse("warmup_min", "warm-up time before the run, as recorded", f"{METHODS} 3.10"),
    ConditionUse("gravity", "local gravity: from the site, not the standard value",
                 "MPU-6000 manual (Helmert's formula)"),
    ConditionUse("sample_rate_hz", "sampling rate of the slowest segment", f"{METHODS} 2.4"),
    ConditionUse("resolution_bits", "sensor resolution, as recorded", f"{METHODS} 2.4"),
    ConditionUse("sensor_temperature_spread_c", "sensor temperature (1-s means) over the "
                 "whole run: recorded for the thermal model, not judged", f"{METHODS} 3.10"),
)  # fmt: skip
ATTITUDES = (
    ConditionUse("settle_s", "settle time before each static attitude, as recorded",
                 f"{METHODS} 3.4"),
    ConditionUse("record_s", "record time of the shortest static attitude", f"{METHODS} 2.4"),
)  # fmt: skip
# The rate-table procedure: table position within 5 arcsec while held (settling and the
# 60-min static run), from the table's position feedback.
TABLE_POSITION = ConditionUse(
    "table_position_arcsec", "table position from its feedback channel (table_angle, "
    "table_pitch, table_roll): span of the 1-s means over the worst held segment",
    "rate-table procedure, settling and 60-min static run")  # fmt: skip
# The rate-table procedure's equipment pre-check, from the lab's equipment records.
EQUIPMENT_PRECHECK = tuple(
    ConditionUse(key, what + ", from the lab's equipment record (lab.toml)",
                 "rate-table procedure, equipment pre-check")
    for key, what in (
        ("table_angle_accuracy_arcsec", "table angle accuracy"),
        ("table_axis_perpendicularity_arcsec", "table axis perpendicularity"),
        ("power_stability_pct", "power supply stability"),
        ("imu_table_parallelism_arcsec", "IMU-to-table axis parallelism"),
    )
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
    solver : labelled segments, gravity (m/s^2), its typed settings -> Calibration.
    conditions : the lab conditions that apply, each with the quantity it judges and source.
    uncertainty : its Type B model (None: Type A only, said so in each budget).
    bounds_hint : what to check when a parameter is beyond physical bounds.
    model_checks : the checks its solver makes of its own model (documentation).
    static_segments : which of its segments are held still and must have been (a
        ``motion:<label>`` check each, `calib_core.preprocess.motion`): "all", "all but
        turns" (labels ending ``_cw``/``_ccw``), or "none" (it moves on purpose).
    reference : the document the procedure follows.
    stream_solver : the solve of its one record streamed in chunks, for a record larger
        than the run's memory limit: (chunks, settings, **streaming) -> Calibration, as
        `calib_core.procedures.static_bias.solve_static_bias_streamed`; None: its records
        are read into memory.
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
    static_segments: StaticSegments = "none"
    missing_rule: Callable[[set[str], Mapping[str, Any]], list[str]] | None = field(
        default=None, repr=False
    )
    stream_solver: Callable[..., Calibration] | None = field(default=None, repr=False)

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

    def validate(self, settings: Mapping[str, Any]) -> Any:
        """Check a whole ``[run.settings]`` table; returns its own settings typed
        (`Settings.parse`: defaults filled in), as its solver takes them.

        Raises SettingError for an unknown key (naming the closest valid one), a wrong type
        or a value out of bounds (naming key, value and allowed range), in a table too.
        """
        declared = self.all_settings()
        known = [*declared.items, *TABLES]
        for key, value in settings.items():
            if key in declared:
                declared.items[key].check(value)
            elif key in TABLES:
                if not isinstance(value, dict):
                    raise SettingError(key, f"expected a table of settings, got {value!r}")
                TABLES[key].validate(value, key)
            else:
                hint = did_you_mean(key, known)
                raise SettingError(key, f"unknown setting of {self.name}{hint}")
        return self.settings.parse(settings)
