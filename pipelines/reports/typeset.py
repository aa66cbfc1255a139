"""The certificate typeset as PDF by Typst (the `typst` package: a compiled typesetter, no
browser engine, no system libraries).

What the certificate says is `pipelines.reports.render.Certificate` (the same object its
HTML is written from); the page layout is `certificate.typ` beside this module: A4 pages,
a header and footer with the certificate number and "page x of y" on every page
(ISO/IEC 17025 7.8.2.1 d), table headers repeated across pages, set in DejaVu Sans from
matplotlib's own font files (so no font is looked up on the system and every machine
sets the same page). The certificate's words reach Typst as one JSON document
(`sys.inputs`), never as markup: no text of a run is ever read as Typst code.

The tables' column widths and which rows are one line high are worked out here
(`pipelines.reports.table_layout`) from the widths of their texts: the sum of each
character's advance, measured by Typst once per character and process (`Metrics`).
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

from pipelines.reports import table_layout
from pipelines.reports.render import Certificate, Section

TEMPLATE = Path(__file__).with_name("certificate.typ")
MM = 72 / 25.4  # pt
MARGIN_X_PT = 14 * MM
TEXT_WIDTH_PT = 210 * MM - 2 * MARGIN_X_PT  # A4 less the left and right margins
TABLE_TEXT_PT = 8.0  # the tables' text size
CELL_INSET_PT = (4.5, 3.0)  # a cell's padding: left and right, top and bottom

# Each character's advances and line heights at the tables' size, in the font and text
# settings of certificate.typ.
_METRICS = b"""#set text(font: "DejaVu Sans", size: float(sys.inputs.size) * 1pt, lang: "en",
  hyphenate: false)
#context [#metadata(json(bytes(sys.inputs.chars)).map(c => {
  let (regular, bold) = (measure(text(c)), measure(text(weight: "bold", c)))
  (regular.width / 1pt, bold.width / 1pt, regular.height / 1pt, bold.height / 1pt)
})) <metrics>]
"""
_REFERENCE = "X"  # its height is one line's


class Metrics:
    """The characters' advances measured so far in this process, and one line's height."""

    def __init__(self) -> None:
        self.advances: dict[str, tuple[float, float, bool]] = {}  # regular, bold (pt), one line
        self.line = 0.0  # pt

    def measure(self, chars: set[str]) -> None:
        """Measure the characters not measured yet (one small Typst document, the reference
        character first). A line break, or a character of another height (set in a
        fallback font), does not keep its row to one line."""
        new = sorted(chars - self.advances.keys())
        if not new:
            return
        import typst

        out = typst.query(
            _METRICS,
            "<metrics>",
            field="value",
            one=True,
            font_paths=fonts(),
            ignore_system_fonts=True,
            sys_inputs={"size": str(TABLE_TEXT_PT), "chars": json.dumps([_REFERENCE, *new])},
        )
        (_, _, line, _), *sizes = json.loads(out)
        self.line = line
        self.advances.update(
            (c, (regular, bold, max(height, bold_height) <= line and c.splitlines() == [c]))
            for c, (regular, bold, height, bold_height) in zip(new, sizes, strict=True)
        )

    def width(self, text: str, bold: bool) -> tuple[float, bool]:
        """`text`'s width (pt: its characters' advances) and whether it stays one line."""
        advances = [self.advances[c] for c in text]
        return sum(a[1] if bold else a[0] for a in advances), all(a[2] for a in advances)


_metrics = Metrics()


@cache
def fonts() -> Any:  # noqa: ANN401 - typst.Fonts
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
    tables = [_rows(s) for s in cert.sections]
    _metrics.measure(
        {c for t in tables for _, rows in t for r in rows for text, _ in r for c in text}
    )
    return {
        "title": cert.title,
        "identifier": cert.identifier,
        "number": f"Certificate {cert.identifier}" if cert.identifier else cert.title,
        "verdict": cert.verdict,
        "verdict_class": cert.verdict.replace(" ", "-"),
        "layout": {
            "margin_x": MARGIN_X_PT,
            "table_size": TABLE_TEXT_PT,
            "inset_x": CELL_INSET_PT[0],
            "inset_y": CELL_INSET_PT[1],
        },
        "sections": [
            {"title": s.title, "tables": _tables(t), "paragraphs": s.paragraphs}
            for s, t in zip(cert.sections, tables, strict=True)
        ],
        "figures": [{"name": name, "svg": chart} for name, chart in cert.figures.items()],
        "end": cert.end,
    }


def _rows(section: Section) -> list[tuple[bool, list[list[table_layout.Cell]]]]:
    """The section's key / value list (True) and table (False, the header row first):
    their rows of (text, bold) cells."""
    tables = []
    if section.pairs:
        tables.append((True, [[(k, True), (v, False)] for k, v in section.pairs]))
    if section.header:
        head = [(h, True) for h in section.header]
        tables.append((False, [head, *([(t, t == "FAIL") for t in r] for r in section.rows)]))
    return tables


def _tables(tables: list[tuple[bool, list[list[table_layout.Cell]]]]) -> list[dict[str, Any]]:
    """A section's key / value list and table (`_rows`) as the template sets them: their
    texts, the columns' widths (pt) and each row's height (pt; None where a text may wrap)."""
    one_line = _metrics.line + 2 * CELL_INSET_PT[1]
    out = []
    for keys, rows in tables:
        widths, single = table_layout.plan(
            rows, _metrics.width, TEXT_WIDTH_PT, 2 * CELL_INSET_PT[0]
        )
        body = rows if keys else rows[1:]
        out.append(
            {
                "keys": keys,
                "head": [] if keys else [text for text, _ in rows[0]],
                "cells": [text for row in body for text, _ in row],
                "columns": widths,
                "rows": [one_line if s else None for s in single],
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
        font_paths=fonts(),
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
