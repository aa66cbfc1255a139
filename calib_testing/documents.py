"""Reading back what a reader of a document sees: the words of an HTML page and the text of
each PDF page (poppler's pdftotext), for the tests that compare the two; a DCC's errors against
PTB's schema; the protocol of a run given by its parameters alone."""

from __future__ import annotations

import functools
import shutil
import subprocess
from collections.abc import Sequence
from datetime import UTC, datetime
from html.parser import HTMLParser
from pathlib import Path

from calib_core.calibration import Parameter
from pipelines.reports.protocol import render_protocol


class _Words(HTMLParser):
    """The words of an HTML document outside its style sheet and title."""

    def __init__(self) -> None:
        super().__init__()
        self.words: list[str] = []
        self._hidden = 0

    def handle_starttag(self, tag: str, attrs: list) -> None:
        self._hidden += tag in ("style", "title")

    def handle_endtag(self, tag: str) -> None:
        self._hidden -= tag in ("style", "title")

    def handle_data(self, data: str) -> None:
        if not self._hidden:
            self.words += data.split()


def html_words(html: str) -> list[str]:
    """The words a reader sees in `html` (not its style sheet or title), in order."""
    parser = _Words()
    parser.feed(html)
    return parser.words


def pdf_pages(path: Path) -> list[str]:
    """The text of each page of the PDF at `path` (pdftotext, one form feed per page)."""
    pdftotext = shutil.which("pdftotext")
    assert pdftotext, "pdftotext missing: scripts/ensure_system_packages.sh installs poppler-utils"
    out = subprocess.run([pdftotext, str(path), "-"], capture_output=True, text=True, check=True)
    return out.stdout.split("\f")[:-1]


DCC_SCHEMA = Path(__file__).resolve().parent.parent / "tests" / "schemas" / "dcc-3.3.0" / "dcc.xsd"


def dcc_schema_errors(xml: bytes) -> list[str]:
    """The errors of a DCC against PTB's DCC 3.3.0 schema (vendored under tests/schemas, its
    D-SI and XML Signature imports local, no network), one message each; [] when valid.

    xmlschema, not lxml: libxml2 leaves an IDREF that names no ID unreported."""

    return [str(e.reason) for e in _dcc_schema(str(DCC_SCHEMA)).iter_errors(xml.decode("utf-8"))]


@functools.cache
def _dcc_schema(path: str):  # noqa: ANN202 - xmlschema.XMLSchema
    import xmlschema

    return xmlschema.XMLSchema(path, allow="local")


def parameter_protocol(parameters: Sequence[Parameter], names: str = "canonical") -> str:
    """The protocol text of an MPU-6000 six-position run holding `parameters` (SI) and
    nothing else: no checks, verdict pass."""
    return render_protocol(
        device_model="MPU-6000",
        serial="S1",
        started_at=datetime(2026, 1, 1, tzinfo=UTC),
        run_id="R1",
        procedure="six_position",
        profile="mpu6000 v3",
        gravity=9.80665,
        operator="lab",
        parameters=parameters,
        checks=[],
        verdict="pass",
        names=names,
    )
