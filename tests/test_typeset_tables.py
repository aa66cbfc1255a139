"""The certificate's tables laid out before Typst sets them (pipelines.reports.table_layout,
pipelines.reports.typeset): the columns' widths, and rows held to one line's height only
where Typst would have set them so.

The widths of texts are checked against Typst's own measure of them; a certificate set
with the worked-out rows is compared, word by word (poppler's pdftotext -bbox), with the
same certificate set with every row's height left to Typst.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from pipelines.reports import table_layout, typeset
from pipelines.reports.render import Certificate, Section

TEXTS = [
    "AVATAR Tower Wave LT",  # kerning pairs
    "acc.misalign.xy",
    "+-0.5 m/s^2",
    "20.4 deg C",
    "µ ± ° Ω ≤ ≥ – —",
    "outliers interpolated 35 of 6000 samples (acc.x 3, acc.y 10)",
    "ed6cb6660d2835ab6795a9a6b16c9972",
]


def test_columns_that_fit_are_widened_in_proportion() -> None:
    assert table_layout.column_widths([100.0, 50.0, 50.0], 400.0) == [200.0, 100.0, 100.0]


def test_columns_too_wide_shrink_as_typst_shrinks_auto_columns() -> None:
    """A column within the fair share keeps its width; the others share what is left."""
    widths = table_layout.column_widths([50.0, 300.0, 400.0], 500.0)
    assert widths == pytest.approx([50.0, 225.0, 225.0])
    # 120 is above the first fair share (500 / 3) but within the second ((500 - 50) / 2)
    assert table_layout.column_widths([50.0, 200.0, 400.0], 500.0) == pytest.approx(
        [50.0, 200.0, 250.0]
    )


def test_a_row_is_one_line_only_if_every_text_fits_with_room_for_kerning() -> None:
    def measure(text: str, bold: bool) -> tuple[float, bool]:
        return 10.0 * len(text), "\n" not in text

    factor, spare = table_layout.KERNING_SPARE
    rows = [[("ab", True), ("cd", False)], [("abcdefgh", False), ("x", False)]]
    natural = [80 * factor + spare, 20 * factor + spare]  # with room for kerning
    widths, one_line = table_layout.plan(rows, measure, 2 * sum(natural), 0.0)
    assert widths == pytest.approx([2 * w for w in natural]) and one_line == [True, True]
    # too narrow for the long text: its column shrinks to what is left, its row wraps
    widths, one_line = table_layout.plan(rows, measure, 60.0, 0.0)
    assert widths == pytest.approx([60.0 - natural[1], natural[1]])
    assert one_line == [True, False]
    assert table_layout.plan([[("a\nb", False)]], measure, 100.0, 0.0)[1] == [False]


def _typst_widths(texts: list[str], bold: bool) -> list[float]:
    import typst

    src = b"""#set text(font: "DejaVu Sans", size: float(sys.inputs.size) * 1pt, lang: "en",
  hyphenate: false)
#context [#metadata(json(bytes(sys.inputs.texts)).map(t =>
  measure(text(weight: sys.inputs.weight, t)).width / 1pt)) <w>]
"""
    out = typst.query(
        src,
        "<w>",
        field="value",
        one=True,
        font_paths=typeset.fonts(),
        ignore_system_fonts=True,
        sys_inputs={
            "size": str(typeset.TABLE_TEXT_PT),
            "texts": json.dumps(texts),
            "weight": "bold" if bold else "regular",
        },
    )
    return json.loads(out)


@pytest.mark.parametrize("bold", [False, True])
def test_a_texts_width_with_the_spare_is_never_less_than_typsts(bold) -> None:
    metrics = typeset.Metrics()
    metrics.measure({c for t in TEXTS for c in t})
    factor, spare = table_layout.KERNING_SPARE
    for text, typst_width in zip(TEXTS, _typst_widths(TEXTS, bold), strict=True):
        width, one_line = metrics.width(text, bold)
        assert one_line, text
        assert width * factor + spare >= typst_width, (text, width, typst_width)


def _words(pdf: bytes, tmp_path: Path, name: str) -> list[tuple[str, str, str, str]]:
    """Each word of the PDF with its page and box (pdftotext -bbox)."""
    pdftotext = shutil.which("pdftotext")
    assert pdftotext, "pdftotext missing: scripts/ensure_system_packages.sh installs poppler-utils"
    path = tmp_path / f"{name}.pdf"
    path.write_bytes(pdf)
    html = subprocess.run(
        [pdftotext, "-bbox", str(path), "-"], capture_output=True, text=True, check=True
    ).stdout
    words = []
    for page, body in enumerate(html.split("<page ")[1:]):
        for m in re.finditer(r'xMin="([\d.]+)" yMin="([\d.]+)" [^>]*>([^<]*)<', body):
            words.append((str(page), m[1], m[2], m[3]))
    return words


def _certificate() -> Certificate:
    long = "a requirement long enough to wrap in its column " * 6
    rows = [[f"p{i}", f"{0.001 * i:.4f}", "m/s^2", "pass"] for i in range(70)]
    rows[3][3] = "FAIL"
    rows[5][2] = long
    rows[9][0] = "line\nbreak"
    rows[11][1] = "𝛼 ℵ ∰ ⟦"  # some from a fallback font (STIX)
    return Certificate(
        title="Layout",
        verdict="fail",
        sections=[
            Section("Pairs", pairs=[("Key", "value"), ("A longer key", long)]),
            Section("Table", header=["parameter", "value", "unit", "result"], rows=rows),
        ],
        figures={},
        protocol="",
        identifier="T-1",
    )


def test_rows_held_to_one_line_set_the_page_as_typst_alone_would(tmp_path) -> None:
    """The certificate set with the worked-out rows has every word where Typst puts it
    when it measures every row itself (across pages: the table breaks, its header repeats)."""
    import typst

    cert = _certificate()
    doc = typeset.document(cert)
    tables = [t for s in doc["sections"] for t in s["tables"]]
    assert all(sum(h is None for h in t["rows"]) for t in tables)  # some rows wrap
    assert sum(h is not None for t in tables for h in t["rows"]) > 60

    def pdf(document: dict) -> bytes:
        return typst.compile(
            typeset.TEMPLATE.read_bytes(),
            root=str(typeset.TEMPLATE.parent),
            font_paths=typeset.fonts(),
            ignore_system_fonts=True,
            sys_inputs={"doc": json.dumps(document)},
        )

    planned = _words(typeset.pdf_bytes(cert), tmp_path, "planned")
    for t in tables:
        t["rows"] = [None] * len(t["rows"])
    measured = _words(pdf(doc), tmp_path, "measured")
    assert planned == measured
    assert {p for p, *_ in planned} == {"0", "1"}  # two pages
    assert sum(w == "parameter" for *_, w in planned) == 2  # the header on each
