"""The certificate typeset as PDF by Typst (the `typst` package: a compiled typesetter, no
browser engine, no system libraries).

What the certificate says is `pipelines.reports.render.Certificate` (the same object its
HTML is written from); the page layout is `certificate.typ` beside this module: A4 pages,
a header and footer with the certificate number and "page x of y" on every page
(ISO/IEC 17025 7.8.2.1 d), table headers repeated across pages, set in DejaVu Sans from
matplotlib's own font files (so no font is looked up on the system and every machine
sets the same page). The certificate's words reach Typst as one JSON document
(`sys.inputs`), never as markup: no text of a run is ever read as Typst code.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

from pipelines.reports.render import Certificate, Section

TEMPLATE = Path(__file__).with_name("certificate.typ")


@cache
def _fonts() -> Any:  # noqa: ANN401 - typst.Fonts
    """The DejaVu fonts matplotlib ships, loaded once per process (system fonts ignored);
    found without importing matplotlib (that alone costs more than a certificate)."""
    import importlib.util

    import typst

    (package,) = importlib.util.find_spec("matplotlib").submodule_search_locations
    folder = Path(package) / "mpl-data" / "fonts" / "ttf"
    return typst.Fonts(
        include_system_fonts=False, include_embedded_fonts=False, font_paths=[str(folder)]
    )


def document(cert: Certificate) -> dict[str, Any]:
    """The certificate as the JSON document the template reads."""
    return {
        "title": cert.title,
        "identifier": cert.identifier,
        "number": f"Certificate {cert.identifier}" if cert.identifier else cert.title,
        "verdict": cert.verdict,
        "verdict_class": cert.verdict.replace(" ", "-"),
        "sections": [
            {"title": s.title, "tables": _tables(s), "paragraphs": s.paragraphs}
            for s in cert.sections
        ],
        "figures": [{"name": name, "svg": chart} for name, chart in cert.figures.items()],
        "end": cert.end,
    }


def _widest(columns: list[list[tuple[str, bool]]], candidates: int = 3) -> list[list]:
    """Per column the texts that may be its widest set (the longest few), for the template to
    measure: measuring every cell of a long table would cost as much as setting it."""
    return [
        [list(c) for c in sorted(texts, key=lambda c: len(c[0]), reverse=True)[:candidates]]
        for texts in columns
    ]


def _tables(section: Section) -> list[dict[str, Any]]:
    """The section's key / value list and table, as the template sets them."""
    out = []
    if section.pairs:
        out.append(
            {
                "keys": True,
                "head": [],
                "cells": [text for pair in section.pairs for text in pair],
                "widest": _widest(
                    [[(k, True) for k, _ in section.pairs], [(v, False) for _, v in section.pairs]]
                ),
            }
        )
    if section.header:
        columns = [[(h, True)] for h in section.header]
        for row in section.rows:
            for i, text in enumerate(row):
                columns[i].append((text, text == "FAIL"))
        out.append(
            {
                "keys": False,
                "head": section.header,
                "cells": [text for row in section.rows for text in row],
                "widest": _widest(columns),
            }
        )
    return out


def pdf_bytes(cert: Certificate) -> bytes:
    """The certificate typeset as PDF (Typst, `certificate.typ`).

    Raises
    ------
    RuntimeError
        Typst warned about the document (the message says what), so nothing is set
        silently other than the template says.
    """
    import typst

    pdf, warnings = typst.compile_with_warnings(
        TEMPLATE.read_bytes(),
        root=str(TEMPLATE.parent),
        font_paths=_fonts(),
        ignore_system_fonts=True,
        sys_inputs={"doc": json.dumps(document(cert), ensure_ascii=False)},
    )
    if warnings:
        raise RuntimeError("Typst warned: " + "; ".join(w.message for w in warnings))
    return pdf


def render_pdf(cert: Certificate, path: Path) -> Path:
    """Write the certificate as PDF (`pdf_bytes`) to `path`; return it."""
    path = Path(path)
    path.write_bytes(pdf_bytes(cert))
    return path
