"""Numbers, units, dates and links as the pages show them (Jinja2 filters and globals)."""

from __future__ import annotations

import json
import math
from datetime import date, datetime
from typing import TYPE_CHECKING, Any
from urllib.parse import quote, urlencode

from pipelines.reports.display import DISPLAY_UNITS
from pipelines.reports.display import display as reports_display

if TYPE_CHECKING:
    from calib_core.calibration import CheckResult


def display(name: str, value: float | None) -> tuple[float | None, str]:
    """(value in the lab display unit, unit) of a canonical parameter value in SI
    (`pipelines.reports.display.display`); a name of no known family stays as it is."""
    if name.rsplit(".", 1)[0] not in DISPLAY_UNITS:
        return value, "SI"
    return reports_display(name, value)


def num(value: Any, digits: int = 6) -> str:
    """A number with `digits` significant digits; "-" for None or NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if not isinstance(value, int | float):
        return str(value)
    return f"{value:.{digits}g}"


def when(value: Any) -> str:
    """A UTC date-time as YYYY-MM-DD HH:MM UTC (dates as YYYY-MM-DD)."""
    if value is None:
        return "-"
    if isinstance(value, datetime):
        return value.strftime("%Y-%m-%d %H:%M UTC")
    if isinstance(value, date):
        return value.isoformat()
    return str(value)


def size(n: int | None) -> str:
    if n is None:
        return "-"
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return str(n)


def as_json(value: Any) -> str:
    return json.dumps(value, indent=1, sort_keys=True, default=str)


def readable(value: Any, indent: str = "") -> str:
    """A nested value (settings, statistics, site) for people: one "key: value" line each,
    nested ones indented, lists joined; "-" for nothing recorded (None, NaN), yes / no.
    The JSON downloads keep the values as they are."""
    if isinstance(value, dict):
        if not value:
            return "-"
        lines = []
        for k, v in sorted(value.items()):
            if isinstance(v, dict) and v:
                lines.append(f"{indent}{k}:\n{readable(v, indent + '  ')}")
            else:
                lines.append(f"{indent}{k}: {readable(v)}")
        return "\n".join(lines)
    if isinstance(value, list | tuple):
        if len(value) > 12:
            return f"{len(value)} values: " + ", ".join(readable(v) for v in value[:6]) + ", ..."
        return ", ".join(readable(v) for v in value) or "none"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return num(value)
    return "-" if value is None else str(value)


def path(*parts: str) -> str:
    """A URL path from segments, each percent-encoded."""
    return "/" + "/".join(quote(str(p), safe="") for p in parts)


def url(base: str, **query: Any) -> str:
    """`base` with the non-empty query parameters."""
    q = {k: v for k, v in query.items() if v is not None and v != ""}
    return base + ("?" + urlencode(q) if q else "")


def run_url(run_id: str) -> str:
    return path("runs", run_id)


def lineage_url(run_id: str, name: str, revision: int | None = None) -> str:
    return url(path("runs", run_id, "lineage", name), revision=revision)


def unit_url(serial: str, parameter: str | None = None) -> str:
    return url(path("units", serial), parameter=parameter)


def fleet_url(model: str, parameter: str | None = None) -> str:
    return url("/fleet", model=model, parameter=parameter)


def equipment_url(kind: str, serial: str) -> str:
    return url("/equipment/item", kind=kind, serial=serial)


def check_result(check: CheckResult) -> str:
    """The badge of one archived check: "pass", else what its failure alone makes of the
    run's verdict (calib_core.checks.overall_verdict): "needs review" for a repeatability,
    device or model check (``model:acc_dof``) or a parameter's conditional pass, "warning"
    or "not recorded" for a lab condition (calib_core.conditions), else "fail"."""
    from calib_core import checks
    from calib_core import condition_rules as conditions

    state = conditions.status(check)
    if state in (conditions.WARNING, conditions.NOT_RECORDED, conditions.INFO):
        return state
    return checks.overall_verdict([check])


FILTERS = {
    "num": num,
    "when": when,
    "size": size,
    "as_json": as_json,
    "readable": readable,
    "check_result": check_result,
}
GLOBALS = {
    "display": display,
    "url": url,
    "path": path,
    "run_url": run_url,
    "lineage_url": lineage_url,
    "unit_url": unit_url,
    "fleet_url": fleet_url,
    "equipment_url": equipment_url,
}
