"""What a reprocessing changed: each run's new revision against the one it superseded.

A parameter changed beyond its uncertainty when ``|new - old| > k * sqrt(u_new^2 + u_old^2)``
with u the standard uncertainties of the two revisions: for two independent estimates of
the same quantity the difference has that standard uncertainty, so with k = 3 a
difference flagged by chance alone is rare (0.27 % per parameter for normal errors).
The two revisions come from the same raw bytes, so their errors are in fact strongly
correlated and the true scatter of the difference is smaller: the rule is conservative,
a flagged change is a real change of the method, not noise. A parameter without an
uncertainty (std missing or 0) cannot be judged that way: a difference there is counted
as "unjudged", never as unchanged.

Results are grouped by parameter family, the canonical name without its axis
(``acc.bias.x`` -> ``acc.bias``); a run counts once per family, when any axis changed.
"""

from __future__ import annotations

import math
from typing import Any

DEFAULT_K = 3.0
FLIPS = ("pass->fail", "fail->pass")


def family(name: str) -> str:
    """The parameter family of a canonical name: ``gyr.scale.x`` -> ``gyr.scale``."""
    head, _, _axis = name.rpartition(".")
    return head or name


def change_report(pairs: list[dict[str, Any]], k: float = DEFAULT_K) -> dict[str, Any]:
    """The change report of revision pairs (`storage.queries.revision_pairs`).

    Parameters
    ----------
    pairs : dicts with run_id and ``new`` / ``old`` revisions (verdict, parameters
        name -> (value, std), SI).
    k : coverage factor of the combined standard uncertainty (> 0).

    Returns
    -------
    dict: k, runs (pairs compared), ``families`` (family -> runs compared, changed,
    unjudged, max_z: the largest |new-old| / combined std), ``verdicts`` (old->new
    -> count, unchanged verdicts left out) and ``flipped`` ("pass->fail" /
    "fail->pass" -> run ids).
    """
    if not (isinstance(k, int | float) and math.isfinite(k) and k > 0):
        raise ValueError(f"k: expected a finite number > 0, got {k!r}")
    families: dict[str, dict[str, Any]] = {}
    verdicts: dict[str, int] = {}
    flipped: dict[str, list[str]] = {f: [] for f in FLIPS}
    for pair in pairs:
        new, old = pair["new"], pair["old"]
        for fam, judged in _family_changes(new["parameters"], old["parameters"], k).items():
            row = families.setdefault(fam, {"runs": 0, "changed": 0, "unjudged": 0, "max_z": 0.0})
            row["runs"] += 1
            row["changed"] += judged["changed"]
            row["unjudged"] += judged["unjudged"]
            row["max_z"] = max(row["max_z"], judged["max_z"])
        if new["verdict"] != old["verdict"]:
            key = f"{old['verdict']}->{new['verdict']}"
            verdicts[key] = verdicts.get(key, 0) + 1
            if key in flipped:
                flipped[key].append(pair["run_id"])
    return {
        "k": float(k),
        "runs": len(pairs),
        "families": dict(sorted(families.items())),
        "verdicts": dict(sorted(verdicts.items())),
        "flipped": flipped,
    }


def _family_changes(
    new: dict[str, tuple[float, float | None]], old: dict[str, tuple[float, float | None]], k: float
) -> dict[str, dict[str, Any]]:
    """Per family of the parameters both revisions have: changed, unjudged (0/1), max_z."""
    out: dict[str, dict[str, Any]] = {}
    for name in sorted(new.keys() & old.keys()):
        (v1, u1), (v0, u0) = new[name], old[name]
        row = out.setdefault(family(name), {"changed": 0, "unjudged": 0, "max_z": 0.0})
        combined = math.hypot(u1 or 0.0, u0 or 0.0)
        if not u1 or not u0 or combined == 0.0:
            if v1 != v0:
                row["unjudged"] = 1
            continue
        z = abs(v1 - v0) / combined
        row["max_z"] = max(row["max_z"], z)
        if z > k:
            row["changed"] = 1
    return out
