"""`calib reprocess`: archived runs processed again from their raw bytes, as new revisions
(the work: pipelines.reprocess; the batch: pipelines.flows.reprocess_batch; what changed:
pipelines.changes)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from pipelines.cli_shared import (
    ArchiveOpt,
    ProgressOpt,
    RunnerOpt,
    SchedulerOpt,
    WorkersOpt,
    app,
    err,
    fail_on,
    flow_batch_console,
    open_archive,
    open_run,
    out,
    print_json,
    progress_bar,
)
from pipelines.direct import IN_PROCESS_MAX_RUNS

Opt = typer.Option


@app.command("reprocess")
def reprocess_command(
    run_id: Annotated[str | None, typer.Argument(help="One run (else a selection).")] = None,
    reason: Annotated[
        str, Opt("--reason", help="Why the runs are processed again (kept with each revision).")
    ] = ...,  # type: ignore[assignment] - required
    every: Annotated[bool, Opt("--all", help="Every run of the archive.")] = False,
    serial: Annotated[str | None, Opt(help="Runs of this unit.")] = None,
    model: Annotated[str | None, Opt(help="Runs of units of this device model.")] = None,
    since: Annotated[str | None, Opt(help="Runs started on or after (YYYY-MM-DD).")] = None,
    until: Annotated[str | None, Opt(help="Runs started on or before (YYYY-MM-DD).")] = None,
    software_version: Annotated[
        str | None, Opt(help="Runs whose current calibration this software version made.")
    ] = None,
    profile: Annotated[
        str | None, Opt(help="Runs whose current calibration this tolerance profile judged.")
    ] = None,
    archive: ArchiveOpt = None,
    runner: RunnerOpt = "local",
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    k: Annotated[
        float, Opt("--k", help="Changed: |new-old| > k x combined standard uncertainty.")
    ] = 3.0,
    progress: ProgressOpt = None,
    flow: Annotated[
        bool, Opt("--flow", help=f"A Prefect flow even for {IN_PROCESS_MAX_RUNS} runs or fewer.")
    ] = False,
    keep: Annotated[
        Path | None, Opt("--keep", help="One run: rebuild its folder here and keep it.")
    ] = None,
    as_json: Annotated[bool, Opt("--json", help="Print the JSON document.")] = False,
) -> None:
    """Process archived runs again from their raw bytes: RUN_ID, --all, or a selection.

    Each run becomes a new revision, kept with REASON.
    A run this software already made with the same settings is skipped (duplicate),
    so the same command run again after an interruption goes on where it stopped.
    Prints each run's outcome, a summary and the change report.
    """
    from pipelines.reprocess import check_reason

    selection = {
        "serial": serial,
        "model": model,
        "since": since,
        "until": until,
        "software_version": software_version,
        "profile": profile,
    }
    with fail_on(ValueError):
        check_reason(reason)
        _check_choice(run_id, every, selection, keep)
    if run_id is not None:
        outcomes = [_one_run(archive, run_id, reason, keep)]
    else:
        show = err.is_terminal if progress is None else progress
        outcomes = _batch(archive, selection, reason, runner, workers, scheduler, flow, show)
    _report(archive, outcomes, k, as_json, reason)
    failed = [o["run_id"] or o["source"] for o in outcomes if o["status"] == "failed"]
    if failed:  # never a success it did not have: each run not written, named
        err.print(f"not written: {', '.join(failed)}", markup=False, soft_wrap=True)
    raise typer.Exit(1 if failed else 0)


def _check_choice(
    run_id: str | None, every: bool, selection: dict[str, Any], keep: Path | None
) -> None:
    """Exactly one of RUN_ID, --all or filters; --keep only for one run."""
    filters = [f"--{k.replace('_', '-')}" for k, v in selection.items() if v is not None]
    if run_id is not None and (every or filters):
        raise ValueError(f"give RUN_ID or a selection ({', '.join(filters) or '--all'}), not both")
    if run_id is None and not every and not filters:
        raise ValueError(
            "name the runs: RUN_ID, --all, or filters (--serial, --model, --since, --until, "
            "--software-version, --profile)"
        )
    if every and filters:
        raise ValueError(f"--all selects every run: drop it or {', '.join(filters)}")
    if keep is not None and run_id is None:
        raise ValueError("--keep rebuilds one run's folder: give RUN_ID")
    if keep is not None and keep.exists() and any(keep.iterdir()):
        raise ValueError(f"--keep {keep}: folder is not empty")


def _one_run(archive: str | None, run_id: str, reason: str, keep: Path | None) -> dict:
    from pipelines.reprocess import ReprocessError, reprocess_run

    arch, run_id = open_run(archive, run_id)
    with fail_on(ReprocessError):
        return reprocess_run(arch, run_id, keep, reason=reason)


def _batch(
    archive: str | None,
    selection: dict[str, Any],
    reason: str,
    runner: str,
    workers: int | None,
    scheduler: str | None,
    flow: bool,
    show: bool,
) -> list[dict]:
    """The selection in this process when it is small (as `calib process`), else the flow."""
    from pipelines.direct import in_process
    from pipelines.reprocess import plan_reprocess, reprocess_in_process
    from pipelines.runners import check_runner

    with fail_on(ValueError):
        check_runner(runner, workers, scheduler)
        arch = open_archive(archive)
        arch.upgrade()
        todo, skipped = plan_reprocess(arch, selection)
    if in_process(len(todo), runner, flow):
        with progress_bar(show) as draw:
            return reprocess_in_process(arch, todo, skipped, reason, draw)
    from pipelines.flows import reprocess_batch

    with flow_batch_console(show):
        return reprocess_batch(
            reason,
            {k: v for k, v in selection.items() if v is not None},
            archive=archive,
            runner=runner,
            workers=workers,
            scheduler=scheduler,
        )


def _report(
    archive: str | None, outcomes: list[dict], k: float, as_json: bool, reason: str
) -> None:
    """Outcomes, summary and change report: one JSON document, or tables."""
    from pipelines.changes import change_report
    from pipelines.reprocess import changed_pairs, summarize

    summary = summarize(outcomes)
    with fail_on(ValueError):
        changes = change_report(changed_pairs(open_archive(archive), outcomes, reason), k)
    if as_json:
        print_json({"runs": outcomes, "summary": summary, "changes": changes})
        return
    table = Table(title="Reprocessed runs")
    for col in ("run", "serial", "status", "verdict", "message / error"):
        table.add_column(col)
    style = {"revised": "green", "duplicate": "yellow", "failed": "red"}
    for o in outcomes:
        detail = o["error"] if o["status"] == "failed" else (o["message"] or "")
        status = f"[{style[o['status']]}]{o['status']}[/]"
        table.add_row(o["run_id"] or "-", o["serial"] or "-", status, o["verdict"] or "-", detail)
    out.print(table)
    out.print(
        f"{summary['runs']} run(s): {summary['revised']} revised, {summary['duplicate']} "
        f"skipped as duplicate, {summary['failed']} failed"
    )
    _print_changes(changes)


def _print_changes(changes: dict[str, Any]) -> None:
    table = Table(
        title=f"Changes against the superseded revision ({changes['runs']} run(s); "
        f"changed: |new-old| > {changes['k']:g} x combined standard uncertainty)"
    )
    for col in ("family", "runs", "changed", "unjudged (no std)", "max |z|"):
        table.add_column(col)
    for name, row in changes["families"].items():
        table.add_row(
            name, str(row["runs"]), str(row["changed"]), str(row["unjudged"]), f"{row['max_z']:.2f}"
        )
    out.print(table)
    flips = ", ".join(f"{key}: {n}" for key, n in changes["verdicts"].items()) or "none"
    out.print(f"verdicts changed: {flips}")
    for key, run_ids in changes["flipped"].items():
        if run_ids:
            out.print(f"  {key}: {' '.join(run_ids)}")
