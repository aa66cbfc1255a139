"""`calib verify`, `calib backup DEST`, `calib restore SRC`: the archive's integrity and backups."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from pipelines import cli_shared as batch  # its batch options (RunnerOpt...)
from pipelines.cli_shared import ArchiveOpt, JsonOpt, app, err, fail_on, open_archive, print_json
from pipelines.commands.audit import ApproversOpt, load_trust

RECOMPUTE_HELP = (
    "Instead: solve every revision of RUN_ID... (--sample N, --all) again from its raw bytes "
    "and compare it with its sealed rows."
)
SAMPLE_HELP = "With --recompute: N runs drawn at random."


@app.command()
def verify(
    run_ids: Annotated[
        list[str] | None, typer.Argument(help="With --recompute: the runs to solve again.")
    ] = None,
    archive: ArchiveOpt = None,
    as_json: JsonOpt = False,
    orphans: Annotated[
        bool, typer.Option("--orphans/--no-orphans", help="List unreferenced files.")
    ] = True,
    repair_orphans: Annotated[
        bool,
        typer.Option(
            "--repair-orphans",
            help="First delete temporary files left by writers that were killed.",
        ),
    ] = False,
    approvers: ApproversOpt = None,
    checkpoint: Annotated[
        list[Path] | None,
        typer.Option(
            "--checkpoint",
            help="A checkpoint written earlier (calib checkpoint): the "
            "audit chain must extend it exactly. Repeatable.",
        ),
    ] = None,
    recompute: Annotated[bool, typer.Option("--recompute", help=RECOMPUTE_HELP)] = False,
    sample: Annotated[int | None, typer.Option("--sample", help=SAMPLE_HELP)] = None,
    every: Annotated[bool, typer.Option("--all", help="With --recompute: every run.")] = False,
    runner: batch.RunnerOpt = "local",
    workers: batch.WorkersOpt = None,
    scheduler: batch.SchedulerOpt = None,
    progress: batch.ProgressOpt = None,
    flow: Annotated[bool, typer.Option("--flow", help="A Prefect flow for any number.")] = False,
) -> None:
    """Re-hash every archived file, recompute every seal, settings hash, the audit chain and
    the approval signatures; with --recompute, solve archived revisions again instead.

    Exit 1 on any missing or changed file or value, on an approval made with a key the
    approvers file does not hold, or on a chain that does not extend a checkpoint. With
    --recompute: every revision of RUN_ID... (--sample N, --all) solved again from its raw
    bytes with its recorded settings, reference correction and judged-against runs; exit 1
    when one made by this software version differs from its sealed rows (run, revision and
    the first differing field are named) or cannot be solved again."""
    from pipelines.commands import recompute as recomputing

    recomputing.check_selection(run_ids or [], sample, every, recompute)
    if recompute:
        how = {"runner": runner, "workers": workers, "scheduler": scheduler, "flow": flow}
        show = err.is_terminal if progress is None else progress
        recomputing.recompute(archive, run_ids or [], sample, how, show, as_json)
    from pipelines.trust import NOT_CHECKED
    from storage import checkpoint as checkpoints
    from storage.rawstore import remove_stale_temp_files
    from storage.seal import record_event
    from storage.verify import verify as run_verify

    trust = load_trust(approvers)
    with fail_on(ValueError):
        heads = [(str(p), checkpoints.load(p)) for p in checkpoint or []]
    arch = open_archive(archive)
    if repair_orphans:
        removed = [p.relative_to(arch.root).as_posix() for p in remove_stale_temp_files(arch.root)]
        for rel in removed:
            err.print(f"removed {rel} (left by a killed writer)")
        if removed:
            record_event(
                arch,
                "repaired",
                reason="temporary files left by killed writers",
                detail={"removed": len(removed), "first": removed[:20]},
            )
    report = run_verify(arch, orphans=orphans, approvers=trust, checkpoints=heads)
    if as_json:
        print_json(report.to_dict())
    else:
        for p in report.problems:
            runs = ", ".join(p.runs)
            sys.stdout.write(f"{p.kind.upper()}\t{p.path or '-'}\t{runs}\t{p.detail}\n")
        for o in report.orphans:
            err.print(f"orphan (not referenced, harmless): {o}")
        mb = report.bytes_checked / 1e6
        seq, head = report.chain_head
        err.print(
            f"{report.files_checked} files ({mb:.1f} MB) of {report.runs_checked} runs and "
            f"{report.seals_checked} seals checked: "
            + ("OK" if report.ok else f"[red]{len(report.problems)} problem(s)[/red]")
        )
        err.print(
            f"audit chain head: event {seq}, hash {head} (note it down, or keep a "
            "calib checkpoint out of the writers' reach)",
            soft_wrap=True,
        )
        err.print(
            f"approvals checked against {report.approvers}" if report.approvers else NOT_CHECKED,
            markup=False,
        )
        for source in report.checkpoints:
            err.print(f"chain compared with the checkpoint {source}", markup=False)
    raise typer.Exit(0 if report.ok else 1)


@app.command()
def backup(
    dest: Annotated[Path, typer.Argument(help="New (or empty) folder for the backup.")],
    archive: ArchiveOpt = None,
) -> None:
    """Consistent backup: database snapshot, file store, hash manifest."""
    from storage.backup import BackupError
    from storage.backup import backup as run_backup

    with fail_on(BackupError, FileNotFoundError):
        manifest = run_backup(open_archive(archive), dest)
    err.print(
        f"backed up the {manifest['backend']} database (schema {manifest['schema_revision']}) "
        f"and {len(manifest['files'])} files to {dest}"
    )


@app.command()
def restore(
    src: Annotated[Path, typer.Argument(help="A backup folder made by `calib backup`.")],
    archive: ArchiveOpt = None,
) -> None:
    """Restore a backup into an empty archive location, then verify it (exit 1 if it fails)."""
    from storage.backup import BackupError
    from storage.backup import restore as run_restore
    from storage.db import resolve_archive
    from storage.seal import record_event
    from storage.verify import verify as run_verify

    with fail_on(BackupError, FileNotFoundError, ValueError):
        target = resolve_archive(archive)
        manifest = run_restore(src, target)
    record_event(
        target,
        "restored",
        detail={"files": len(manifest["files"]), "schema": manifest["schema_revision"]},
    )
    report = run_verify(target, orphans=False)
    err.print(
        f"restored {len(manifest['files'])} files and the {manifest['backend']} database "
        f"into {target.display_url} (files under {target.root}); verify: "
        + ("OK" if report.ok else f"{len(report.problems)} problem(s)")
    )
    raise typer.Exit(0 if report.ok else 1)
