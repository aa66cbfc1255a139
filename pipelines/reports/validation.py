"""Method validation, the report: the certificate's section of the revision's latest validation
record (`calib validate`, docs/validation.md), per peer its parameters with E_n; a peer's
outcome in one line (`peer_line`: `calib show`, the web run page, the certificate)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from pipelines.reports.render import Section

if TYPE_CHECKING:
    from storage.queries.records import Validation

COLUMNS = ["parameter", "ours", "theirs", "difference", "u_c", "E_n", "unit"]
HEADER = ["peer", *COLUMNS]


def row_texts(r: dict[str, Any]) -> list[str]:
    """One compared parameter as text, in `COLUMNS` order (the CLI, the web page, the
    certificate)."""
    return [
        r["parameter"],
        f"{r['ours']:.6g}",
        f"{r['theirs']:.6g}",
        f"{r['difference']:.3g}",
        f"{r['u_combined']:.3g}",
        "-" if r["e_n"] is None else f"{r['e_n']:.2f}",
        r["unit"],
    ]


def validation_sections(records: list[Validation]) -> list[Section]:
    """One "Method validation" section for the latest record; none without a record."""
    if not records:
        return []
    v = records[-1]
    rows = [[p["peer"], *row_texts(r)] for p in v.document["peers"] for r in p["parameters"]]
    paragraphs = [
        f"Validation record {v.id} of {v.created_at:%Y-%m-%d} (software "
        f"{v.software_version}): this revision's parameters against independent public "
        "implementations run on the same raw bytes. E_n = |ours - theirs| / sqrt(U_ours^2 + "
        "U_theirs^2) with U = 2 u; a peer stating no uncertainty counts 0.",
        *(peer_line(p) for p in v.document["peers"]),
    ]
    return [
        Section(
            "Method validation", header=HEADER if rows else [], rows=rows, paragraphs=paragraphs
        )
    ]


def peer_line(peer: dict[str, Any]) -> str:
    """One peer's outcome in words: how many parameters, the largest E_n and those above 1,
    or why it did not compare (`calib show`, the web run page, the certificate)."""
    who = f"{peer['peer']} {peer.get('version') or ''}".strip()
    if peer["status"] != "compared":
        return f"{who}: {peer['status']} ({peer['reason']})"
    rows = peer["parameters"]
    scored = [r for r in rows if r["e_n"] is not None]
    over = [r["parameter"] for r in scored if r["e_n"] > 1.0]
    worst = max((r["e_n"] for r in scored), default=None)
    text = f"{who}: {len(rows)} parameters compared"
    if worst is not None:
        text += f", largest E_n {worst:.2f}"
    return text + (f"; E_n > 1: {', '.join(over)}" if over else "; every E_n <= 1")
