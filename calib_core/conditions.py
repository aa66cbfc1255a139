"""Lab conditions and acquisition rules of a run, measured on its data and judged.

docs/methods.md 3.10 sets conditions a run must be made under; recording them is not enough, each
is judged and printed as one verdict line of the "conditions" section of the protocol and
the certificate. Which conditions apply is the run's procedure's declaration
(`calib_core.procedures`, its ``conditions``); their limits, severity and wording are the
catalogue `calib_core.condition_rules` (re-exported here); this module measures each on the
run's segments and judges it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from calib_core.calibration import CheckResult
from calib_core.condition_rules import (  # noqa: F401  (the catalogue's names, re-exported)
    CONDITION_PREFIX,
    DEFAULT_CONDITIONS,
    FAILURE,
    INFO,
    NOT_RECORDED,
    WARNING,
    Condition,
    ConditionUse,
    conditions,
    counts_against_verdict,
    judge,
    parse_conditions,
    requirement,
    status,
)
from calib_core.preprocess.motion import is_rotation
from calib_core.recording import Recording
from calib_core.streamed import RecordSummary
from calib_core.units import ARCSEC, DEG

if TYPE_CHECKING:  # the procedures (every solver, scipy) load where a run is judged: the
    # readers of archived checks (`status`, `calib show`) need none of them
    from calib_core import procedures

ZERO_RATE = 1e-6  # rad/s: a plateau below this is a 0-rate (static) point
# Reference channels of the lab's own temperature (chamber or ambient), deg C.
CHAMBER_CHANNELS = ("chamber_temperature", "ambient_temperature")


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


def temperature_block(rec: Recording | RecordSummary) -> int:
    """Samples per mean of `temperature_spread`: about one second's."""
    return max(1, int(round(_rate_hz(rec))))


def _statics(segments: Mapping[str, Recording]) -> dict[str, Recording]:
    """Segments at rest: neither a turn nor a moving plateau."""
    out = {}
    for label, rec in segments.items():
        rate = plateau_rate(rec)
        if not is_rotation(label) and (rate is None or abs(rate) <= ZERO_RATE):
            out[label] = rec
    return out


def _temperature(rec: Recording, channel: str | None) -> np.ndarray | None:
    """The sensor's temperature (`channel` None) or a reference channel, deg C."""
    temp = rec.temp if channel is None else rec.reference.get(channel)
    return None if temp is None else np.asarray(temp, dtype=float)


def temperature_spread(
    records: Mapping[str, Recording], channel: str | None = None
) -> tuple[float | None, str]:
    """Largest minus smallest 1-s mean temperature over all records, deg C.

    `channel` None takes the sensor's temperature, else that reference channel (the
    chamber's). 1-s means keep the temperature noise and the 0.1 deg C display step from
    counting as a spread. None when no record has the channel.
    """
    means: list[tuple[float, str]] = []
    for label, rec in records.items():
        if isinstance(rec, RecordSummary):  # streamed: its means kept while read
            if channel is None and rec.temp_means is not None:
                means += [(float(m), label) for m in rec.temp_means]
            continue
        temp = _temperature(rec, channel)
        if temp is None or not np.isfinite(temp).any():
            continue
        block = temperature_block(rec)
        temp = temp[np.isfinite(temp)]
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
        if isinstance(rec, RecordSummary):  # streamed: its trend kept while read
            if rec.temp_slope is not None and rec.duration >= 600.0:
                slopes.append((abs(rec.temp_slope) * 3600.0, label))
            continue
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


# The table's position feedback channels (rad): a one-axis table's angle, a two-axis
# table's pitch / roll (or azimuth / pitch).
POSITION_CHANNELS = ("table_angle", "table_pitch", "table_roll", "table_azimuth")


def table_position_deviation(segments: Mapping[str, Recording]) -> tuple[float | None, str]:
    """Largest span (max - min) of the 1-s means of a position feedback channel over a
    held segment (settle and record), arcsec; None when no held segment has one.

    The rate-table procedure limits the table position deviation during settling and the
    static run to 5 arcsec; the commanded position is not recorded, so the deviation is
    taken as the span of the held position (docs/methods.md 3.10). 1-s means keep the
    encoder's noise from counting as a deviation.
    """
    worst: tuple[float, str, str] | None = None
    streamed = []
    for label, rec in _statics(segments).items():
        if isinstance(rec, RecordSummary):  # streamed: its feedback is not kept
            streamed.append(label)
            continue
        for channel in POSITION_CHANNELS:
            angle = rec.reference.get(channel)
            angle = None if angle is None else np.asarray(angle, dtype=float)
            if angle is None or not np.isfinite(angle).any():
                continue
            angle = angle[np.isfinite(angle)]
            k = max(1, len(angle) // temperature_block(rec))
            means = [float(chunk.mean()) for chunk in np.array_split(angle, k)]
            span = (max(means) - min(means)) / ARCSEC
            if worst is None or span > worst[0]:
                worst = (span, label, channel)
    if worst is None:
        note = f"; records streamed: {', '.join(streamed)}" if streamed else ""
        return None, f"no table position feedback ({', '.join(POSITION_CHANNELS)}){note}"
    return worst[0], f"span of the 1-s means of {worst[2]}, worst segment {worst[1]}"


# Conditions the lab states (manifest [environment] / [acquisition], the model's data sheet).
RECORDED_KEYS = ("ambient_temperature_c", "humidity_pct", "pressure_hpa", "warmup_min")
# The equipment pre-check of the rate-table procedure (the lab's equipment records).
PRECHECK_KEYS = (
    "table_angle_accuracy_arcsec",
    "table_axis_perpendicularity_arcsec",
    "power_stability_pct",
    "imu_table_parallelism_arcsec",
)


def check_conditions(
    segments: Mapping[str, Recording],
    recorded: Mapping[str, float | None],
    *,
    procedure: str | procedures.Procedure,
    settings: Mapping[str, Any],
    gravity: float,
    gravity_source: str | None,
    overrides: Mapping[str, Mapping[str, float]] | None = None,
) -> list[CheckResult]:
    """Every condition that applies to the run, one CheckResult ``condition:<key>`` each.

    Parameters
    ----------
    segments : the run's segments as acquired (before preprocessing), SI units; a record
        streamed in chunks as its `calib_core.streamed.RecordSummary`.
    recorded : what the lab recorded: the RECORDED_KEYS, the PRECHECK_KEYS,
        ``temperature_drift_c_per_h``,
        ``resolution_bits`` and ``settle_s`` (before each attitude); None or absent: not
        recorded.
    procedure : the run's procedure (or its name): its ``conditions`` are the ones judged.
    settings : the run's settings (the procedure's defaults are filled in); a rate table's
        ``settle_s`` / ``record_s`` are the plateau's settle and record times (the solver
        drops the settle); a procedure without ``settle_s`` drops none.
    gravity : the gravity used, m/s^2.
    gravity_source : how it was obtained ("Helmert at 48.137 deg, 519 m"); None when it is
        the standard value for want of the site's (a warning).
    overrides : the profile's ``[conditions]`` limits.
    """
    from calib_core import procedures

    proc = procedures.get(procedure) if isinstance(procedure, str) else procedure
    conds = conditions(overrides)
    out = [judge(conds[k], recorded.get(k)) for k in RECORDED_KEYS + PRECHECK_KEYS]
    drift = recorded.get("temperature_drift_c_per_h")
    out.append(
        judge(
            conds["temperature_drift_c_per_h"],
            *((abs(drift), "recorded") if drift is not None else temperature_drift(segments)),
        )
    )
    out.append(_gravity_check(conds["gravity"], gravity, gravity_source))
    # The procedure's settings as its solver uses them: a rate table's settle_s default.
    out += _acquisition_checks(segments, recorded, proc.settings.parse(settings), conds)
    out += _temperature_checks(segments, conds)
    out.append(judge(conds["table_position_arcsec"], *table_position_deviation(segments)))
    applies = {CONDITION_PREFIX + key for key in proc.condition_keys()}
    if CONDITION_PREFIX + "zero_position_min" in applies:
        out += _centrifuge_checks(segments, conds)
    return [c for c in out if c.name in applies]


def _gravity_check(cond: Condition, gravity: float, source: str | None) -> CheckResult:
    if source is not None:
        return CheckResult(CONDITION_PREFIX + cond.key, gravity, None, True, source)
    return CheckResult(
        CONDITION_PREFIX + cond.key,
        gravity,
        None,
        False,
        "standard value: the site's latitude and height are not known (give them in the "
        "manifest's [site] or the lab file); the MPU-6000 manual uses Helmert's formula "
        "with the height correction",
    )


def _acquisition_checks(
    segments: Mapping[str, Recording],
    recorded: Mapping[str, float | None],
    settings: Any,
    conds: dict[str, Condition],
) -> list[CheckResult]:
    """Sampling, resolution, settle and record times, static record length, table rate
    (`settings`: the procedure's typed settings; settle_s and record_s where it has them)."""
    if not segments:
        return []
    rate = min((_rate_hz(r), label) for label, r in segments.items())
    out = [
        judge(conds["sample_rate_hz"], rate[0], f"segment {rate[1]}"),
        judge(conds["resolution_bits"], recorded.get("resolution_bits")),
    ]
    plateaus = {k: r for k, r in segments.items() if plateau_rate(r) is not None}
    attitudes = {k: r for k, r in segments.items() if k not in plateaus and not is_rotation(k)}
    # The settle its solver drops from each plateau; a procedure without one drops none.
    given = getattr(settings, "settle_s", None) if plateaus else None
    settle = 0.0 if given is None else float(given)
    records = [(r.duration, k) for k, r in attitudes.items()]
    if given is not None:
        out.append(judge(conds["settle_rate_s"], settle, "the solver drops it from each plateau"))
    if plateaus:
        window = getattr(settings, "record_s", None)
        records += [
            (min(r.duration - settle, float(window or math.inf)), k) for k, r in plateaus.items()
        ]
        out += _table_checks(plateaus, settle, conds)
    if attitudes:
        out.append(judge(conds["settle_s"], recorded.get("settle_s")))
    if records:
        out.append(judge(conds["record_s"], min(records)[0], f"segment {min(records)[1]}"))
    longest = max(r.duration for r in segments.values()) / 60.0
    out.append(judge(conds["static_record_min"], longest))
    return out


def _centrifuge_checks(
    segments: Mapping[str, Recording], conds: dict[str, Condition]
) -> list[CheckResult]:
    """The centrifuge paper's durations: each zero position 3 min, each g step 5 min
    (docs/methods.md 2.8); the shortest of each kind is judged."""
    from calib_core.solvers.centrifuge_segments import step_label, steps_from_segments

    try:
        steps = steps_from_segments(segments)
    except ValueError as exc:  # the solve names the label; no duration to judge
        return [judge(conds[k], None, str(exc)) for k in ("zero_position_min", "g_step_min")]
    out = []
    for key, kinds in (("zero_position_min", ("zero", "zero_after")), ("g_step_min", ("step",))):
        found = [(s.recording.duration / 60.0, step_label(s)) for s in steps if s.kind in kinds]
        worst = min(found) if found else (None, "none in the run")
        out.append(judge(conds[key], worst[0], f"segment {worst[1]}" if found else worst[1]))
    return out


def _temperature_checks(
    segments: Mapping[str, Recording], conds: dict[str, Condition]
) -> list[CheckResult]:
    """The chamber's temperature spread over the static records (its reference channel,
    else the sensor's own), and the sensor's spread over the whole run (information)."""
    statics = _statics(segments)
    channel = next(
        (c for c in CHAMBER_CHANNELS if any(c in r.reference for r in statics.values())), None
    )
    spread, note = temperature_spread(statics, channel)
    where = f"reference channel {channel}" if channel else "no chamber channel: the sensor's"
    out = [judge(conds["static_temperature_spread_c"], spread, f"{where}; {note}")]
    spread, note = temperature_spread(segments)
    out.append(judge(conds["sensor_temperature_spread_c"], spread, note))
    return out
