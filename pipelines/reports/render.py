"""What a certificate shows (`Certificate`, its `Section`s and figures) and its HTML.

What a certificate says is gathered from the archive in pipelines.reports.certificate;
this module holds it and writes it as one self-contained HTML file (inline CSS, plots
as SVG images). pipelines.reports.typeset sets the same object as PDF pages, so the two
never differ in what they say.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field


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
    figures: dict[str, str]  # name -> SVG chart (pipelines.reports.figures)
    protocol: str
    identifier: str = ""  # the certificate number, on every page (ISO/IEC 17025 7.8.2.1 d)

    @property
    def images(self) -> dict[str, str]:
        """Each figure as a data: URI (base64 SVG), for the HTML's images."""
        return {
            name: "data:image/svg+xml;base64," + base64.b64encode(chart.encode()).decode("ascii")
            for name, chart in self.figures.items()
        }

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


def render_html(cert: Certificate) -> str:
    """The certificate as one self-contained HTML document (plots embedded as SVG images)."""
    e = html.escape
    css = _CSS
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
            f'<figure><img alt="{e(name)}" src="{data}"><figcaption>{e(name)}</figcaption></figure>'
        )
    parts.append(f"<p><strong>{e(cert.end)}</strong></p></body></html>")
    return "\n".join(parts) + "\n"
