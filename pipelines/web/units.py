"""Pages of units and fleets: a unit's parameter history with tolerance band, trend and
forecast (calib_core.drift) and its thermal model curves; a device model's fleet."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from datetime import timedelta
from typing import TYPE_CHECKING, Any

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse

from calib_core import params
from pipelines.reports.display import limit_text, shown
from pipelines.tolerances import load_profile
from pipelines.web import forms, svg
from pipelines.web.pages import render
from pipelines.web.present import display, lineage_url
from storage import queries

if TYPE_CHECKING:  # the fits' science (numpy, scipy) is imported by the pages that fit
    from calib_core import drift
    from calib_core.tolerances import ToleranceProfile

router = APIRouter()

FORECAST_HORIZON_DAYS = 3650.0
FLEET_LIST_MAX = 200
FLEET_PARAMETERS = (
    params.ACC_LINEAR
    + params.GYR_LINEAR
    + params.GSENS
    + [f"{s}.noise.{a}" for s in ("acc", "gyr") for a in params.AXES]
)
THERMAL_GROUPS = ("acc.bias", "gyr.bias", "acc.scale", "gyr.scale")


def _profile(name: str | None) -> ToleranceProfile | None:
    """A tolerance profile by name (lab folder first), None when unnamed or not found."""
    if not name:
        return None
    try:
        return load_profile(name)
    except ValueError:
        return None


def _band(profile: ToleranceProfile | None, name: str) -> tuple[float, float]:
    lim = None if profile is None else profile.limit_for(name)
    return (-math.inf, math.inf) if lim is None else (lim.low, lim.high)


@dataclass
class Series:
    """One parameter of one unit over its runs (one value per run), SI."""

    name: str
    unit: str
    rows: list[dict[str, Any]]
    low: float = -math.inf
    high: float = math.inf
    trend: drift.Trend | None = None
    forecast: drift.Forecast | None = None
    note: str = ""

    pooled: str = ""  # which runs the trend compares ("3 of 4 runs, at 20 deg C")

    def fit(self, references: dict[str, dict[str, Any]] | None = None) -> None:
        """Trend and tolerance forecast (calib_core.drift) of the runs at one condition
        (`pipelines.trends.pooled_runs`: like with like); a note says why not when it can't.
        With the runs' `references` (`storage.queries.run_references`), the fit
        `calib trend` makes: runs on one reference share its Type B
        (`pipelines.shared_reference`), else the independent fit."""
        import numpy as np

        from calib_core import drift
        from pipelines import shared_reference
        from pipelines.trends import TREND_MIN_RUNS, pooled_runs
        from storage.unit_latest import REFERENCE_C

        like = pooled_runs([r.get("env_temperature_c") for r in self.rows], REFERENCE_C)
        rows = [self.rows[i] for i in like.indices]
        self.pooled = like.said(len(self.rows))
        if len(like.conditions) > 1 and len(rows) < TREND_MIN_RUNS:
            self.note = like.note
            return
        t = [svg.days(r["started_at"]) for r in rows]
        stds = [r["std"] if r["std"] is not None and r["std"] > 0 else None for r in rows]
        values = [r["value"] for r in rows]
        shared = None
        if references is not None:
            ids = [r["run_id"] for r in rows]
            shared = shared_reference.trend_inputs_of(references, ids, self.name, stds)
        try:
            if shared is None:
                self.trend = drift.fit_trend(t, values, stds)
            else:
                self.trend = drift.fit_trend_shared(np.asarray(t), np.asarray(values), *shared)
        except ValueError as exc:
            self.note = str(exc)
            return
        if math.isfinite(self.low) or math.isfinite(self.high):
            self.forecast = drift.forecast_exit(
                self.trend, self.low, self.high, horizon_days=FORECAST_HORIZON_DAYS
            )

    def summary(self) -> dict[str, Any]:
        last = self.rows[-1]
        scale = display(self.name, 1.0)[0]
        out = {
            "name": self.name,
            "n": len(self.rows),
            "last": last,
            "unit": display(self.name, 0.0)[1],
            "last_value": last["value"] * scale,
            "last_std": None if last["std"] is None else last["std"] * scale,
            "slope_per_year": None,
            "slope_std_per_year": None,
            "leaves": None,
            "earliest": None,
            "out_now": None,
            "note": self.note,
            "pooled": self.pooled,
            "shown": shown(self.name, last["value"], last["std"]),
            "spark": svg.sparkline([r["value"] for r in self.rows]),
            "band": _band_text(self.low * scale, self.high * scale),
        }
        if self.trend is not None:
            out["slope_per_year"] = self.trend.slope * 365.25 * scale
            out["slope_std_per_year"] = self.trend.slope_std * 365.25 * scale
            # per year, rounded as every value with its u (the unit's own factor applies)
            out["slope_shown"] = shown(
                self.name, self.trend.slope * 365.25, self.trend.slope_std * 365.25
            )
        if self.forecast is not None:
            out["leaves"] = _date(self.forecast.crossing)
            out["earliest"] = _date(self.forecast.earliest)
            out["out_now"] = self.forecast.out_now
        return out

    def chart(self, serial: str) -> Any:
        import numpy as np

        scale = display(self.name, 1.0)[0]
        unit = display(self.name, 0.0)[1]
        points = [
            svg.TrendPoint(
                r["started_at"],
                r["value"] * scale,
                None if r["std"] is None else r["std"] * scale,
                f"{r['run_id']} {r['started_at']:%Y-%m-%d}: "
                f"{shown(self.name, r['value'], r['std']).value} {unit} ({r['verdict']})",
                lineage_url(r["run_id"], self.name),
                r["verdict"] != "pass",
            )
            for r in self.rows
        ]
        fit, until = None, None
        if self.trend is not None:
            from calib_core.distributions import t_ppf

            end = self.trend.t_last + 365.0
            if self.forecast is not None and self.forecast.earliest is not None:
                end = max(end, min(self.forecast.earliest + 60.0, self.trend.t_last + 1825.0))
            grid = np.linspace(self.trend.t_first, end, 120)
            k = 1.96 if self.trend.dof <= 0 else float(t_ppf(0.975, self.trend.dof))
            fit = (grid, self.trend.value(grid) * scale, k * self.trend.std(grid) * scale)
            until = end
        return svg.trend_chart(
            points,
            title=f"{self.name} of {serial}",
            unit=unit,
            fit=fit,
            limits=(self.low * scale, self.high * scale),
            until=until,
        )


def _band_text(low: float, high: float) -> str:
    if not (math.isfinite(low) or math.isfinite(high)):
        return "-"
    if low == -high:
        return f"± {limit_text(high)}"
    if not math.isfinite(low):
        return f"<= {limit_text(high)}"
    if not math.isfinite(high):
        return f">= {limit_text(low)}"
    return f"{limit_text(low)} .. {limit_text(high)}"


def _date(day: float | None) -> str | None:
    return None if day is None else (svg.EPOCH + timedelta(days=day)).date().isoformat()


def _series(rows: list[dict[str, Any]]) -> dict[str, Series]:
    """Parameter -> Series, one value per run (nearest storage.unit_latest.REFERENCE_C
    when temperature-dependent)."""
    from storage.unit_latest import REFERENCE_C

    per: dict[tuple[str, str], dict[str, Any]] = {}
    for r in rows:
        key = (r["name"], r["run_id"])
        t = r["temperature_c"]
        old = per.get(key)
        dist = abs((t if t is not None else REFERENCE_C) - REFERENCE_C)
        if old is None or dist < old["_dist"]:
            per[key] = {**r, "_dist": dist}
    out: dict[str, Series] = {}
    for (name, _), r in per.items():
        out.setdefault(name, Series(name, r["unit"], [])).rows.append(r)
    for s in out.values():
        s.rows.sort(key=lambda r: r["started_at"])
    return dict(sorted(out.items()))


def _unit_profile(series: dict[str, Series], serial: str, archive) -> ToleranceProfile | None:  # noqa: ANN001
    """The tolerance profile of the unit's latest calibration: its archived thresholds,
    else the named profile file."""
    from pipelines.web.runs import archived_thresholds

    latest = queries.latest_calibration(archive, serial)
    if latest is not None and (archived := archived_thresholds(latest)) is not None:
        return archived
    names = [r["profile_name"] for s in series.values() for r in s.rows[-1:]]
    return _profile(names[-1] if names else None)


@router.get("/units/{serial}", response_class=HTMLResponse)
def unit_page(request: Request, serial: str) -> HTMLResponse:
    """A unit: its runs, every parameter's history with trend and forecast, thermal curves."""
    archive = request.app.state.archive
    q = forms.params(request, ("parameter",))
    dev = forms.checked(queries.device, archive, serial)
    series = _series(queries.unit_parameters(archive, serial))
    profile = _unit_profile(series, serial, archive)
    run_ids = list(dict.fromkeys(r["run_id"] for s in series.values() for r in s.rows))
    references = queries.run_references(archive, run_ids)  # once for every parameter
    for s in series.values():
        s.low, s.high = _band(profile, s.name)
        s.fit(references)
    chosen = q.get("parameter") or next(
        (n for n, s in series.items() if math.isfinite(s.high) or math.isfinite(s.low)),
        next(iter(series), None),
    )
    if chosen is not None and chosen not in series:
        forms.checked(params.validate, chosen)
        forms.checked(_missing, chosen, serial)
    history = queries.history(archive, serial).to_dict("records")
    return render(
        request,
        "unit.html",
        title=f"Unit {serial}",
        dev=dev,
        history=history,
        summaries=[s.summary() for s in series.values()],
        chosen=chosen,
        chart=series[chosen].chart(serial) if chosen else None,
        chosen_note=series[chosen].note if chosen else "",
        chosen_pooled=series[chosen].pooled if chosen else "",
        profile=profile,
        thermal=_thermal(archive, serial, series),
    )


def _missing(name: str, serial: str) -> None:
    raise LookupError(f"unit {serial} has no archived value of {name}")


def _thermal(archive, serial: str, series: dict[str, Series]) -> dict[str, Any] | None:  # noqa: ANN001
    """The current thermal model's curves (by parameter family) with the campaign points."""
    row = queries.thermal_model(archive, serial)
    if row is None:
        return None
    import numpy as np

    from calib_core.thermal import ThermalModel

    model = ThermalModel.from_dict(row["document"])
    temps = np.linspace(model.t_min, model.t_max, 60)
    charts = []
    for family in THERMAL_GROUPS:
        names = sorted(n for n in model.curves if n.startswith(family + "."))
        if not names:
            continue
        scale, unit = display(names[0], 1.0)
        curves = {n: (model.value(n, temps) * scale, model.std(n, temps) * scale) for n in names}
        points = {
            n: [
                (r["env_temperature_c"], r["value"] * scale)
                for r in series[n].rows
                if r["env_temperature_c"] is not None
            ]
            for n in names
            if n in series
        }
        charts.append(
            svg.curve_chart(temps, curves, points, title=f"{family} against temperature", unit=unit)
        )
    orders = {n: c.order for n, c in sorted(model.curves.items())}
    return {"row": row, "model": model, "charts": charts, "orders": orders}


@router.get("/models", response_class=HTMLResponse)
def models_page(request: Request) -> HTMLResponse:
    """Device models in the archive, with their number of units."""
    forms.params(request, ())
    return render(
        request,
        "models.html",
        title="Device models",
        models=queries.models(request.app.state.archive),
    )


@router.get("/fleet", response_class=HTMLResponse)
def fleet_page(request: Request) -> HTMLResponse:
    """A model's fleet: one parameter's distribution over the units' latest valid calibration,
    units out of tolerance, latest verdicts. Read afresh on every request (no cache to
    go stale): the units' counts are grouped in the database (queries.fleet_units)."""
    archive = request.app.state.archive
    q = forms.params(request, ("model", "parameter"))
    model = q.get("model", "")
    if not model:
        forms.checked(queries.check_text, model, "model")
    name = q.get("parameter") or FLEET_PARAMETERS[0]
    forms.checked(params.validate, name)
    fleet = forms.checked(queries.fleet_units, archive, model, FLEET_LIST_MAX)
    if not fleet.units:
        forms.checked(_no_model, model)
    profiles = Counter(fleet.profiles)
    profile = _profile(profiles.most_common(1)[0][0] if profiles else None)
    low, high = _band(profile, name)
    scale, unit = display(name, 1.0)
    one = queries.fleet_values(archive, model, name)
    outside = [r for r in one if not low <= r["value"] <= high]
    queries.fleet_lineage(archive, outside[:FLEET_LIST_MAX])
    from calib_core import drift

    stats = (
        drift.fleet_statistics(
            [r["value"] * scale for r in one], [math.nan] * len(one), [r["serial"] for r in one]
        )
        if one
        else []
    )
    chart = svg.histogram(
        [r["value"] * scale for r in one],
        unit=unit,
        title=f"{name} over {len(one)} units of {model}",
        limits=(low * scale, high * scale),
    )
    latest = {
        v or "no calibration": n for v, n in sorted(fleet.latest.items(), key=lambda kv: -kv[1])
    }
    return render(
        request,
        "fleet.html",
        title=f"Fleet of {model}",
        model=model,
        name=name,
        names=FLEET_PARAMETERS,
        units=fleet.units,
        latest=latest,
        failing=fleet.failing,
        n_failing=fleet.n_failing,
        outside=outside[:FLEET_LIST_MAX],
        n_outside=len(outside),
        scale=scale,
        unit=unit,
        stats=stats[0] if stats else None,
        chart=chart,
        profile=profile,
        low=low * scale,
        high=high * scale,
        n_values=len(one),
    )


def _no_model(model: str) -> None:
    raise LookupError(f"no units of model {model!r} in the archive")
