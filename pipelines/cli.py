"""The `calib` command. Data goes to stdout (tables, or JSON with --json); logs go to stderr."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape

from pipelines.cli_shared import (
    ArchiveOpt,
    DeviceIdOpt,
    JsonOpt,
    RevisionOpt,
    RotationOpt,
    VehicleIdOpt,
    app,
    cell,
    err,
    fail,
    fail_on,
    flow_batch_console,
    frame_records,
    group_commands,
    open_archive,
    open_run,
    out,
    print_facts,
    print_json,
    print_table,
    progress_bar,
    warn,
)
from pipelines.commands import register_all
from pipelines.direct import IN_PROCESS_MAX_RUNS

if TYPE_CHECKING:
    from storage.queries.records import RunSummary


@app.command()
def process(
    paths: Annotated[list[Path], typer.Argument(help="Run folders, or folders holding runs.")],
    archive: ArchiveOpt = None,
    as_json: JsonOpt = False,
    runner: Annotated[
        str,
        typer.Option(
            "--runner",
            help="local (threads), process (local processes: CPU-bound solving on every "
            "core) or dask (an existing scheduler with --scheduler, else a local cluster).",
        ),
    ] = "local",
    workers: Annotated[
        int | None, typer.Option("--workers", help="Runs in parallel (default: the cores).")
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler", help="Dask scheduler address, tcp://host:8786 (--runner dask)."
        ),
    ] = None,
    progress: Annotated[
        bool | None,
        typer.Option(
            "--progress/--no-progress",
            help="Progress bar on stderr (default: when stderr is a terminal).",
        ),
    ] = None,
    reports: Annotated[
        bool,
        typer.Option("--reports", help="Also list each archived run's protocol and certificate."),
    ] = False,
    flow: Annotated[
        bool,
        typer.Option(
            "--flow",
            help="Run as a Prefect flow even for a few runs (always so above "
            f"{IN_PROCESS_MAX_RUNS} runs, with another runner or a configured Prefect API).",
        ),
    ] = False,
) -> None:
    """Ingest, solve, check and archive every run under PATHS (a Prefect flow for batches)."""
    from pipelines.direct import discover, in_process, process_in_process
    from pipelines.runners import check_runner

    with fail_on(ValueError):
        check_runner(runner, workers, scheduler)
    show = err.is_terminal if progress is None else progress
    names = [str(p) for p in paths]
    sources, failed = discover(names)
    if in_process(len(sources), runner, flow):
        with progress_bar(show) as draw:
            outcomes = failed + process_in_process(sources, archive, draw)
    else:
        outcomes = _process_flow(names, archive, runner, workers, scheduler, show)
    if reports:
        _write_reports(archive, outcomes)
    if as_json:
        print_json({"runs": outcomes})
    else:
        _print_outcomes(outcomes)
    raise typer.Exit(1 if any(o["status"] == "failed" for o in outcomes) else 0)


def _print_outcomes(outcomes: list[dict]) -> None:
    """The batch's table (ids whole), then each run's protocol path or error on its own line
    (whole: a path cut or wrapped inside a table cell cannot be copied)."""
    rows = []
    for o in outcomes:
        failed = str(sum(c.get("status") == "fail" for c in o["checks"]))
        style = {"ok": "green", "duplicate": "yellow", "failed": "red"}[o["status"]]
        status = f"[{style}]{o['status']}[/]"
        rows.append([o["run_id"] or "-", o["serial"] or "-", status, o["verdict"] or "-", failed])
    print_table("Processed runs", ["run", "serial", "status", "verdict", "failed checks"], rows)
    for o in outcomes:
        if o["status"] == "failed":
            err.print(f"[red]failed[/red] {escape(o['source'])}: {escape(str(o['error']))}")
        elif o["protocol"]:
            out.print(f"{o['run_id']} protocol: {o['protocol']}", markup=False, highlight=False)


def _process_flow(
    paths: list[str],
    archive: str | None,
    runner: str,
    workers: int | None,
    scheduler: str | None,
    show: bool,
) -> list[dict]:
    """The batch as the Prefect flow `process_batch`, with progress bar and Ctrl-C handling."""
    from pipelines.flows import process_batch

    with flow_batch_console(show):
        return process_batch(paths, archive, runner=runner, workers=workers, scheduler=scheduler)


def _write_reports(archive: str | None, outcomes: list[dict]) -> None:
    """The issued certificates (HTML, PDF) of every archived run of the batch: issued when
    each run was archived; one that was not (its issue failed) is issued now."""
    from pipelines.reports.issue import issue, issued

    arch = open_archive(archive)
    for o in outcomes:
        if o["status"] != "failed":
            done = issued(arch, o["run_id"]) or issue(arch, o["run_id"])
            paths = ", ".join(str(p) for p in done.files.values())
            err.print(f"{o['run_id']}: certificate {done.number}: {paths}")


@app.command()
def history(serial: str, archive: ArchiveOpt = None, as_json: JsonOpt = False) -> None:
    """Every calibration revision of a serial, oldest first."""
    from storage import queries

    arch = open_archive(archive)
    if as_json:
        print_json(frame_records(queries.history(arch, serial)))
        return
    rows = queries.history_rows(arch, serial)  # no pandas: the table starts fast
    if not rows:
        fail(f"no calibrations archived for serial {serial!r}")
    # The row's identity and verdict first: a narrow terminal leaves out the right end.
    columns = [
        "run_id",
        "verdict",
        "started_at",
        "revision",
        "superseded",
        "procedure",
        "software_version",
        "created_at",
    ]
    print_table(f"History of {serial}", columns, [[cell(r[c]) for c in columns] for r in rows])


@app.command()
def show(run_id: str, archive: ArchiveOpt = None, as_json: JsonOpt = False) -> None:
    """One archived run: unit, raw files, steps, parameters, checks."""
    from storage import queries

    arch, run_id = open_run(archive, run_id)
    with fail_on(KeyError, LookupError, ValueError):
        summary = queries.run_summary(arch, run_id)
    if as_json:
        print_json(summary.to_dict())
        return
    _print_run(summary, arch.root)
    _print_approvals(arch, summary)
    _print_validations(summary)


def _print_validations(summary: RunSummary) -> None:
    """The revision's validation records (`calib validate`), one line per peer."""
    from pipelines.reports.validation import peer_line

    for v in summary.validations:
        out.print(f"validation record {v.id} ({v.created_at:%Y-%m-%d %H:%M} UTC):", markup=False)
        for peer in v.document["peers"]:
            out.print(f"  {peer_line(peer)}", markup=False)
    if not summary.validations:
        out.print(
            "not validated against independent implementations (calib validate)", markup=False
        )


def _print_approvals(arch, summary: RunSummary) -> None:  # noqa: ANN001 - an Archive
    """The approvals of the shown revision, marked by the lab's approvers file."""
    from pipelines.commands.audit import load_trust
    from pipelines.trust import NOT_CHECKED, approval_line
    from storage.approval import approval_status

    trust = load_trust(None)
    found = approval_status(arch, summary.run_id, summary.calibration.revision, trust)
    for a, holds in found:
        changed = " (NO LONGER VALID: the record changed after signing)"
        gone = "" if holds or a.untrusted else changed
        out.print(f"{approval_line(a)}{gone}", markup=False)
    if not found:
        out.print("not approved (calib approve)", markup=False)
    elif trust is None:
        out.print(NOT_CHECKED, markup=False)


def _print_run(summary: RunSummary, root: Path) -> None:
    """`calib show` for people: the unit, the run, its verdict, the parameters in display
    units with their standard uncertainty, and the checks that failed."""
    from pipelines.reports.display import (
        STANDARD_U,
        STANDARD_U_MEANING,
        check_counts,
        record_notes,
        shown,
        solve_warnings,
    )

    cal, unit = summary.calibration, summary.device
    print_facts(
        {
            "unit": f"{unit.serial} ({unit.model}, {unit.manufacturer})",
            "run": summary.run_id,
            "started": summary.started_at,
            "procedure": summary.procedure,
            "operator": summary.operator,
            "temperature_c": summary.temperature_c,
            "verdict": f"{cal.verdict} (profile {cal.profile_name} v{cal.profile_version})",
            "revision": f"{cal.revision} of {summary.revisions}",
            "folder": str(root / summary.run_dir),
        },
        f"Run {summary.run_id}",
        paths=("folder",),
    )
    rows = []
    for p in cal.parameters:
        s = shown(p.name, p.value, p.std)
        rows.append([p.name, s.value, s.u or "-", s.unit])
    print_table(f"Parameters ({STANDARD_U_MEANING})", ["name", "value", STANDARD_U, "unit"], rows)
    from calib_core.condition_rules import NOT_RECORDED, WARNING
    from calib_core.condition_rules import status as condition_status

    failed = [c for c in cal.checks if condition_status(c) == "fail"]
    if failed:
        rows = [[c.name, _num(c.value), _limit(c.limit), cell(c.detail or "")] for c in failed]
        # in SI, as the archived detail beside them states them (the web page's table too)
        print_table("Failed checks", ["check", "value (SI)", "limit (SI)", "detail"], rows)
    out.print(check_counts(cal.checks).sentence(), markup=False, highlight=False)
    notes = record_notes(cal.checks, solve_warnings(cal))
    if notes:  # findings about the record, samples replaced: beside the verdict, always
        print_table(
            "The record: findings, samples replaced, solver warnings",
            ["finding", "detail"],
            [[name, cell(text)] for name, text in notes],
        )
    noted = [c for c in cal.checks if condition_status(c) in (WARNING, NOT_RECORDED)]
    if noted:  # conditions that leave the verdict as it is
        rows = [[c.name, condition_status(c), _num(c.value), cell(c.detail or "")] for c in noted]
        print_table(
            "Conditions: warnings, not recorded", ["check", "status", "value", "detail"], rows
        )
    out.print(f"(every field: calib show {summary.run_id} --json)", markup=False)


def _num(value: float | None) -> str:
    from pipelines.reports.display import number

    return "" if value is None else number(value)


def _limit(value: float | None) -> str:
    from pipelines.reports.display import limit_text

    return "" if value is None else limit_text(value)


@app.command()
def export(
    run_id: str,
    archive: ArchiveOpt = None,
    fmt: Annotated[
        str,
        typer.Option(
            "--format",
            help="json, px4, ardupilot, csv, mat, kalibr or openvins (docs/exports.md).",
        ),
    ] = "json",
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="File to write (default: stdout).")
    ] = None,
    revision: RevisionOpt = None,
    thermal: Annotated[
        bool, typer.Option("--thermal/--no-thermal", help="Add the unit's thermal model.")
    ] = True,
    instance: Annotated[
        int | None, typer.Option(help="PX4 sensor instance (0) / ArduPilot IMU number (1).")
    ] = None,
    device_id: DeviceIdOpt = None,
    accel_id: Annotated[
        int | None, typer.Option(help="PX4 accelerometer device id (else --device-id).")
    ] = None,
    gyro_id: Annotated[
        int | None, typer.Option(help="PX4 gyro device id (else --device-id).")
    ] = None,
    rotation: RotationOpt = None,
    vehicle_id: VehicleIdOpt = 1,
    rostopic: Annotated[str, typer.Option(help="kalibr / openvins: the IMU topic.")] = "/imu0",
    update_rate: Annotated[
        float | None, typer.Option(help="kalibr / openvins: update_rate, Hz (default: the run's).")
    ] = None,
) -> None:
    """Export a run's calibration: JSON, PX4 / ArduPilot parameters, CSV, MATLAB, or the noise
    model of a static-bias run for Kalibr / OpenVINS."""
    from pipelines.run_export import FORMATS, export_run

    if fmt not in FORMATS:
        fail(f"unknown export format {fmt!r}; expected one of: {', '.join(FORMATS)}")
    if fmt == "mat" and output is None:
        fail("--format mat writes a binary file: give --output FILE.mat")
    arch, run_id = open_run(archive, run_id)
    with fail_on(KeyError, LookupError, ValueError):
        result = export_run(
            arch,
            run_id,
            fmt,
            revision=revision,
            thermal=thermal,
            instance=instance,
            accel_id=device_id if accel_id is None else accel_id,
            gyro_id=device_id if gyro_id is None else gyro_id,
            rostopic=rostopic,
            update_rate_hz=update_rate,
            rotation=rotation,
            vehicle_id=vehicle_id,
        )
    for note in result.warnings:
        warn(note)
    if output is None:
        sys.stdout.flush()
        sys.stdout.buffer.write(result.data)
        sys.stdout.buffer.flush()
    else:
        output.write_bytes(result.data)
        err.print(f"wrote {output}", soft_wrap=True)


# Commands of the other areas live in pipelines/commands/ and register themselves on `app`.
register_all()
group_commands()

if __name__ == "__main__":
    app()
