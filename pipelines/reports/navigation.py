"""Navigation performance, the certificate's section: the figures of `calib navfit` for each
mission profile the lab's ``lab.toml`` names (``[navigation] profiles``), gathered into the
certificate's data when it is issued and printed as one table per profile
(docs/navigation.md)."""

from __future__ import annotations

from typing import Any

from pipelines.reports.render import Section

METHOD = (
    "The calibration's residual errors (each parameter's standard uncertainty, the noise "
    "terms, the thermal model's residual and the drift expected by the end of the "
    "recalibration interval, where the archive holds them) propagated through the strapdown "
    "inertial error equations over the mission profile (docs/navigation.md). A computed "
    "estimate for the stated profile, not a measured result."
)


def navigation_data(archive, run_id: str) -> list[dict[str, Any]]:  # noqa: ANN001 - Archive
    """`pipelines.navigation.navfit` of the run for each profile the lab names; [] when it
    names none. A profile that cannot be computed is kept with its reason (``error``)."""
    from pipelines import navigation
    from pipelines.lab import lab_navigation_profiles

    names, path = lab_navigation_profiles()
    known = navigation.profile_names()
    for i, name in enumerate(names):
        if name not in known:
            raise ValueError(
                f"lab profile {path}: navigation.profiles[{i}]: no mission profile {name!r}; "
                f"expected one of {', '.join(known)}"
            )
    out = []
    for name in names:
        try:
            out.append(navigation.navfit(archive, run_id, navigation.load_profile(name)))
        except (LookupError, ValueError) as exc:
            out.append({"profile": {"name": name}, "error": str(exc)})
    return out


def navigation_sections(data: list[dict[str, Any]] | None) -> list[Section]:
    """One "Navigation performance" section per profile of the certificate's data."""
    return [_section(r) for r in data or []]


def _section(r: dict[str, Any]) -> Section:
    p = r["profile"]
    title = f"Navigation performance: {p['name']}"
    if "error" in r:
        return Section(title, paragraphs=[f"Not computed: {r['error']}"])
    rows = []
    for key, v in r["end"].items():
        dom = r["dominant"][key]
        share = f" ({100 * r['shares'][key][dom]:.0f} %)" if dom else ""
        rows.append(
            [
                key.rsplit("_", 1)[0].replace("_", " "),
                f"{v['sigma']:.3g}",
                f"{v['p95']:.3g}",
                v["unit"],
                f"{dom or '-'}{share}",
            ]
        )
    t = r["time_to_limit_s"]
    since = "the start" if p["aiding"] == "none" else "the fixes end"
    limit = f"Horizontal position error (95 %) reaches {r['position_limit_m']:g} m " + (
        "not within the profile." if t is None else f"{t:.1f} s after {since}."
    )
    paragraphs = [f"{p['description']} ({p['duration_s']:g} s; figures at its end).", limit]
    paragraphs += [METHOD] + [f"Note: {n}" for n in r["notes"]]
    return Section(
        title,
        header=["Error", "1 sigma", "95 %", "Unit", "Dominant source (share)"],
        rows=rows,
        paragraphs=paragraphs,
    )
