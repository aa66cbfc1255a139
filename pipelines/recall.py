"""Recalibration intervals, the pipeline glue: each unit's interval from its own drift and its
model's fleet (calib_core.interval; method and reliability target in the tolerance profile's
``[recall]``), and the units due before a date (`calib query due`, docs/interval.md).
"""

from __future__ import annotations

import math
from datetime import date, timedelta
from typing import Any

from calib_core import drift, interval
from calib_core.checks import FAIL
from calib_core.tolerances import ALL_NAMES, ToleranceProfile
from pipelines.trends import days_since_epoch, pooled_runs
from storage import queries
from storage.db import Archive

DAYS_PER_MONTH = 365.25 / 12.0


def _one_condition(rows: Any) -> Any:
    """A unit's calibrations at one lab temperature (`pipelines.trends.pooled_runs`): runs
    of a thermal campaign differ by the temperature effect, which a line over the dates
    would read as a drift of days, and so set an interval of days for the whole fleet."""
    temps = [
        None if t is None or (isinstance(t, float) and math.isnan(t)) else float(t)
        for t in rows["temperature_c"]
    ]
    return rows.iloc[pooled_runs(temps).indices]


def _stds(rows: Any) -> list[float | None]:
    """The standard uncertainties of a parameter's rows, None where none is stated (the
    noise terms of a static-bias run carry none)."""
    return [
        None if s is None or (isinstance(s, float) and math.isnan(s)) else float(s)
        for s in rows["std"]
    ]


def _own_slope(rows: Any) -> tuple[float | None, float | None]:
    """(slope, variance) of one unit's trend (SI / day), or (None, None) below 3 points."""
    stds = _stds(rows)
    days = [days_since_epoch(t) for t in rows["started_at"]]
    try:
        if all(s is not None and s > 0 for s in stds):  # stated uncertainties, not rescaled
            tr = drift.fit_trend_shared(
                days, rows["value"].to_numpy(), stds, [0.0] * len(stds), [None] * len(stds)
            )
        else:
            tr = drift.fit_trend(days, rows["value"].to_numpy(), stds)
    except ValueError:  # fewer than 3 calibrations or one date: no trend of its own
        return None, None
    return tr.slope, float(tr.cov[1, 1]) if tr.cov[1, 1] > 0 else None


def model_intervals(
    archive: Archive, model: str, profile: ToleranceProfile, serials: list[str]
) -> dict[str, dict[str, Any]]:
    """{serial: {"days", "parameter", "capped", "probability", "parameters"}} for the units of
    one model judged by one profile ("variables" method), from every parameter with a limit."""
    rel = float(profile.recall["reliability"])
    max_days = float(profile.recall["max_months"]) * DAYS_PER_MONTH
    out: dict[str, dict[str, Any]] = {s: {"parameters": []} for s in serials}
    for name in ALL_NAMES:
        lim = profile.limit_for(name)
        if lim is None:
            continue
        hist = queries.fleet_history(archive, model, name)
        if hist.empty:
            continue
        by_unit = {s: _one_condition(g) for s, g in hist.groupby("serial")}
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
            days = [days_since_epoch(t) for t in rows["started_at"]]
            try:
                line = interval.predict_line(days, rows["value"].to_numpy(), stds, fleet)
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

    units = queries.units(archive)
    if units.empty:
        return []
    units = units.sort_values(["started_at", "run_id"]).drop_duplicates("serial", keep="last")
    if serial is not None:
        units = units[units["model"].isin(units.loc[units["serial"] == serial, "model"])]
    profiles: dict[str, ToleranceProfile] = {}
    groups: dict[tuple[str, str], list[str]] = {}
    last: dict[str, dict[str, Any]] = {}
    for row in units.itertuples(index=False):  # each unit's latest run
        if serial is not None and row.serial != serial:
            continue
        name = queries.run_summary(archive, row.run_id)["tolerance_profile"]
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
