"""Recalibration intervals, the pipeline glue: each unit's interval from its own drift and its
model's fleet (calib_core.interval; method and reliability target in the tolerance profile's
``[recall]``), and the units due before a date (`calib query due`, docs/interval.md).
"""

from __future__ import annotations

import math
from collections import namedtuple
from datetime import date, timedelta
from typing import TYPE_CHECKING, Any

import numpy as np

from calib_core import drift, interval
from calib_core.checks import FAIL
from calib_core.tolerances import ALL_NAMES, ToleranceProfile
from pipelines.trends import days_since_epoch, pooled_runs
from storage import queries
from storage.db import Archive

if TYPE_CHECKING:
    from sqlalchemy import Row

DAYS_PER_MONTH = 365.25 / 12.0
_Unit = namedtuple("_Unit", queries.UNIT_COLUMNS)  # a row of queries.units(frame=False)


def _one_condition(rows: list[Row]) -> list[Row]:
    """A unit's calibrations at one lab temperature (`pipelines.trends.pooled_runs`): runs
    of a thermal campaign differ by the temperature effect, which a line over the dates
    would read as a drift of days, and so set an interval of days for the whole fleet."""
    temps = [_stated(r.temperature_c) for r in rows]
    return [rows[i] for i in pooled_runs(temps).indices]


def _stated(x: float | None) -> float | None:
    """A value as a float, None where none is stated (NULL or NaN)."""
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else float(x)


def _stds(rows: list[Row]) -> list[float | None]:
    """The standard uncertainties of a parameter's rows, None where none is stated (the
    noise terms of a static-bias run carry none)."""
    return [_stated(r.std) for r in rows]


def _days_values(rows: list[Row]) -> tuple[list[float], np.ndarray]:
    """The rows' dates (days since the epoch) and values (SI)."""
    values = np.array([np.nan if r.value is None else r.value for r in rows], dtype=float)
    return [days_since_epoch(r.started_at) for r in rows], values


def _own_slope(rows: list[Row]) -> tuple[float | None, float | None]:
    """(slope, variance) of one unit's trend (SI / day), or (None, None) below 3 points."""
    stds = _stds(rows)
    days, values = _days_values(rows)
    try:
        if all(s is not None and s > 0 for s in stds):  # stated uncertainties, not rescaled
            tr = drift.fit_trend_shared(days, values, stds, [0.0] * len(stds), [None] * len(stds))
        else:
            tr = drift.fit_trend(days, values, stds)
    except ValueError:  # fewer than 3 calibrations or one date: no trend of its own
        return None, None
    return tr.slope, float(tr.cov[1, 1]) if tr.cov[1, 1] > 0 else None


def model_intervals(
    archive: Archive, model: str, profile: ToleranceProfile, serials: list[str]
) -> dict[str, dict[str, Any]]:
    """{serial: {"days", "parameter", "capped", "probability", "parameters"}} for the units of
    one model judged by one profile ("variables" method), from every parameter with a limit
    (their histories asked of the archive in one question)."""
    rel = float(profile.recall["reliability"])
    max_days = float(profile.recall["max_months"]) * DAYS_PER_MONTH
    out: dict[str, dict[str, Any]] = {s: {"parameters": []} for s in serials}
    limits = {n: lim for n in ALL_NAMES if (lim := profile.limit_for(n)) is not None}
    history: dict[str, dict[str, list[Row]]] = {}
    for row in queries.fleet_histories(archive, model, list(limits)):
        history.setdefault(row.name, {}).setdefault(row.serial, []).append(row)
    for name, lim in limits.items():
        units = history.get(name)
        if not units:
            continue
        by_unit = {s: _one_condition(units[s]) for s in sorted(units)}
        slopes = {s: _own_slope(g) for s, g in by_unit.items()}
        have = [(b, v) for b, v in slopes.values() if b is not None and v is not None]
        fleet = drift_of_fleet(have)
        for serial in serials:
            rows = by_unit.get(serial)
            if rows is None:
                continue
            stds = _stds(rows)
            if not all(x is not None and x > 0 for x in stds):  # no stated uncertainty:
                continue  # no prediction (a noise term has none: its value is a spread)
            days, values = _days_values(rows)
            try:
                line = interval.predict_line(days, values, stds, fleet)
            except ValueError:
                continue  # one date and no fleet: this parameter sets nothing
            iv = interval.interval(line, lim.low, lim.high, rel, max_days=max_days)
            out[serial]["parameters"].append(
                {
                    "name": name,
                    "days": iv.days,
                    "capped": iv.capped,
                    "probability": iv.probability,
                    "rate_per_year": line.rate * 365.25,
                }
            )
    for entry in out.values():
        if entry["parameters"]:
            worst = min(entry["parameters"], key=lambda p: p["days"])
            entry |= {
                "days": worst["days"],
                "parameter": worst["name"],
                "capped": worst["capped"],
                "probability": worst["probability"],
            }
    return out


def drift_of_fleet(slopes: list[tuple[float, float]]) -> interval.FleetDrift | None:
    """The fleet's drift rates pooled, or None with fewer than 2 units with a trend."""
    if len(slopes) < 2:
        return None
    return interval.fleet_drift([b for b, _ in slopes], [v for _, v in slopes])


def recall_list(
    archive: Archive, before: date | None = None, *, serial: str | None = None
) -> list[dict[str, Any]]:
    """Every unit with its last calibration, interval, due date; only those due on or before
    `before` when given (only `serial` when given), earliest due first."""
    from pipelines.lab import customer_name
    from pipelines.tolerances import load_profile

    runs = sorted(queries.units(archive, frame=False), key=lambda r: (r[4], r[3]))  # start, run id
    last_of = {r[0]: i for i, r in enumerate(runs)}
    units = [_Unit(*r) for i, r in enumerate(runs) if last_of[r[0]] == i]
    profiles: dict[str, ToleranceProfile] = {}
    groups: dict[tuple[str, str], list[str]] = {}
    last: dict[str, dict[str, Any]] = {}
    for row in units:  # each unit's latest run
        if serial is not None and row.serial != serial:
            continue
        name = queries.run_summary(archive, row.run_id).tolerance_profile
        if name not in profiles:
            profiles[name] = load_profile(name)
        groups.setdefault((row.model, name), []).append(row.serial)
        last[row.serial] = {
            "run_id": row.run_id,
            "started_at": row.started_at,
            "verdict": row.verdict,
            "model": row.model,
            "profile": name,
        }
    owner = customer_name()
    out = []
    for (model, pname), serials in groups.items():
        prof = profiles[pname]
        method = prof.recall["method"]
        found = model_intervals(archive, model, prof, serials) if method == "variables" else {}
        for unit in serials:
            out.append(_entry(unit, model, prof, found.get(unit, {}), last[unit], owner))
    if before is not None:
        out = [e for e in out if date.fromisoformat(e["due"]) <= before]
    return sorted(out, key=lambda e: (e["due"], e["serial"]))


def _entry(
    serial: str,
    model: str,
    prof: ToleranceProfile,
    entry: dict[str, Any],
    last: dict[str, Any],
    owner: str | None,
) -> dict[str, Any]:
    """One unit's row: its interval (or the profile's fixed one, saying why) and due date."""
    days = entry.get("days")
    how = f"variables, R = {float(prof.recall['reliability']):g}" + (
        f", capped at {prof.recall['max_months']:g} months" if entry.get("capped") else ""
    )
    if last["verdict"] == FAIL:  # not released: no interval runs from a failed calibration
        days, entry = 0.0, {}
        how = "due now: its last calibration failed"
    elif days is None:  # fixed method, or no parameter with a limit and a drift
        days = float(prof.recall["fixed_months"]) * DAYS_PER_MONTH
        fallback = "" if prof.recall["method"] == "fixed" else " (no drift to judge by)"
        how = f"fixed {prof.recall['fixed_months']:g} months{fallback}"
    due = (last["started_at"] + timedelta(days=days)).date()
    return {
        "serial": serial,
        "model": model,
        **last,
        "owner": owner or "not recorded",
        "interval_days": round(days, 1),
        "interval_months": round(days / DAYS_PER_MONTH, 1),
        "limiting_parameter": entry.get("parameter"),
        "capped": entry.get("capped"),
        "reliability": float(prof.recall["reliability"]),
        "method": how,
        "due": due.isoformat(),
        # each limited parameter's drift line, per year (SI): navigation's drift source
        "drift_rates": {p["name"]: p["rate_per_year"] for p in entry.get("parameters", [])},
    }


def unit_recall(archive: Archive, serial: str, run_id: str) -> dict[str, Any] | None:
    """The interval of `serial` when `run_id` is its latest run (the certificate's
    recommendation), else None: an older run's certificate is not judged by later data."""
    rows = recall_list(archive, serial=serial)
    return rows[0] if rows and rows[0]["run_id"] == run_id else None
