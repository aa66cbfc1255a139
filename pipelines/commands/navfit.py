"""`calib navfit RUN --profile NAME|FILE`, the CLI: what a unit's calibrated errors mean for
attitude, velocity and position over a mission (pipelines/navigation.py,
docs/navigation.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any

import typer

from pipelines.cli_shared import (
    ArchiveOpt,
    app,
    err,
    fail,
    fail_on,
    open_run,
    print_facts,
    print_json,
)

PLOT_SUFFIXES = (".png", ".svg", ".pdf")


@app.command()
def navfit(
    run_id: Annotated[str, typer.Argument(help="Run id (or a unique prefix).")],
    profile: Annotated[
        str,
        typer.Option(
            "--profile",
            help="Mission profile: a built-in name (static-alignment, land-vehicle, "
            "land-vehicle-outage-60s, multicopter-flight), a lab's (CALIB_NAVPROFILES) or a "
            ".toml file.",
        ),
    ],
    limit: Annotated[
        float | None,
        typer.Option("--limit", help="Horizontal position limit, m (default: the profile's)."),
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the figures as JSON.")] = False,
    plot: Annotated[
        Path | None,
        typer.Option("--plot", help="Write the error-against-time figure (.png, .svg, .pdf)."),
    ] = None,
    archive: ArchiveOpt = None,
) -> None:
    """Navigation performance of a run's calibration over a mission: 1 sigma and 95 %
    attitude, velocity and position error, time to the position limit, dominant sources."""
    from pipelines import navigation

    if plot is not None and plot.suffix.lower() not in PLOT_SUFFIXES:
        fail(f"--plot {plot}: expected a file ending {', '.join(PLOT_SUFFIXES)}")
    if limit is not None and not limit > 0:
        fail(f"--limit must be > 0 m, got {limit:g}")
    arch, full = open_run(archive, run_id)
    with fail_on(LookupError, ValueError):
        prof = navigation.load_profile(profile)
        result = navigation.navfit(arch, full, prof, limit)
    if plot is not None:
        _write_plot(result, plot)
    if json_out:
        print_json(result)
        return
    print_facts(_facts(result), f"Navigation performance of {result['serial']} on {prof.name}")


def _write_plot(result: dict[str, Any], path: Path) -> None:
    import matplotlib.pyplot as plt

    fig = navigation_figure(result)
    try:
        fig.savefig(path)
    except OSError as exc:
        fail(f"--plot {path}: cannot be written ({exc.strerror or exc})")
    finally:
        plt.close(fig)
    err.print(f"figure written to {path}")


def _facts(result: dict[str, Any]) -> dict[str, Any]:
    """The terminal's table: the end figures (1 sigma / 95 %), the limit, the dominant
    source of each, the notes."""
    p = result["profile"]
    facts: dict[str, Any] = {
        "run": result["run_id"],
        "unit": f"{result['serial']} ({result['model']}), revision {result['revision']}",
        "profile": f"{p['name']}: {p['description']}",
    }
    for key, v in result["end"].items():
        dom = result["dominant"][key]
        share = result["shares"][key].get(dom, 0.0) if dom else 0.0
        facts[f"{key.rsplit('_', 1)[0]} at {p['duration_s']:g} s"] = (
            f"{v['sigma']:.3g} {v['unit']} (1 sigma), {v['p95']:.3g} {v['unit']} (95 %); "
            f"dominant: {dom} ({100 * share:.0f} %)"
        )
    t = result["time_to_limit_s"]
    since = "the start" if p["aiding"] == "none" else f"the fixes end ({result['free_from_s']:g} s)"
    facts[f"time to {result['position_limit_m']:g} m horizontal (95 %)"] = (
        f"not reached by {p['duration_s']:g} s" if t is None else f"{t:.1f} s after {since}"
    )
    facts["notes"] = result["notes"]
    return facts


NAV_PANELS = (
    (("heading_deg", "roll_deg", "pitch_deg"), "attitude error (deg)"),
    (("horizontal_velocity_mps", "vertical_velocity_mps"), "velocity error (m/s)"),
    (("horizontal_position_m", "vertical_position_m"), "position error (m)"),
)


def navigation_figure(result: Mapping[str, Any]) -> Any:  # noqa: ANN401 - a Figure
    """Attitude, velocity and position error against time: 1 sigma solid, 95 % dashed; the
    outage start and the position limit marked.

    Parameters
    ----------
    result : `pipelines.navigation.navfit`'s document (deg, m/s, m, s).
    """
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    series = result["series"]
    t = np.asarray(series["t_s"])
    fig, axes = plt.subplots(1, 3, figsize=(10.0, 3.2))
    for ax, (keys, label) in zip(axes, NAV_PANELS, strict=True):
        for i, key in enumerate(keys):
            colour = ("tab:red", "tab:green", "tab:blue")[i]
            name = key.rsplit("_", 1)[0].replace("_", " ")
            ax.plot(t, series[key]["sigma"], "-", color=colour, lw=1, label=f"{name} 1 sigma")
            ax.plot(t, series[key]["p95"], "--", color=colour, lw=0.8, label=f"{name} 95 %")
        start = result["profile"].get("outage_start_s")
        if result["profile"]["aiding"] != "none" and start is not None:
            ax.axvline(start, color="grey", lw=0.6, ls=":")
        if label.startswith("position"):
            ax.axhline(result["position_limit_m"], color="black", lw=0.6, ls="-.")
        ax.set_xlabel("time (s)", fontsize=7)
        ax.set_ylabel(label, fontsize=7)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=5)
        ax.grid(True, lw=0.3)
    fig.suptitle(f"{result['serial']} on {result['profile']['name']}", fontsize=9)
    fig.tight_layout()
    return fig
