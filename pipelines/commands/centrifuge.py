"""Centrifuge procedure, the CLI: `calib centrifuge [solve] RUN`, `calib centrifuge plan`.

`solve` (also `calib centrifuge RUN`, as before `plan` existed): the report goes
to stdout (or the JSON document with --json) and to a text file. `plan`: the
table rates for the g levels from the equivalent radius. Exit codes: 0 done,
2 invalid input.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from pipelines.cli_shared import CalibGroup, JsonOpt, app, fail, fail_on, out, print_json


class _SolveByDefault(CalibGroup):
    """`calib centrifuge RUN ...` means `calib centrifuge solve RUN ...`.

    A run folder named like a subcommand is reached as ``./plan``.
    """

    def parse_args(self, ctx, args):  # noqa: ANN001, ANN201 - click's signature
        if args and args[0] not in self.commands and args[0] not in ("--help", "-h"):
            args = ["solve", *args]
        return super().parse_args(ctx, args)


centrifuge_app = typer.Typer(
    cls=_SolveByDefault,
    no_args_is_help=True,
    help="Centrifuge high-g model: solve a run (calib centrifuge RUN), plan the table rates.",
)
app.add_typer(centrifuge_app, name="centrifuge")


@centrifuge_app.command("solve")
def solve(
    run: Annotated[Path, typer.Argument(help="Centrifuge run folder (run.toml + data).")],
    repeat: Annotated[
        Path | None,
        typer.Option("--repeat", help="Repeat run of the same unit: validate the model on it."),
    ] = None,
    report: Annotated[
        Path | None,
        typer.Option("--report", help="Text report file (default RUN/centrifuge_report.txt)."),
    ] = None,
    alpha: Annotated[
        float | None,
        typer.Option(help="Significance level of the F and t tests (default: manifest, 0.05)."),
    ] = None,
    t_test: Annotated[
        str | None,
        typer.Option(
            "--t-test",
            help="two-sided or one-sided (the paper's) coefficient t test (default: manifest, "
            "two-sided).",
        ),
    ] = None,
    steer: Annotated[
        str | None,
        typer.Option(
            help="How the reduction decides: F-then-t (the paper's: model F test, then t tests), "
            "t (t tests) or F (largest model F) (default: manifest, F-then-t)."
        ),
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """Solve a centrifuge run: high-g model per axis, F/t tests, zero drift, validation."""
    from pipelines.centrifuge import process_centrifuge
    from pipelines.ingest import IngestError

    if alpha is not None and not 0.0 < alpha < 1.0:
        fail(f"--alpha must be in (0, 1), got {alpha}")
    with fail_on(ValueError, IngestError, OSError):
        outcome = process_centrifuge(
            run, repeat=repeat, report_path=report, alpha=alpha, t_test=t_test, steer=steer
        )
    if as_json:
        print_json(outcome.to_dict())
    else:
        out.print(outcome.report, markup=False, highlight=False, soft_wrap=True)


def _levels(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise typer.BadParameter(f"{text!r}: expected g levels separated by commas") from None


@centrifuge_app.command("plan")
def plan(
    radius: Annotated[
        float, typer.Option("--radius", help="Equivalent radius, m (from the near-1 g run).")
    ],
    levels: Annotated[
        str, typer.Option(help="g levels, comma separated (default the paper's 2,4,...,20).")
    ] = "2,4,6,8,10,12,14,16,18,20",
    latitude: Annotated[
        float, typer.Option(help="Site latitude, deg (Earth rate's vertical component).")
    ] = 0.0,
    gravity: Annotated[float, typer.Option(help="Local gravity, m/s^2.")] = 9.80665,
    sense: Annotated[str, typer.Option(help="ccw (anticlockwise seen from above) or cw.")] = "ccw",
    step_s: Annotated[
        float, typer.Option("--step-s", help="Length of a step, s (the paper: 5 min).")
    ] = 300.0,
    max_rpm: Annotated[
        float | None, typer.Option("--max-rpm", help="The table's highest rate, rpm.")
    ] = None,
    as_json: JsonOpt = False,
) -> None:
    """Table rates for the g levels: R w (w + 2 Omega_V) = n g, from the equivalent radius."""
    from calib_core.solvers.centrifuge_plan import plan_rates

    if sense not in ("ccw", "cw"):
        fail(f"--sense must be ccw or cw, got {sense!r}")
    if not step_s > 0:
        fail(f"--step-s must be positive, got {step_s}")
    max_rate = None if max_rpm is None else max_rpm * 2.0 * math.pi / 60.0
    with fail_on(ValueError):
        points = plan_rates(
            radius,
            _levels(levels),
            gravity=gravity,
            latitude_deg=latitude,
            sense=1 if sense == "ccw" else -1,
            max_rate=max_rate,
        )
    rows = [
        {
            "g": p.n_g,
            "input_m_s2": p.input,
            "rate_rad_s": p.rate,
            "rate_deg_s": p.deg_s,
            "rpm": p.rpm,
            "revolutions": abs(p.rate) * step_s / (2.0 * math.pi),
        }
        for p in points
    ]
    if as_json:
        settings = {"radius_m": radius, "latitude_deg": latitude, "gravity": gravity}
        print_json({**settings, "sense": sense, "step_s": step_s, "steps": rows})
        return
    out.print(
        f"R = {radius:g} m, g = {gravity:g} m/s^2, latitude {latitude:g} deg, {sense}, "
        f"{step_s:g} s per step",
        markup=False,
        highlight=False,
    )
    out.print(f"{'g':>6}{'input m/s^2':>14}{'rad/s':>12}{'deg/s':>12}{'rpm':>10}{'turns':>9}")
    for r in rows:
        out.print(
            f"{r['g']:>6g}{r['input_m_s2']:>14.4f}{r['rate_rad_s']:>12.5f}"
            f"{r['rate_deg_s']:>12.3f}{r['rpm']:>10.3f}{r['revolutions']:>9.1f}",
            markup=False,
            highlight=False,
        )
