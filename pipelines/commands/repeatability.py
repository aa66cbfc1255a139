"""`calib repeatability SERIAL`: judge the repeatability of a unit's archived runs on demand.

At archive time each run is compared with the runs archived before it
(pipelines.process.verify_run); this command judges the group as the archive
holds it now: the most recent run of the procedure and the runs taken under the
same conditions, by the repeatability rules of the latest run's tolerance profile.
"""

from __future__ import annotations

from typing import Annotated

import typer
from rich.table import Table

from pipelines.cli_shared import ArchiveOpt, JsonOpt, app, fail_on, open_archive, out, print_json


@app.command("repeatability")
def repeatability_command(
    serial: str,
    archive: ArchiveOpt = None,
    procedure: Annotated[
        str | None, typer.Option(help="Procedure (default: that of the latest run).")
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """Repeatability of SERIAL's latest runs: CV of scale factors, scatter of the rest."""
    from calib_core.checks import overall_verdict
    from calib_core.verification import RunValues, comparable_runs, repeatability
    from pipelines.shared_reference import with_shared
    from pipelines.tolerances import load_profile
    from storage import queries

    arch = open_archive(archive)
    with fail_on(LookupError, ValueError):
        latest = queries.latest_run(arch, serial)  # the one rule: storage.current
        if latest is None:
            raise LookupError(f"no calibrations archived for serial {serial!r}")
        proc = procedure or latest["procedure"]
        runs = queries.repeatability_candidates(arch, serial, proc)
        if not runs:
            raise LookupError(f"no current calibrations of serial {serial!r} by procedure {proc!r}")
        profile = load_profile(queries.run_summary(arch, runs[0]["run_id"]).tolerance_profile)
    values = [
        RunValues(r["run_id"], (r["environment"] or {}).get("temperature_c"), r["parameters"])
        for r in runs
    ]
    rules = profile.repeatability
    group = comparable_runs(
        values[0], values[1:], rules["temperature_tol_c"], int(rules["max_runs"])
    )
    group = with_shared(arch, group)  # runs on one reference share its Type B
    checks = repeatability(group, profile)
    doc = {
        "serial": serial,
        "procedure": proc,
        "profile": {"name": profile.name, "version": profile.version, "rules": rules},
        "group": [r.run_id for r in group],
        "judged": bool(checks),
        "verdict": overall_verdict(checks) if checks else None,
        "checks": [
            {
                "name": c.name,
                "value": c.value,
                "limit": c.limit,
                "passed": c.passed,
                "detail": c.detail,
            }
            for c in checks
        ],
    }
    if as_json:
        print_json(doc)
    elif not checks:
        out.print(
            f"not judged: {len(group)} comparable run(s) of {serial} ({', '.join(doc['group'])}), "
            f"{rules['min_runs']} needed"
        )
    else:
        table = Table(title=f"Repeatability of {serial} over {', '.join(doc['group'])}")
        for col in ("parameter", "rule", "value", "limit", "result"):
            table.add_column(col)
        for c in checks:
            rule = c.detail.split(":", 1)[0].removeprefix("rule ")
            mark = "[green]pass[/]" if c.passed else "[red]FAIL[/]"
            table.add_row(
                c.name.removeprefix("repeat:"), rule, f"{c.value:.4g}", f"{c.limit:.4g}", mark
            )
        out.print(table)
    raise typer.Exit(0 if not checks or all(c.passed for c in checks) else 1)
