"""Reading back what a reader of a typeset document sees: the words of an HTML page and the
text of each PDF page (poppler's pdftotext), for the tests that compare the two."""

from __future__ import annotations

import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path


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
