"""Shared references in trends and repeatability, the pipeline glue: each archived run's
reference identity and the Type A / Type B split of each parameter's budget, for
`calib_core.drift.fit_trend_shared` and `calib_core.verification.RunValues.shared`.

Two runs share a reference when they name the same equipment (kind and serial, the
sealed snapshot) and the same site (its gravity): their Type B contributions are then one
draw. A run without a budget leaves the statistics on their independent form.
"""

from __future__ import annotations

import json
import math
from typing import Any

from storage import queries
from storage.db import Archive


def reference_id(
    equipment: list[tuple[str, str]] | list[dict[str, Any]], site: dict[str, Any] | None
) -> str:
    """The identity of a run's reference: its equipment (kind:serial, sorted) and its site."""
    pairs = sorted((e["kind"], e["serial"]) if isinstance(e, dict) else tuple(e) for e in equipment)
    kit = "+".join(f"{k}:{s}" for k, s in pairs) or "no equipment"
    return f"{kit} @ {json.dumps(site or {}, sort_keys=True, default=str)}"


def split_budget(budget: dict[str, Any]) -> tuple[float, float]:
    """(u_A, u_B) of a budget document: root sum of squares of its Type A / B rows."""

    def rss(kind: str) -> float:
        return math.sqrt(
            sum(
                float(r["contribution"]) ** 2
                for r in budget.get("rows", [])
                if r.get("kind") == kind
            )
        )

    return rss("A"), rss("B")


def shared_values(archive: Archive, run_ids: list[str]) -> dict[str, dict[str, tuple]]:
    """{run_id: {parameter: (reference id, u_B)}} of the runs with an uncertainty budget."""
    out: dict[str, dict[str, tuple]] = {}
    for run_id, ref in queries.run_references(archive, run_ids).items():
        rid = reference_id(ref["equipment"], ref["site"])
        out[run_id] = {name: (rid, split_budget(b)[1]) for name, b in ref["budgets"].items()}
    return out


def with_shared(archive: Archive, runs: list, current: dict[str, tuple] | None = None) -> list:
    """`runs` (calib_core.verification.RunValues) with their shared references filled in;
    `current` is the shared map of a run not archived yet (the first in `runs`)."""
    from dataclasses import replace

    found = shared_values(archive, [r.run_id for r in runs])
    if current is not None and runs:
        found[runs[0].run_id] = current
    return [replace(r, shared=found.get(r.run_id, {})) for r in runs]


def trend_inputs(
    archive: Archive, run_ids: list[str], name: str, stds: list[float | None]
) -> tuple[list[float], list[float], list[str]] | None:
    """(u_A, u_B, reference ids) of a parameter's trend points, or None when a point has
    no budget of it (the trend then stays an independent fit). u_A is the point's std."""
    return trend_inputs_of(queries.run_references(archive, run_ids), run_ids, name, stds)


def trend_inputs_of(
    found: dict[str, dict[str, Any]], run_ids: list[str], name: str, stds: list[float | None]
) -> tuple[list[float], list[float], list[str]] | None:
    """`trend_inputs` from `storage.queries.run_references` already read (a page that
    fits every parameter of a unit reads them once)."""
    u_a, u_b, refs = [], [], []
    for run_id, std in zip(run_ids, stds, strict=True):
        ref = found.get(run_id)
        if ref is None or name not in ref["budgets"] or std is None:
            return None
        u_a.append(float(std))
        u_b.append(split_budget(ref["budgets"][name])[1])
        refs.append(reference_id(ref["equipment"], ref["site"]))
    if not any(u_b):
        return None  # no Type B anywhere: nothing is shared
    return u_a, u_b, refs
