"""Navigation performance, the web pages: a run's calibration over a mission profile
(attitude, velocity and position error against time, time to the position limit, dominant
sources; pipelines/navigation.py) and a device model's units compared on one profile."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse

from pipelines.web import forms, svg
from pipelines.web.pages import render
from storage import queries

router = APIRouter()

DEFAULT_PROFILE = "land-vehicle-outage-60s"
FLEET_NAV_MAX = 20  # units propagated for one fleet page (about a second each)
CHARTS = (
    ("attitude", "deg", ("heading_deg", "roll_deg", "pitch_deg")),
    ("velocity", "m/s", ("horizontal_velocity_mps", "vertical_velocity_mps")),
    ("position", "m", ("horizontal_position_m", "vertical_position_m")),
)


def _profile(q: dict[str, str]) -> Any:
    """The chosen profile by name (never a path: names only, from the lab's and the
    shipped folders), 400 for another."""
    from pipelines import navigation  # numpy and the science: loaded when a page asks

    name = forms.choice(q, "profile", navigation.profile_names(), DEFAULT_PROFILE)
    return forms.checked(navigation.load_profile, name)


def _label(key: str) -> str:
    return key.rsplit("_", 1)[0].replace("_", " ")


@router.get("/runs/{run_id}/navigation", response_class=HTMLResponse)
def run_navigation(request: Request, run_id: str) -> HTMLResponse:
    """One run's calibration over a mission profile."""
    from pipelines import navigation  # numpy and the science: loaded when a page asks

    archive = request.app.state.archive
    q = forms.params(request, ("profile",))
    full = forms.checked(queries.full_run_id, archive, run_id)
    profile = _profile(q)
    result = forms.checked(navigation.navfit, archive, full, profile)
    p = result["profile"]
    outage = p["outage_start_s"] if p["aiding"] != "none" else None
    charts = []
    for title, unit, keys in CHARTS:
        series = {
            f"{_label(k)} 1 sigma / 95 %": (
                result["series"][k]["sigma"],
                result["series"][k]["p95"],
            )
            for k in keys
        }
        limit = result["position_limit_m"] if title == "position" else None
        charts.append(
            svg.error_chart(
                result["series"]["t_s"],
                series,
                title=f"{title} error",
                unit=unit,
                outage=outage,
                limit=limit,
            )  # fmt: skip
        )
    return render(
        request,
        "navigation.html",
        title=f"Navigation performance of run {full}",
        r=result,
        names=navigation.profile_names(),
        charts=charts,
        label=_label,
    )


@router.get("/fleet/navigation", response_class=HTMLResponse)
def fleet_navigation(request: Request) -> HTMLResponse:
    """A device model's units on one profile: each unit's latest valid calibration."""
    from pipelines import navigation  # numpy and the science: loaded when a page asks

    archive = request.app.state.archive
    q = forms.params(request, ("model", "profile"))
    model = q.get("model", "")
    forms.checked(queries.check_text, model, "model")
    profile = _profile(q)
    latest = forms.checked(queries.fleet_latest_valid, archive, model)  # storage.current's rule
    if not latest:
        forms.checked(_no_units, model)
    from pipelines.recall import recall_list

    recalls = {
        e["serial"]: e for e in forms.checked(recall_list, archive, serial=latest[0]["serial"])
    }
    rows = [
        forms.checked(navigation.navfit, archive, unit["run_id"], profile, None, recalls)
        for unit in latest[:FLEET_NAV_MAX]
    ]
    rows.sort(key=lambda r: r["end"]["horizontal_position_m"]["p95"])
    return render(
        request,
        "navigation_fleet.html",
        title=f"Navigation performance of {model}",
        model=model,
        profile=profile,
        names=navigation.profile_names(),
        rows=rows,
        n_units=len(latest),
        shown=min(len(latest), FLEET_NAV_MAX),
    )


def _no_units(model: str) -> None:
    raise LookupError(f"no unit of model {model!r} has a valid calibration")
