"""Method validation, the certificate's section: the revision's latest validation record
(`calib validate`, docs/validation.md), per peer its parameters with E_n."""

from __future__ import annotations

from typing import Any

from pipelines.reports.render import Section

HEADER = ["peer", "parameter", "ours", "theirs", "difference", "u_c", "E_n", "unit"]


def validation_sections(records: list[dict[str, Any]] | None) -> list[Section]:
    """One "Method validation" section for the latest record; none without a record."""
    from pipelines.validation.compare import peer_line

    if not records:
        return []
    v = records[-1]
    rows = [
        [
            p["peer"],
            r["parameter"],
            f"{r['ours']:.6g}",
            f"{r['theirs']:.6g}",
            f"{r['difference']:.3g}",
            f"{r['u_combined']:.3g}",
            "-" if r["e_n"] is None else f"{r['e_n']:.2f}",
            r["unit"],
        ]
        for p in v["document"]["peers"]
        for r in p["parameters"]
    ]
    paragraphs = [
        f"Validation record {v['id']} of {v['created_at']:%Y-%m-%d} (software "
        f"{v['software_version']}): this revision's parameters against independent public "
        "implementations run on the same raw bytes. E_n = |ours - theirs| / sqrt(U_ours^2 + "
        "U_theirs^2) with U = 2 u; a peer stating no uncertainty counts 0.",
        *(peer_line(p) for p in v["document"]["peers"]),
    ]
    return [
        Section(
            "Method validation", header=HEADER if rows else [], rows=rows, paragraphs=paragraphs
        )
    ]
