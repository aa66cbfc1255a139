"""The certificate's layout: its sections and figures rendered as HTML and as PDF.

What a certificate says is gathered from the archive in pipelines.reports.certificate;
this module only lays it out. The HTML is one self-contained file (inline CSS, plots
as base64 PNG); the PDF is drawn by matplotlib's PdfPages (text pages, then one page
per plot), so neither a browser nor LaTeX is needed.
"""

from __future__ import annotations

import html
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
from matplotlib.backends.backend_pdf import PdfPages  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from calib_core.verification import (  # noqa: E402
    NEEDS_REVIEW,
    PASS,
)
from pipelines.reports import plots  # noqa: E402

A4 = (8.27, 11.69)  # inches
PDF_FONT_PT = 7.5
PDF_LINES_PER_PAGE = 92
PDF_WIDTH_CHARS = 112


@dataclass
class Section:
    """One part of the certificate: a key/value list, a table or paragraphs."""

    title: str
    pairs: list[tuple[str, str]] = field(default_factory=list)
    header: list[str] = field(default_factory=list)
    rows: list[list[str]] = field(default_factory=list)
    paragraphs: list[str] = field(default_factory=list)


@dataclass
class Certificate:
    """Everything the certificate prints, gathered from the archive."""

    title: str
    verdict: str
    sections: list[Section]
    figures: dict[str, Figure]
    protocol: str
    identifier: str = ""  # the certificate number, on every page (ISO/IEC 17025 7.8.2.1 d)

    @property
    def end(self) -> str:
        """The line that marks the certificate's clear end."""
        return f"End of certificate {self.identifier}".strip()


_CSS = """
body { font-family: Helvetica, Arial, sans-serif; font-size: 10pt; margin: 2em; color: #111; }
h1 { font-size: 16pt; } h2 { font-size: 12pt; border-bottom: 1px solid #999; margin-top: 1.4em; }
table { border-collapse: collapse; margin: 0.4em 0; }
td, th { border: 1px solid #bbb; padding: 2px 6px; font-size: 9pt; text-align: left; }
th { background: #eee; } td.FAIL { color: #b00; font-weight: bold; }
.verdict { font-size: 14pt; font-weight: bold; padding: 4px 10px; display: inline-block; }
.pass { background: #cfc; } .fail { background: #fcc; } .needs-review { background: #ffc; }
img { max-width: 100%; }
"""


def render_html(cert: Certificate) -> str:
    """The certificate as one self-contained HTML document (plots embedded as base64 PNG)."""
    e = html.escape
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{e(cert.title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{e(cert.title)}</h1>",
        f"<p>Certificate number {e(cert.identifier)}</p>" if cert.identifier else "",
        f'<p class="verdict {cert.verdict.replace(" ", "-")}">'
        f"Verdict: {e(cert.verdict.upper())}</p>",
    ]
    for sec in cert.sections:
        parts.append(f"<h2>{e(sec.title)}</h2>")
        if sec.pairs:
            parts.append("<table>")
            parts += [f"<tr><th>{e(k)}</th><td>{e(v)}</td></tr>" for k, v in sec.pairs]
            parts.append("</table>")
        if sec.header:
            parts.append("<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in sec.header) + "</tr>")
            for row in sec.rows:
                cells = "".join(
                    f'<td class="{e(c)}">{e(c)}</td>' if c == "FAIL" else f"<td>{e(c)}</td>"
                    for c in row
                )
                parts.append(f"<tr>{cells}</tr>")
            parts.append("</table>")
        parts += [f"<p>{e(p)}</p>" for p in sec.paragraphs]
    if cert.figures:
        parts.append("<h2>Plots</h2>")
    for name, fig in cert.figures.items():
        data = plots.to_png_base64(fig)
        parts.append(
            f'<figure><img alt="{e(name)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{e(name)}</figcaption></figure>"
        )
    parts.append(f"<p><strong>{e(cert.end)}</strong></p></body></html>")
    return "\n".join(parts) + "\n"


# --- PDF ---------------------------------------------------------------------------------


def _text_lines(cert: Certificate) -> list[tuple[str, str]]:
    """(style, text) lines of the text pages; style "title", "verdict", "head" or "mono"."""
    banner = f"Verdict: {cert.verdict.upper()}"
    lines: list[tuple[str, str]] = [("title", cert.title), ("verdict", banner), ("mono", "")]
    wrap = textwrap.TextWrapper(width=PDF_WIDTH_CHARS, subsequent_indent="  ")
    for sec in cert.sections:
        lines += [("mono", ""), ("head", sec.title)]
        width = max((len(k) for k, _ in sec.pairs), default=0)
        for k, v in sec.pairs:
            lines += [("mono", s) for s in wrap.wrap(f"{k:<{width}} : {v}")]
        if sec.header:
            table = [sec.header, *sec.rows]
            # The free-text detail column of check tables goes last and may be cut.
            widths = [max(len(r[i]) for r in table) for i in range(len(sec.header))]
            for row in table:
                text = "  ".join(f"{c:<{w}}" for c, w in zip(row, widths, strict=True))
                lines.append(("mono", text[:PDF_WIDTH_CHARS]))
        for p in sec.paragraphs:
            lines += [("mono", s) for s in wrap.wrap(p)]
    end = cert.end if not cert.figures else f"{cert.end} (its plots follow on the next pages)"
    return [*lines, ("mono", ""), ("head", end)]


def render_pdf(cert: Certificate, path: Path) -> Path:
    """Write the certificate as PDF: A4 text pages, then one page per plot."""
    path = Path(path)
    lines = _text_lines(cert)
    with matplotlib.rc_context({"pdf.fonttype": 3}), PdfPages(path) as pdf:
        # Type 3 fonts (matplotlib's default) keep the text extractable and searchable
        # and are subset quickly; Type 42 embedding costs seconds per document.
        pages = [
            lines[i : i + PDF_LINES_PER_PAGE] for i in range(0, len(lines), PDF_LINES_PER_PAGE)
        ]
        total = len(pages) + len(cert.figures)
        for n, page in enumerate(pages, start=1):
            fig = Figure(figsize=A4)
            y = 0.965
            for style, text in page:
                if style == "title":
                    fig.text(0.06, y, text, size=14, weight="bold")
                elif style == "verdict":
                    colour = {PASS: "#070", NEEDS_REVIEW: "#a60"}.get(cert.verdict, "#b00")
                    fig.text(0.06, y - 0.004, text, size=11, weight="bold", color=colour)
                elif style == "head":
                    fig.text(0.06, y, text, size=9.5, weight="bold", color="#123")
                else:
                    colour = "#b00" if "FAIL" in text or text.endswith(": FAIL") else "black"
                    fig.text(0.06, y, text, size=PDF_FONT_PT, family="monospace", color=colour)
                y -= 0.0102
            fig.text(0.06, 0.02, f"{cert.title}  -  certificate {cert.identifier}  -  "
                     f"verdict {cert.verdict.upper()}", size=7)
            fig.text(0.86, 0.02, f"page {n} of {total}", size=7)
            pdf.savefig(fig)
        for n, (name, fig) in enumerate(cert.figures.items(), start=len(pages) + 1):
            fig.suptitle(name, fontsize=10)
            fig.tight_layout()
            last = f"  -  {cert.end}" if n == total else ""
            fig.text(0.01, 0.005, f"certificate {cert.identifier}  -  page {n} of {total}{last}",
                     size=6)
            pdf.savefig(fig)
    return path
