"""`calib verify --recompute`: every revision of archived runs solved again from its raw
bytes and compared with its sealed rows (the work: pipelines.recompute; the batch:
pipelines.flows.recompute_batch). `calib verify` takes the options (archive_admin)."""

from __future__ import annotations

import sys
from typing import Any

import typer
from rich.table import Table

from pipelines.cli_shared import (
    err,
    fail,
    fail_on,
    flow_batch_console,
    open_archive,
    out,
    print_json,
    progress_bar,
)


def check_selection(run_ids: list[str], sample: int | None, every: bool, recompute: bool) -> None:
    """Exactly one of RUN_ID..., --sample N, --all, and only with --recompute."""
    given = [n for n, on in (("RUN_ID", run_ids), ("--sample", sample is not None),
                             ("--all", every)) if on]  # fmt: skip
    if given and not recompute:
        fail(f"{', '.join(given)}: only with --recompute (which runs to solve again)")
    if recompute and len(given) != 1:
        fail(
            "--recompute: name the runs: RUN_ID..., --sample N or --all"
            if not given
            else f"--recompute: give one of {', '.join(given)}"
        )


def recompute(
    archive: str | None,
    run_ids: list[str],
    sample: int | None,
    batch: dict[str, Any],
    show: bool,
    as_json: bool,
) -> None:
    """Recompute the runs chosen; print each revision that differs or failed and a summary;
    exit 1 when one does (a revision made by another software version only lists changes).

    `batch`: runner, workers, scheduler and flow (a Prefect flow even for a few runs).
    """
    from pipelines.direct import in_process
    from pipelines.recompute import plan_recompute, problem_lines, recompute_in_process, summarize
    from pipelines.runners import check_runner

    arch = open_archive(archive)
    with fail_on(ValueError, LookupError):
        check_runner(batch["runner"], batch["workers"], batch["scheduler"])
        chosen = plan_recompute(arch, run_ids or None, sample)
    if in_process(len(chosen), batch["runner"], batch["flow"]):
        with progress_bar(show) as draw:
            outcomes = recompute_in_process(arch, chosen, draw)
    else:
        from pipelines.flows import recompute_batch

        with flow_batch_console(show):
            outcomes = recompute_batch(
                chosen,
                archive=archive,
                runner=batch["runner"],
                workers=batch["workers"],
                scheduler=batch["scheduler"],
            )
    summary = summarize(outcomes)
    if as_json:
        print_json({"runs": outcomes, "summary": summary})
    else:
        for line in problem_lines(outcomes):  # tab-separated, as verify's problems
            sys.stdout.write(line + "\n")
        _print_changed(outcomes)
        r, v = summary["runs"], summary["revisions"]
        err.print(
            f"{sum(r.values())} run(s), {sum(v.values())} revision(s) solved again: "
            f"{v['identical']} identical, {v['changed']} made by another software version "
            f"(changes listed), {v['differs']} differ, {v['failed']} failed: "
            + ("OK" if summary["ok"] else "[red]not reproduced[/red]")
        )
    raise typer.Exit(0 if summary["ok"] else 1)


def _print_changed(outcomes: list[dict[str, Any]]) -> None:
    """The revisions another software version made: `calib reprocess`'s change columns."""
    rows = [(o, r) for o in outcomes for r in o["revisions"] if r["status"] == "changed"]
    if not rows:
        return
    table = Table(title="Revisions made by another software version, solved by this one")
    for col in ("run", "revision", "software", "changed families", "verdict"):
        table.add_column(col)
    for o, r in rows:
        changes = r["changes"]
        families = [f for f, row in changes["families"].items() if row["changed"]]
        verdicts = ", ".join(changes["verdicts"]) or "unchanged"
        table.add_row(o["run_id"], str(r["revision"]), r["software_version"],
                      ", ".join(families) or "none beyond k", verdicts)  # fmt: skip
    out.print(table)
