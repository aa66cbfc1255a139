"""The certificate's layout: its sections and figures rendered as HTML and as PDF.

What a certificate says is gathered from the archive in pipelines.reports.certificate;
this module only lays it out. The HTML is one self-contained file (inline CSS, plots
as base64 PNG); the PDF is that same HTML typeset by WeasyPrint (Pango fonts, tables
that wrap, a page header and footer with the certificate number and "page x of y"),
so the two never differ in what they say and neither a browser nor LaTeX is needed.
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any


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
    figures: dict[str, Any]  # name -> matplotlib Figure
    protocol: str
    identifier: str = ""  # the certificate number, on every page (ISO/IEC 17025 7.8.2.1 d)

    @cached_property
    def images(self) -> dict[str, str]:
        """Each figure as base64 PNG, drawn once (the figures are closed after it)."""
        from pipelines.reports import plots

        return {name: plots.to_png_base64(fig) for name, fig in self.figures.items()}

    @property
    def end(self) -> str:
        """The line that marks the certificate's clear end."""
        return f"End of certificate {self.identifier}".strip()


_CSS = """
body { font-family: "DejaVu Sans", Helvetica, Arial, sans-serif; font-size: 10pt; margin: 2em;
       color: #111; }
h1 { font-size: 16pt; } h2 { font-size: 12pt; border-bottom: 1px solid #999; margin-top: 1.4em; }
table { border-collapse: collapse; margin: 0.4em 0; }
td, th { border: 1px solid #bbb; padding: 2px 6px; font-size: 9pt; text-align: left;
         vertical-align: top; overflow-wrap: break-word; }
th { background: #eee; } td.FAIL { color: #b00; font-weight: bold; }
.verdict { font-size: 14pt; font-weight: bold; padding: 4px 10px; display: inline-block; }
.pass { background: #cfc; } .fail { background: #fcc; } .needs-review { background: #ffc; }
img { max-width: 100%; }
"""

# Print only (WeasyPrint): A4 pages, header and footer with the certificate number and
# "page x of y" on every page (ISO/IEC 17025 7.8.2.1 d), tables within the margins.
_PRINT_CSS = """
@page {
  size: A4; margin: 18mm 14mm 18mm 14mm; font-family: "DejaVu Sans", sans-serif;
  @top-left { content: %(title)s; font-size: 8pt; color: #444; }
  @top-right { content: %(number)s; font-size: 8pt; color: #444; }
  @bottom-left { content: %(number)s; font-size: 8pt; color: #444; }
  @bottom-right { content: "page " counter(page) " of " counter(pages); font-size: 8pt;
                  color: #444; }
}
body { margin: 0; font-size: 9pt; }
table { width: 100%%; table-layout: auto; }
td, th { font-size: 8pt; }
thead { display: table-header-group; }
tr, figure { break-inside: avoid; }
h2 { break-after: avoid; }
figure { margin: 0.5em 0; } img { width: 100%%; }
"""


def _css_string(text: str) -> str:
    """`text` as a CSS string literal (for the page header's `content`)."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", " ") + '"'


def render_html(cert: Certificate, *, for_print: bool = False) -> str:
    """The certificate as one self-contained HTML document (plots embedded as base64 PNG).

    `for_print` adds the page layout the PDF is typeset with (`render_pdf`); what the
    document says is the same.
    """
    e = html.escape
    css = _CSS
    if for_print:
        number = f"Certificate {cert.identifier}" if cert.identifier else cert.title
        css += _PRINT_CSS % {"title": _css_string(cert.title), "number": _css_string(number)}
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{e(cert.title)}</title><style>{css}</style></head><body>",
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
            parts.append(
                "<table><thead><tr>"
                + "".join(f"<th>{e(h)}</th>" for h in sec.header)
                + "</tr></thead><tbody>"
            )
            for row in sec.rows:
                cells = "".join(
                    f'<td class="{e(c)}">{e(c)}</td>' if c == "FAIL" else f"<td>{e(c)}</td>"
                    for c in row
                )
                parts.append(f"<tr>{cells}</tr>")
            parts.append("</tbody></table>")
        parts += [f"<p>{e(p)}</p>" for p in sec.paragraphs]
    if cert.figures:
        parts.append("<h2>Plots</h2>")
    for name, data in cert.images.items():
        parts.append(
            f'<figure><img alt="{e(name)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{e(name)}</figcaption></figure>"
        )
    parts.append(f"<p><strong>{e(cert.end)}</strong></p></body></html>")
    return "\n".join(parts) + "\n"


def pdf_bytes(cert: Certificate) -> bytes:
    """The certificate typeset as PDF by WeasyPrint from its HTML (`render_html`)."""
    import weasyprint

    return weasyprint.HTML(string=render_html(cert, for_print=True)).write_pdf()


def render_pdf(cert: Certificate, path: Path) -> Path:
    """Write the certificate as PDF (`pdf_bytes`) to `path`; return it."""
    path = Path(path)
    path.write_bytes(pdf_bytes(cert))
    return path
