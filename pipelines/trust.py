"""Which approvers file applies: ``--approvers FILE``, else env ``CALIB_APPROVERS``, else
``[trust] approvers`` of the lab profile (pipelines.lab; a relative path is taken from
the folder of lab.toml). The file itself is read by storage.approval.load_approvers."""

from __future__ import annotations

import os
from pathlib import Path

from storage.approval import APPROVERS_ENV, NOT_CHECKED, Approval, Approvers, load_approvers


def approvers_file(given: Path | str | None = None) -> Path | None:
    """The approvers file named by the command line, the environment or lab.toml."""
    if given:
        return Path(given)
    if os.environ.get(APPROVERS_ENV):
        return Path(os.environ[APPROVERS_ENV])
    from pipelines.lab import load_lab_profile

    found = load_lab_profile()
    if found is None or "trust" not in found[0]:
        return None
    doc, lab_toml = found
    return lab_toml.parent / doc["trust"]["approvers"]


def lab_approvers(given: Path | str | None = None) -> Approvers | None:
    """The lab's approvers (None when no file is named); ValueError naming the file
    and line of a bad entry."""
    path = approvers_file(given)
    return None if path is None else load_approvers(path)


def approval_line(a: Approval) -> str:
    """One approval for people: "approved by NAME" only when the lab's approvers file
    trusts its key; otherwise it says why not, or that it was not checked."""
    when = a.at[:19].replace("T", " ")
    if a.untrusted:
        return f"UNTRUSTED {a.meaning} claimed by {a.signer} at {when} UTC: {a.untrusted}"
    checked = "" if a.trusted else " (key not checked against an approvers file)"
    return f"{a.meaning} by {a.signer} at {when} UTC{checked}"


__all__ = ["NOT_CHECKED", "approval_line", "approvers_file", "lab_approvers"]
