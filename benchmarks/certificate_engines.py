"""The certificate's PDF by three engines, side by side on the same certificate.

The CSV sample of data_samples/ is archived (without its certificate) and its certificate
gathered once (`pipelines.reports.run_reports.certificate_of`); then each engine typesets
that same `Certificate` `REPEATS` + 1 times in this process (the first, with its imports
and warm-up, is left out) and the median CPU seconds (every thread) are kept:

- ``typst_cpu_s``: Typst, the engine calib uses (`pipelines.reports.typeset.pdf_bytes`);
- ``weasyprint_cpu_s``: WeasyPrint from the certificate's HTML (`render_html`) with an A4
  page, header and footer (the print style calib used with it);
- ``reportlab_cpu_s``: ReportLab's platypus, the sections as paragraphs and tables with a
  header and footer on every page; its figures are not drawn (ReportLab reads no SVG), so
  it does less than the others.

An engine that is not installed is reported as null (ReportLab is not a dependency of
calib: ``pip install reportlab`` to measure it). Progress goes to stderr; the last stdout
line is one JSON object with the figures.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data_samples" / "csv_IMU-2026-0042"
REPEATS = 5
PRINT_CSS = """
@page { size: A4; margin: 18mm 14mm;
  @top-left { content: "%(title)s"; font-size: 8pt; }
  @bottom-right { content: "page " counter(page) " of " counter(pages); font-size: 8pt; } }
body { margin: 0; font-size: 9pt; } table { width: 100%%; } td, th { font-size: 8pt; }
thead { display: table-header-group; } tr, figure { break-inside: avoid; }
"""


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def cpu_median(typeset) -> float:  # noqa: ANN001 - a callable of no arguments
    times = []
    for _ in range(REPEATS + 1):
        started = time.process_time()
        typeset()
        times.append(time.process_time() - started)
    return round(statistics.median(times[1:]), 3)


def weasyprint_pdf(cert) -> bytes:  # noqa: ANN001 - a Certificate
    import weasyprint

    from pipelines.reports.render import render_html

    page = render_html(cert).replace(
        "</style>", PRINT_CSS % {"title": cert.title.replace('"', "")} + "</style>", 1
    )
    return weasyprint.HTML(string=page).write_pdf()


def reportlab_pdf(cert) -> bytes:  # noqa: ANN001 - a Certificate
    import io
    from xml.sax.saxutils import escape

    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.styles import getSampleStyleSheet
    from reportlab.lib.units import mm
    from reportlab.platypus import LongTable, Paragraph, SimpleDocTemplate, Spacer

    styles = getSampleStyleSheet()
    cell = styles["BodyText"].clone("cell", fontSize=7, leading=8.5)
    grid = [
        ("GRID", (0, 0), (-1, -1), 0.5, colors.HexColor("#bbbbbb")),
        ("VALIGN", (0, 0), (-1, -1), "TOP"),
    ]

    def table(rows: list[list[str]], header: bool) -> LongTable:
        data = [[Paragraph(escape(c), cell) for c in row] for row in rows]
        style = [*grid, ("BACKGROUND", (0, 0), (-1 if header else 0, 0 if header else -1), "#eee")]
        return LongTable(data, repeatRows=1 if header else 0, style=style, hAlign="LEFT")

    story = [Paragraph(escape(cert.title), styles["Title"])]
    story.append(Paragraph(f"Verdict: {escape(cert.verdict.upper())}", styles["Heading2"]))
    for sec in cert.sections:
        story.append(Paragraph(escape(sec.title), styles["Heading2"]))
        if sec.pairs:
            story.append(table([list(p) for p in sec.pairs], header=False))
        if sec.header:
            story.append(table([sec.header, *sec.rows], header=True))
        story += [Paragraph(escape(p), styles["BodyText"]) for p in sec.paragraphs]
        story.append(Spacer(1, 4))
    story.append(Paragraph(escape(cert.end), styles["BodyText"]))

    def furniture(canvas, doc) -> None:  # noqa: ANN001 - reportlab's page callback
        canvas.setFont("Helvetica", 8)
        canvas.drawString(14 * mm, A4[1] - 12 * mm, cert.title)
        canvas.drawRightString(A4[0] - 14 * mm, 10 * mm, f"page {doc.page}")

    out = io.BytesIO()
    doc = SimpleDocTemplate(out, pagesize=A4, leftMargin=14 * mm, rightMargin=14 * mm)
    doc.build(story, onFirstPage=furniture, onLaterPages=furniture)
    return out.getvalue()


def main() -> None:
    os.environ["CALIB_ISSUE_CERTIFICATES"] = "0"
    sys.path.insert(0, str(ROOT))
    from pipelines.direct import process_in_process
    from pipelines.ingest import discover_runs
    from pipelines.reports.run_reports import certificate_of
    from pipelines.reports.typeset import pdf_bytes
    from storage.db import resolve_archive

    figures: dict[str, float | None] = {}
    with tempfile.TemporaryDirectory(prefix="calib-engines-") as tmp:
        (outcome,) = process_in_process(discover_runs([SAMPLE]), tmp)
        _, cert = certificate_of(resolve_archive(tmp), outcome["run_id"])
        cells = sum(len(s.pairs) * 2 + len(s.header) * (1 + len(s.rows)) for s in cert.sections)
        log(f"certificate of {outcome['run_id']}: {len(cert.sections)} sections, {cells} cells")
        engines = {"typst": pdf_bytes, "weasyprint": weasyprint_pdf, "reportlab": reportlab_pdf}
        for name, engine in engines.items():
            try:
                figures[f"{name}_cpu_s"] = cpu_median(lambda e=engine: e(cert))
            except ImportError as exc:
                log(f"{name}: not installed ({exc})")
                figures[f"{name}_cpu_s"] = None
                continue
            log(f"{name}: median {figures[f'{name}_cpu_s']} s CPU")
    figures["load_average"] = round(os.getloadavg()[0], 2)
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
