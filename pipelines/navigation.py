"""Navigation performance, the pipeline glue: mission-profile files (pipelines/navprofiles/
*.toml, a lab's own in ``CALIB_NAVPROFILES``, or a file path), a trajectory CSV, a run's
archived calibration made into the error model of `calib_core.navigation` (with the unit's
thermal model and drift when the archive has them), and the figures `calib navfit`, the
certificate and `calib serve` show (docs/navigation.md).
"""

from __future__ import annotations

import csv
import math
import os
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from calib_core import navigation
from calib_core.calibration import Calibration
from calib_core.mission import (
    AIDING_KINDS,
    Aiding,
    MissionProfile,
    Segment,
    Trajectory,
    trajectory_from_segments,
)
from calib_core.settings import Setting, SettingError, Settings, key_line, key_path, typed
from storage import queries
from storage.db import Archive
from storage.naming import check_safe_name

SHIPPED = Path(__file__).resolve().parent / "navprofiles"
TRAJECTORY_COLUMNS = ("t_s", "north_m", "east_m", "down_m", "roll_deg", "pitch_deg", "yaw_deg")
THERMAL_POINTS = 11  # temperatures sampled across the profile's range


_POSITIVE = {"low": 0.0, "low_open": True}
_ZERO3 = [0.0, 0.0, 0.0]
# A mission profile file (docs/navigation.md, "Mission profiles"): its top level, [initial]
# (one-sigma initial errors), [aiding], [trajectory] and the trajectory's segments.
PROFILE = Settings(
    Setting("name", "text", "", None, "the profile's name (required)"),
    Setting("description", "text", "", "", "one line for people"),
    Setting("duration_s", "number", "s", None, "how long it runs (required)", **_POSITIVE),
    Setting("step_s", "number", "s", 0.5, "propagation step", **_POSITIVE),
    Setting("latitude_deg", "number", "deg", 45.0, "where", low=-89.0, high=89.0),
    Setting("height_m", "number", "m", 0.0, "height above the ellipsoid"),
    Setting("temperature_c", "list", "degC", [20.0, 25.0], "temperature range", length=2),
    Setting("position_limit_m", "number", "m", 10.0, "horizontal error allowed", **_POSITIVE),
    Setting("initial", "table", "", {}, "INITIAL"),
    Setting("aiding", "table", "", {}, "AIDING"),
    Setting("trajectory", "table", "", None, "TRAJECTORY (required)"),
    noun="field",
)
INITIAL = Settings(
    Setting("attitude_deg", "list", "deg", _ZERO3, "roll, pitch, yaw", length=3),
    Setting("velocity_mps", "list", "m/s", _ZERO3, "north, east, down", length=3),
    Setting("position_m", "list", "m", _ZERO3, "north, east, down", length=3),
    noun="field",
)
AIDING = Settings(
    Setting("kind", "text", "", "none", "what the fixes give", choices=AIDING_KINDS),
    Setting("interval_s", "number", "s", 1.0, "time between fixes", **_POSITIVE),
    Setting("position_std_m", "number", "m", 2.0, "a position fix's sigma", **_POSITIVE),
    Setting("velocity_std_mps", "number", "m/s", 0.1, "a velocity fix's sigma", **_POSITIVE),
    Setting("until_s", "number", "s", None, "fixes end (None: never)", low=0.0),
    Setting("height_std_m", "number", "m", None, "a height fix's sigma", **_POSITIVE),
    noun="field",
)
TRAJECTORY = Settings(
    Setting("heading_deg", "number", "deg", 0.0, "initial heading"),
    Setting("tilt_with_acceleration", "bool", "", False, "the body tilts as it accelerates"),
    Setting("segments", "list", "", [], "SEGMENT tables (or file)"),
    Setting("file", "text", "", None, "a trajectory CSV beside the profile (or segments)"),
    noun="field",
)
SEGMENT = Settings(
    Setting("duration_s", "number", "s", None, "how long (required)", **_POSITIVE),
    Setting("forward_accel_mps2", "number", "m/s^2", 0.0, "along-track acceleration"),
    Setting("yaw_rate_dps", "number", "deg/s", 0.0, "turn rate"),
    Setting("climb_accel_mps2", "number", "m/s^2", 0.0, "vertical acceleration"),
    noun="field",
)


def profile_dirs() -> list[Path]:
    extra = os.environ.get("CALIB_NAVPROFILES")
    return ([Path(extra)] if extra else []) + [SHIPPED]


def builtin_names() -> list[str]:
    """The shipped profiles' names."""
    return sorted(p.stem for p in SHIPPED.glob("*.toml"))


def profile_names() -> list[str]:
    """Every profile name a lab can choose: its own folder's and the shipped ones."""
    return sorted({p.stem for folder in profile_dirs() for p in folder.glob("*.toml")})


def find_profile(name_or_file: str) -> Path:
    """The file of profile `name_or_file`: a path to a .toml file, or a name looked up in
    the lab's folder (CALIB_NAVPROFILES) and then the shipped ones."""
    if name_or_file.endswith(".toml"):
        path = Path(name_or_file)
        if not path.is_file():
            raise ValueError(f"mission profile file {path} does not exist")
        return path
    check_safe_name(name_or_file, "mission profile name")
    for folder in profile_dirs():
        path = folder / f"{name_or_file}.toml"
        if path.is_file():
            return path
    raise ValueError(
        f"no mission profile {name_or_file!r}; built in: {', '.join(builtin_names())} "
        f"(or give a .toml file)"
    )


def load_profile(name_or_file: str) -> MissionProfile:
    """The mission profile named or given by file (docs/navigation.md, "Mission profiles").

    Raises
    ------
    ValueError naming the file and the field for a bad file.
    """
    path = find_profile(name_or_file)
    try:
        text = path.read_text(encoding="utf-8")
        return _profile(tomllib.loads(text), path)
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    except SettingError as exc:
        key = ".".join(p for p in (exc.root, exc.key) if p)
        line = key_line(text, key_path(key))
        where = "" if line is None else f" line {line}"
        raise ValueError(f"{path}{where}: field {key}: {exc.problem}") from None
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _profile(doc: dict[str, Any], path: Path) -> MissionProfile:
    spec = typed(PROFILE, doc, "", ("name", "duration_s", "trajectory"))
    tr = typed(TRAJECTORY, spec.trajectory, "trajectory")
    if (tr.file is None) == (not tr.segments):
        raise ValueError("trajectory: give either segments or file, not both or neither")
    if tr.file is not None:
        trajectory = read_trajectory(path.parent / tr.file)
    else:
        segments = [
            typed(SEGMENT, s, f"trajectory.segments[{i}]", ("duration_s",))
            for i, s in enumerate(tr.segments)
        ]
        trajectory = trajectory_from_segments(
            [
                Segment(
                    s.duration_s,
                    s.forward_accel_mps2,
                    math.radians(s.yaw_rate_dps),
                    s.climb_accel_mps2,
                )
                for s in segments
            ],
            heading=math.radians(tr.heading_deg),
            tilt_with_acceleration=tr.tilt_with_acceleration,
            step=min(0.05, spec.step_s),
        )
    a = typed(AIDING, spec.aiding, "aiding")
    ini = typed(INITIAL, spec.initial, "initial")
    return MissionProfile(
        name=spec.name,
        duration=spec.duration_s,
        trajectory=trajectory,
        latitude=math.radians(spec.latitude_deg),
        height=spec.height_m,
        temperature_range=(spec.temperature_c[0], spec.temperature_c[1]),
        aiding=Aiding(
            a.kind, a.interval_s, a.position_std_m, a.velocity_std_mps, a.until_s, a.height_std_m
        ),
        initial_std=np.concatenate(
            [np.radians(ini.attitude_deg), ini.velocity_mps, ini.position_m]
        ),
        step=spec.step_s,
        position_limit=spec.position_limit_m,
        description=spec.description,
    )


def read_trajectory(path: Path) -> Trajectory:
    """A trajectory CSV: a header with TRAJECTORY_COLUMNS (time s; North, East, Down m from
    the start; roll, pitch, yaw deg), one row per sample."""
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise ValueError(
            f"trajectory file {path}: cannot be read ({exc.strerror or exc})"
        ) from None
    if not rows or tuple(c.strip() for c in rows[0]) != TRAJECTORY_COLUMNS:
        raise ValueError(
            f"trajectory file {path}, line 1: expected the header {','.join(TRAJECTORY_COLUMNS)}"
        )
    values = []
    for i, row in enumerate(rows[1:], start=2):
        try:
            v = [float(c) for c in row]
        except ValueError:
            raise ValueError(f"trajectory file {path}, line {i}: expected 7 numbers") from None
        if len(v) != 7 or not all(map(math.isfinite, v)):
            raise ValueError(f"trajectory file {path}, line {i}: expected 7 finite numbers")
        values.append(v)
    a = np.array(values).reshape(-1, 7)
    try:
        return Trajectory(a[:, 0] - (a[0, 0] if len(a) else 0.0), a[:, 1:4], np.radians(a[:, 4:7]))
    except ValueError as exc:
        raise ValueError(f"trajectory file {path}: {exc}") from None


def thermal_residuals(model_doc: dict[str, Any], profile: MissionProfile) -> tuple[dict, list]:
    """Each compensated parameter's residual after compensation: the standard uncertainty of
    its fitted curve (`ParameterCurve.std`), the largest across THERMAL_POINTS temperatures
    of the profile's range. The scatter of one run about the curve is the run's own u (a
    source of its own), not counted again. Temperatures beyond the model's range are noted:
    the curve is clipped there and the residual beyond is not known."""
    from calib_core.thermal import ThermalModel

    tm = ThermalModel.from_dict(model_doc)
    temps = np.linspace(*profile.temperature_range, THERMAL_POINTS)
    notes = []
    if temps.min() < tm.t_min or temps.max() > tm.t_max:
        notes.append(
            f"the profile's {profile.temperature_range[0]:g}..{profile.temperature_range[1]:g} "
            f"deg C exceed the thermal model's {tm.t_min:g}..{tm.t_max:g} deg C: the residual "
            "beyond its range is not known and not included"
        )
    return {name: float(np.max(tm.std(name, temps))) for name in tm.curves}, notes


def drift_at_interval(recall: dict[str, Any] | None) -> tuple[dict[str, float], list[str]]:
    """The change each parameter's drift line predicts by the end of the unit's
    recalibration interval (rate x interval), from `pipelines.recall.unit_recall`."""
    if not recall or not recall.get("drift_rates"):
        return {}, ["no drift line for this unit (fewer than 3 calibrations, or not its latest)"]
    years = float(recall["interval_days"]) / 365.25
    return {n: abs(r) * years for n, r in recall["drift_rates"].items()}, []


def unit_error_model(
    archive: Archive,
    run_id: str,
    profile: MissionProfile,
    recalls: Mapping[str, dict[str, Any]] | None = None,
) -> tuple[navigation.ErrorModel, dict[str, Any]]:
    """The error model of the calibration of `run_id` (current revision) on `profile`, and
    what it was built from ({"serial", "model", "revision", "procedure", "thermal_model",
    "interval_days", "notes"}). `recalls`: `pipelines.recall.recall_list`'s entries by
    serial when the caller has them (a fleet), else the unit's is looked up."""
    from pipelines.recall import unit_recall

    doc = queries.export_calibration(archive, run_id, None)
    cal = Calibration.from_dict(doc["calibration"])
    serial = doc["unit"]["serial"]
    u = {name: p.std for name, p in cal.parameters.items()}
    cov = {}
    for a, pa in cal.parameters.items():
        for b, pb in cal.parameters.items():
            if a != b and pa.cov_index is not None and pb.cov_index is not None:
                cov[a, b] = float(cal.covariance[pa.cov_index, pb.cov_index])
    noise = cal.info.get("noise_parameters") or {}
    notes = [
        f"{n}: no stated uncertainty, left out"
        for n, s in u.items()
        if s is None and not (n.split(".")[1] == "noise" and noise.get(n.split(".")[0]))
    ]
    tm = queries.latest_thermal_model(archive, serial, None)
    thermal, more = ({}, ["no thermal model: temperature effects not included"])
    if tm is not None:
        thermal, more = thermal_residuals(tm["document"], profile)
    notes += more
    try:
        if recalls is None:
            recall = unit_recall(archive, serial, run_id)
        else:  # the drift of the unit's latest run only, as unit_recall
            recall = recalls.get(serial)
            recall = recall if recall and recall["run_id"] == run_id else None
    except (LookupError, ValueError) as exc:
        recall, notes = None, notes + [f"drift not included: {exc}"]
    drift, more = drift_at_interval(recall)
    model = navigation.error_model(
        {n: s for n, s in u.items() if s is not None},
        noise,
        covariance=cov,
        thermal=thermal,
        drift=drift,
    )
    notes = list(dict.fromkeys([*notes, *more, *model.notes]))
    return model, {
        "serial": serial,
        "model": doc["unit"]["model"],
        "revision": doc["revision"],
        "procedure": cal.procedure,
        "thermal_model": None if tm is None else tm["id"],
        "interval_days": None if recall is None else recall.get("interval_days"),
        "notes": notes,
    }


# Figures as shown: output group -> (key, unit, scale from SI)
SHOWN = {
    "roll": ("roll_deg", "deg", math.degrees(1.0)),
    "pitch": ("pitch_deg", "deg", math.degrees(1.0)),
    "heading": ("heading_deg", "deg", math.degrees(1.0)),
    "horizontal_velocity": ("horizontal_velocity_mps", "m/s", 1.0),
    "vertical_velocity": ("vertical_velocity_mps", "m/s", 1.0),
    "horizontal_position": ("horizontal_position_m", "m", 1.0),
    "vertical_position": ("vertical_position_m", "m", 1.0),
}
SERIES_POINTS = 200
# Tilt (1 sigma) beyond which first-order theory is not to be trusted: against the full
# mechanisation (tests/test_navigation.py), at 0.5 deg every figure agreed within 4 %, at
# 5 deg the vertical velocity error was twice the covariance's (the g phi^2 / 2 term).
LINEAR_TILT_DEG = 1.0


def navfit(
    archive: Archive,
    run_id: str,
    profile: MissionProfile,
    position_limit: float | None = None,
    recalls: Mapping[str, dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """The navigation performance of the calibration of `run_id` on `profile`: JSON-ready.

    Returns
    -------
    {"run_id", "serial", "model", "revision", "procedure", "profile": {...},
    "end": {figure: {"sigma", "p95", "unit"}}, "position_limit_m", "time_to_limit_s",
    "dominant": {figure: source}, "shares": {figure: {source: share}},
    "series": {"t_s": [...], figure: {"sigma": [...], "p95": [...]}}, "notes": [...]}
    (deg, m/s, m, s). Horizontal figures: sigma = the root sum of the two axes' variances,
    p95 = the radius holding 95 % of the 2-D error.
    """
    model, meta = unit_error_model(archive, run_id, profile, recalls)
    prop = navigation.propagate(profile, model)
    limit = profile.position_limit if position_limit is None else float(position_limit)
    perf = navigation.performance(prop, limit, free_from=_free_from(profile))
    a = profile.aiding
    out: dict[str, Any] = {
        "run_id": run_id,
        **{k: meta[k] for k in ("serial", "model", "revision", "procedure")},
        "profile": {
            "name": profile.name,
            "description": profile.description,
            "duration_s": profile.duration,
            "aiding": a.kind,
            # fixes end (None: fixes all along); 0 without aiding
            "outage_start_s": a.until if a.kind != "none" else 0.0,
            "height_aiding": a.height_std is not None,
            "temperature_c": list(profile.temperature_range),
            "latitude_deg": math.degrees(profile.latitude),
        },
        "end": {},
        "position_limit_m": limit,
        "free_from_s": _free_from(profile),
        "time_to_limit_s": perf["time_to_limit"],
        "dominant": {},
        "shares": {},
        "series": {},
        "error_sources": [s.name for s in model.sources],
        "thermal_model": meta["thermal_model"],
        "interval_days": meta["interval_days"],
        "notes": list(meta["notes"]),
    }
    tilt = math.degrees(float(np.max(prop.sigma()[:, :2])))
    if round(tilt, 6) > LINEAR_TILT_DEG:  # a profile's initial 1 deg is within
        out["notes"].append(
            f"the tilt error reaches {tilt:.2g} deg (1 sigma): beyond {LINEAR_TILT_DEG:g} deg "
            "the linear error model leaves out second-order terms (g phi^2 / 2 in the vertical "
            "channel): the figures are a first-order estimate, the vertical ones too small"
        )
    idx = np.unique(np.linspace(0, prop.t.size - 1, SERIES_POINTS).round().astype(int))
    out["series"]["t_s"] = prop.t[idx].tolist()
    for group, (key, unit, scale) in SHOWN.items():
        sig, p95 = _group_series(perf, group)
        out["end"][key] = {"sigma": sig[-1] * scale, "p95": p95[-1] * scale, "unit": unit}
        out["series"][key] = {
            "sigma": (sig[idx] * scale).tolist(),
            "p95": (p95[idx] * scale).tolist(),
        }
        out["dominant"][key] = perf["dominant"][group]
        out["shares"][key] = perf["shares"][group]
    return out


def _free_from(profile: MissionProfile) -> float:
    """When free inertial navigation starts: the outage, or 0 s without aiding."""
    a = profile.aiding
    if a.kind == "none":
        return 0.0
    return profile.duration if a.until is None else min(a.until, profile.duration)


def _group_series(perf: dict[str, Any], group: str) -> tuple[np.ndarray, np.ndarray]:
    """(sigma, p95) over time of one output group, SI."""
    s = perf["sigma"]
    if group in ("horizontal_velocity", "horizontal_position"):
        kind = group.split("_")[1]
        sig = np.hypot(s[f"{kind}_north"], s[f"{kind}_east"])
        return sig, perf[f"{group}_95"]
    name = {"vertical_velocity": "velocity_down", "vertical_position": "position_down"}.get(
        group, group
    )
    return s[name], navigation.Z95 * s[name]
