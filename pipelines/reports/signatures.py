"""The certificate's signature block (ISO/IEC 17025 7.8.2.1 o): the person authorising it,
the electronic approvals of the revision (Ed25519, storage.approval) and whether each still
holds and is trusted, the audit chain's head at issue, and the lines signed by hand.
"""

from __future__ import annotations

from typing import Any

from pipelines.reports import iso17025
from pipelines.reports.render import Section


def signatures_section(
    lab: dict[str, Any] | None,
    chain_head: tuple[int, str] | None,
    approvals: list[tuple[Any, bool]],
) -> Section:
    """The signature block: who authorised the certificate (the lab profile), the electronic
    approvals of the revision with whether each holds, the audit chain at issue, and lines
    for signatures by hand.

    Parameters
    ----------
    lab : the lab profile (pipelines.lab), None without one.
    chain_head : (seq, hash) of the archive's audit chain at issue.
    approvals : (approval, holds) of `storage.approval.approval_status`.
    """
    signed = [
        (
            f"UNTRUSTED, claimed {a.meaning}" if a.untrusted else f"Electronically {a.meaning}",
            f"{a.signer}, {a.at[:19].replace('T', ' ')} UTC (Ed25519 key {a.public_key[:16]}...)"
            + (
                f": {a.untrusted}"
                if a.untrusted
                else ""
                if holds
                else ": NO LONGER VALID, the record changed after signing"
            ),
        )
        for a, holds in approvals
    ]
    if not any(holds and a.meaning == "approved" for a, holds in approvals):
        signed.append(("Electronic approval", "NOT APPROVED (no valid approval: calib approve)"))
    if approvals and all(a.trusted is None for a, _ in approvals):
        signed.append(("Approvers", "keys not checked against the lab's list of trusted approvers"))
    if chain_head is not None:  # the archive's audit chain when the certificate was issued
        seq, head = chain_head
        signed.append(("Audit chain at issue", f"event {seq}, hash {head}"))
    return Section(
        "Signatures",
        pairs=[
            *iso17025.authorisation_pairs(lab),
            *signed,
            ("Customer representative", "______________________   Date: __________"),
            ("Quality control", "______________________   Date: __________"),
            ("Production", "______________________   Date: __________"),
        ],
    )
