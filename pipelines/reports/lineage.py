"""The lineage of one parameter as text for a terminal: what bears on that number only.

`storage.queries.lineage` gives the full record of a run's value (every step with all of
its settings and statistics; `calib query lineage --format json` prints it whole). People
asking where ``gyr.scale.x`` comes from want the chain: the raw files and their SHA-256,
each step with the settings and statistics that concern that parameter (its own entry of
a per-parameter table, its channel's entry of a per-channel one, short scalars), the
solver, and the parameter's uncertainty budget line by line. Everything else of a step is
counted, not printed ("3 more fields: --format json").
"""

from __future__ import annotations

import textwrap
from typing import Any

from pipelines.reports.display import STANDARD_U, expanded_u, shown, uncertainty

MAX_ITEMS = 8  # a list or table longer than this is summarised, not printed
MAX_TEXT = 120  # characters of one scalar value before it is summarised


def _scalar(value: Any) -> bool:
    return value is None or isinstance(value, bool | int | float | str)


def _text(value: Any) -> str:
    """A scalar for people: yes / no, floats to 6 significant digits, "-" for none."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.6g}"
    return "-" if value is None else str(value)


def _bearing(value: Any, param: str, channel: str) -> str | None:
    """`value` as it bears on `param`, or None when it does not (or is too long to read)."""
    if isinstance(value, dict):
        for key in (param, channel):
            if key in value:
                return _bearing(value[key], param, channel)
        if len(value) <= MAX_ITEMS and all(_scalar(v) for v in value.values()):
            return ", ".join(f"{k} {_text(v)}" for k, v in value.items()) or "none"
        return None
    if isinstance(value, list):
        if not value:
            return "none"
        if len(value) <= MAX_ITEMS and all(_scalar(v) for v in value):
            return ", ".join(_text(v) for v in value)
        return None
    text = _text(value)
    return text if len(text) <= MAX_TEXT else None


def _replaced(segments: dict[str, Any], channel: str) -> str | None:
    """Replaced (flagged) samples of `channel` per segment, from the outlier step."""
    counts = {
        name: seg["n_flagged"][channel]
        for name, seg in segments.items()
        if isinstance(seg, dict) and channel in (seg.get("n_flagged") or {})
    }
    if not counts:
        return None
    some = ", ".join(f"{k} {n}" for k, n in counts.items() if n)
    return f"{sum(counts.values())} in {len(counts)} segments" + (f" ({some})" if some else "")


def _fields(step: dict[str, Any], param: str, channel: str) -> tuple[list[tuple[str, str]], int]:
    """(label, text) of a step's settings and statistics that bear on `param`; the number
    left out."""
    shown_fields: list[tuple[str, str]] = []
    left = 0
    for part in ("settings", "statistics"):
        for key, value in (step.get(part) or {}).items():
            if (step["name"] == "uncertainty" and key == "budgets") or key.endswith("seconds"):
                continue  # the budget is printed below; a step's duration is no input
            if key == "segments" and isinstance(value, dict):
                text = _replaced(value, channel)
                key = f"replaced samples of {channel}"
            else:
                text = _bearing(value, param, channel)
            if text is None:
                left += 1
            else:
                shown_fields.append((key.replace("_", " "), text))
    return shown_fields, left


def _budget(budget: dict[str, Any], param: str) -> list[str]:
    lines = [f"Uncertainty budget of {param} ({budget.get('label') or 'GUM'})"]
    for row in budget.get("rows") or []:
        u = uncertainty(param, row.get("contribution"))
        lines.append(
            f"  {row.get('source')}: type {row.get('kind')}, "
            f"{row.get('distribution')}, contribution {u} "
            f"{shown(param, 0.0).unit}, dof {_text(row.get('dof'))}"
        )
    s = shown(param, budget.get("value"), budget.get("uc"))
    lines.append(
        f"  combined {STANDARD_U} = {s.u or '-'} {s.unit}, nu_eff "
        f"{_text(budget.get('nu_eff'))}, {budget.get('k_method') or ''}"
    )
    k = budget.get("k")
    if k is not None:
        big = shown(param, budget.get("value"), budget.get("U"))
        lines.append(
            f"  {expanded_u(k)} = {big.u or '-'} {big.unit} "
            f"(coverage {_text(budget.get('coverage'))})"
        )
    lines += [f"  note: {n}" for n in budget.get("notes") or []]
    return lines


def lineage_lines(doc: dict[str, Any], param: str) -> list[str]:
    """The lineage record `doc` (`storage.queries.lineage`) of `param` as lines of text."""
    parts = param.split(".")
    channel = f"{parts[0]}.{parts[-1][0]}" if len(parts) >= 3 else param
    run, dev, cal = doc["run"], doc["device"], doc["calibration"]
    current = (
        "current"
        if cal.get("current")
        else (f"superseded by revision {cal.get('superseded_by_revision')}")
    )
    lines = [
        f"{param} of run {run['run_id']} ({dev['serial']}, {dev['model']}), "
        f"revision {cal['revision']} ({current})",
    ]
    for v in doc["parameter"]["values"]:
        s = shown(param, v["value"], v["std"])
        at = "" if v.get("temperature_c") is None else f" at {v['temperature_c']:g} deg C"
        lines.append(f"  value {s.value} {s.unit}, {STANDARD_U} {s.u or '-'}{at}")
    lines.append(
        f"  verdict {cal['verdict']} (profile {cal['profile_name']} "
        f"v{cal['profile_version']}); software {cal['software_version']}"
    )
    lines.append(f"Raw files ({len(doc['raw_files'])})")
    lines.append(f"    raw hash {run['raw_hash']}")
    for f in doc["raw_files"]:
        lines.append(f"  {f['name']} ({f.get('format') or '-'}, {f['size']} bytes)")
        lines.append(f"    sha256 {f['sha256']}")
    if run.get("samples_sha256"):
        lines.append(f"  samples {run['samples_path']}")
        lines.append(f"    sha256 {run['samples_sha256']}")
    budget = None
    for step in doc["steps"]:
        fields, left = _fields(step, param, channel)
        lines.append(f"Step {step['seq']}: {step['name']}")
        lines += [f"  {label}: {text}" for label, text in fields]
        if left:
            lines.append(f"  ({left} more fields of this step: --format json)")
        if step["name"] == "uncertainty":
            budget = ((step.get("statistics") or {}).get("budgets") or {}).get(param)
    if budget:
        lines += _budget(budget, param)
    if doc.get("equipment"):
        lines.append("Equipment")
        lines += [
            f"  {e.get('kind')} {e.get('model')} {e.get('serial')}, due "
            f"{_text(e.get('calibration_due'))}"
            for e in doc["equipment"]
        ]
    return lines


def lineage_text(doc: dict[str, Any], param: str, width: int = 80) -> str:
    """`lineage_lines` wrapped to `width` columns (continuations indented)."""
    out = []
    for line in lineage_lines(doc, param):
        indent = " " * (len(line) - len(line.lstrip()) + 2)
        out += textwrap.wrap(
            line, width, subsequent_indent=indent, break_on_hyphens=False, break_long_words=True
        ) or [""]
    return "\n".join(out) + "\n"
