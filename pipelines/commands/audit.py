"""`calib audit`, `calib keygen`, `calib approve`: the audit trail and signed approvals."""

from __future__ import annotations

import os
import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import typer

from pipelines.cli_shared import (
    ArchiveOpt,
    RevisionOpt,
    app,
    cell,
    err,
    fail,
    fail_on,
    open_archive,
    open_run,
    out,
    print_json,
    print_table,
)


class AuditFormat(StrEnum):
    """How `calib audit` prints the events."""

    table = "table"
    tsv = "tsv"
    json = "json"


PASSPHRASE_ENV = "CALIB_KEY_PASSPHRASE"
ApproversOpt = Annotated[
    Path | None,
    typer.Option(
        "--approvers",
        help="The lab's trusted approvers: a file of calib keygen .pub "
        "lines (default: env CALIB_APPROVERS, else [trust] approvers of lab.toml).",
    ),
]


def load_trust(given: Path | None):  # noqa: ANN201 - Approvers | None
    """The lab's approvers (pipelines.trust), or exit 2 naming the bad file and line."""
    from pipelines.trust import lab_approvers

    with fail_on(ValueError):
        return lab_approvers(given)


@app.command()
def audit(
    target: Annotated[
        str | None, typer.Argument(help="A unit serial or a run id (prefix); default: all.")
    ] = None,
    since: Annotated[
        str | None, typer.Option("--since", help="Only events from this date (YYYY-MM-DD) on.")
    ] = None,
    archive: ArchiveOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the events as JSON.")] = False,
    fmt: Annotated[
        AuditFormat | None,
        typer.Option(
            "--format",
            help="table (default on a terminal), tsv (default when piped: one event a "
            "line, tab-separated) or json.",
        ),
    ] = None,
    approvers: ApproversOpt = None,
) -> None:
    """Show the audit trail: who changed what in the archive, when and why (oldest first)."""
    from pipelines.trust import NOT_CHECKED
    from storage import queries
    from storage.approval import Approval

    trust = load_trust(approvers)
    arch = open_archive(archive)
    with fail_on(LookupError, ValueError):
        events = queries.audit_trail(arch, target, since)
    approved = 0
    for ev in events:
        if ev["action"] == "approved":
            d = ev["detail"] or {}
            a = Approval(
                ev["seq"],
                ev["run_id"],
                ev["revision"],
                d.get("meaning", ""),
                d.get("signer", ""),
                d.get("public_key", ""),
                ev["at"].isoformat(),
            )
            ev["approval"] = a if trust is None else trust.mark(a)
            ev["trusted"], ev["untrusted"] = ev["approval"].trusted, ev["approval"].untrusted
            approved += 1
    fmt = AuditFormat.json if as_json else fmt
    if fmt is None:  # a person at a terminal reads a table; a pipe gets one event a line
        fmt = AuditFormat.table if out.is_terminal else AuditFormat.tsv
    if fmt is AuditFormat.json:
        print_json([{k: v for k, v in ev.items() if k != "approval"} for ev in events])
        return
    if fmt is AuditFormat.table:
        _print_table(events)
    for ev in events if fmt is AuditFormat.tsv else ():
        what = ev["run_id"] + f" revision {ev['revision']}" if ev["run_id"] else ""
        what += f" (written as {ev['db_user']})" if ev.get("db_user") else ""
        why = f"  reason: {ev['reason']}" if ev["reason"] else ""
        sys.stdout.write(
            f"{ev['seq']}\t{ev['at'].isoformat(timespec='seconds')}\t{ev['actor']}\t"
            f"{ev['action']}\t{(what + ' ' + _what(ev)).strip()}{why}\n"
        )
    err.print(f"{len(events)} event(s)")
    if approved:
        err.print(
            f"approvals checked against {trust.source}" if trust else NOT_CHECKED, markup=False
        )


def _what(ev: dict[str, Any], key: bool = True) -> str:
    """What an event did, in words (nested values named, not printed raw: --json has them);
    an approval's key fingerprint unless `key` is False."""
    from pipelines.trust import approval_line

    detail = ev["detail"] or {}
    if ev["action"] == "approved":
        return approval_line(ev["approval"]) + (f" (key {_key(ev)})" if key else "")
    if ev["action"] == "certificate issued":  # pipelines.reports.issue
        return (
            f"certificate {detail.get('certificate')} (issue {detail.get('issue')}, "
            f"{len(detail.get('files') or {})} files sealed)"
        )
    return ", ".join(
        f"{k}={v}" if not isinstance(v, dict | list) else f"{k}: {len(v)} entries"
        for k, v in sorted(detail.items())
    )


def _who(ev: dict[str, Any]) -> str:
    """The claimed actor, and the database user (PostgreSQL) or OS user (SQLite) that wrote
    the event where it was recorded (migration 0009) and differs."""
    user = ev.get("db_user")
    return ev["actor"] + (f" (written as {user})" if user and user != ev["actor"] else "")


def _key(ev: dict[str, Any]) -> str:
    """The fingerprint of an approval's key ("" for other events)."""
    from storage.approval import fingerprint

    if ev["action"] != "approved":
        return ""
    return fingerprint((ev["detail"] or {}).get("public_key", ""))


def _print_table(events: list[dict[str, Any]]) -> None:
    """The events at the terminal's width (`print_table`): the event's identity (seq, run)
    and what happened first, then when; who, what and why fold. An approval's key
    fingerprint (one 50-character word) is left to --format tsv / json. Values escaped."""
    from datetime import UTC

    rows = []
    for ev in events:
        what = [f"by {_who(ev)}"] + ([f"revision {ev['revision']}"] if ev["run_id"] else [])
        what += [t for t in (_what(ev, key=False),) if t]
        what += [f"reason: {ev['reason']}"] if ev["reason"] else []
        rows.append(
            [
                cell(ev["seq"]),
                cell(ev["run_id"] or "-"),
                cell(ev["action"]),
                cell(f"{ev['at'].astimezone(UTC):%Y-%m-%d %H:%M:%S}"),
                cell("; ".join(what)),
            ]
        )
    print_table("Audit trail (oldest first)", ["seq", "run_id", "event", "at (UTC)", "what"], rows)


def read_passphrase(confirm: bool) -> str:
    given = os.environ.get(PASSPHRASE_ENV)
    if given:
        return given
    return typer.prompt("Passphrase of the key", hide_input=True, confirmation_prompt=confirm)


@app.command()
def keygen(
    key: Annotated[Path, typer.Argument(help="New private key file (FILE.pub is written too).")],
    name: Annotated[str, typer.Option("--name", help="The signer's full name.")],
) -> None:
    """Make a personal Ed25519 signing key, encrypted with a passphrase (env CALIB_KEY_PASSPHRASE
    or asked)."""
    from storage.approval import generate_key

    with fail_on(ValueError, FileExistsError):
        public = generate_key(key, name, read_passphrase(confirm=True))
    err.print(f"key of {name} written to {key} (public key {public} in {key}.pub)")


@app.command()
def approve(
    run_id: Annotated[str, typer.Argument(help="Run id or a unique prefix of it.")],
    key: Annotated[Path, typer.Option("--key", help="Your private key file (calib keygen).")],
    meaning: Annotated[
        str, typer.Option("--meaning", help="approved (default) or reviewed.")
    ] = "approved",
    name: Annotated[
        str | None, typer.Option("--name", help="Signer name (default: from KEY.pub).")
    ] = None,
    revision: RevisionOpt = None,
    approvers: ApproversOpt = None,
    archive: ArchiveOpt = None,
) -> None:
    """Sign the seal of a run's calibration with your key; `calib verify` checks it. A key
    the lab's approvers file (when one is configured) does not hold is refused."""
    import json

    from sqlalchemy.exc import SQLAlchemyError

    from storage.approval import ApprovalError, load_key
    from storage.approval import approve as sign
    from storage.write_failures import describe

    trust = load_trust(approvers)
    arch, full = open_run(archive, run_id)
    try:
        if name is None:
            pub = key.with_name(key.name + ".pub")
            name = json.loads(pub.read_text())["name"] if pub.is_file() else None
        if not name:
            fail(f"no --name given and no {key}.pub to take it from")
        ev = sign(
            arch,
            full,
            load_key(key, read_passphrase(confirm=False)),
            signer=name,
            meaning=meaning,
            revision=revision,
            approvers=trust,
        )
    except (ApprovalError, ValueError, KeyError) as exc:
        fail(str(exc))
    except (OSError, SQLAlchemyError) as exc:  # the write failed: nothing was signed
        fail(f"run {full}: not signed: {describe(exc, arch.url) or exc}")
    err.print(f"run {full} revision {ev.revision} {meaning} by {name} (audit event {ev.seq})")
