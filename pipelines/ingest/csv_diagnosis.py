"""CSV reader, the diagnosis of bad input: the first bad line and column, named.

The fast path (pipelines.ingest.csv_reader) parses blocks of many lines at once
and only sees that a block holds a value that is not a finite number. Only then
is the file read again as text, in chunks (bounded memory), to name the first
bad line and column, or the first byte that is not UTF-8.
"""

from __future__ import annotations

import codecs
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipelines.ingest.csv_dialect import split_fields
from pipelines.ingest.csv_layout import CsvLayout
from pipelines.ingest.errors import IngestError, quoted

if TYPE_CHECKING:
    import pandas as pd  # imported where a frame is made (slow to import)

PANDAS_CHUNK_ROWS = 1_000_000  # rows per chunk of text read by pandas (here and the reader's)


def diagnose(layout: CsvLayout, columns: list[str], iso_column: str | None, from_row: int) -> None:
    """Raise IngestError at the first value that is not a finite number (or valid ISO time).

    Reads the file again as text in chunks (bounded memory), from data row
    `from_row` on.
    """
    import pandas as pd

    sep = r"\s+" if layout.delimiter == "whitespace" else layout.delimiter
    try:
        reader = pd.read_csv(
            layout.path,
            sep=sep,
            header=None,
            names=layout.names,
            usecols=columns,
            dtype=str,
            keep_default_na=False,
            skiprows=layout.data_start - 1,
            engine="c",
            encoding="utf-8-sig",
            chunksize=PANDAS_CHUNK_ROWS,
        )
        row0 = 0
        with reader:
            for text in reader:
                if row0 + len(text) > from_row:
                    _first_bad(layout, text[columns], iso_column, row0)
                row0 += len(text)
    except UnicodeDecodeError:
        _raise_not_utf8(layout.path)
        raise
    except pd.errors.ParserError as exc:
        m = re.search(r"line (\d+)", str(exc))
        line = int(m.group(1)) + layout.data_start - 1 if m else _wrong_count_line(layout)
        raise IngestError(
            f"cannot split the line into columns: {exc}", file=layout.path, line=line
        ) from None


def _wrong_count_line(layout: CsvLayout) -> int | None:
    """1-based line of the first data line whose field count is not the header's."""
    with layout.path.open("r", encoding="utf-8", errors="replace", newline="") as fh:
        for number, line in enumerate(fh, start=1):
            fields = split_fields(line.rstrip("\r\n"), layout.delimiter)
            if number >= layout.data_start and line.strip() and len(fields) != len(layout.names):
                return number
    return None


def _raise_not_utf8(path: Path) -> None:
    """Raise IngestError at the first byte of `path` that is not UTF-8 (line, column, byte)."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    line, offset = 1, 0
    with path.open("rb") as fh:
        while block := fh.read(1 << 20):
            try:
                decoder.decode(block)
            except UnicodeDecodeError as exc:
                data = decoder.getstate()[0] + block  # undecoded bytes carried over + block
                bad = exc.start
                start = data.rfind(b"\n", 0, bad) + 1
                line += data.count(b"\n", 0, bad)
                column = len(data[start:bad].decode("utf-8", errors="replace")) + 1
                raise IngestError(
                    f"not UTF-8 text: byte 0x{data[bad]:02x} at column {column} (byte offset "
                    f"{offset - len(decoder.getstate()[0]) + bad}); save the file as UTF-8",
                    file=path,
                    line=line,
                ) from None
            line += block.count(b"\n")
            offset += len(block)


def _first_bad(layout: CsvLayout, text: pd.DataFrame, iso_column: str | None, row0: int) -> None:
    import pandas as pd

    raw = text.to_numpy(dtype=object)  # not dtype=str: one 1M-character field would size every cell
    bad = np.zeros(raw.shape, dtype=bool)
    for j, c in enumerate(text.columns):
        if c == iso_column:
            parsed = pd.to_datetime(text[c], errors="coerce", utc=True, format="ISO8601")
            bad[:, j] = parsed.isna().to_numpy()
        elif c == layout.roles.get("section"):
            bad[:, j] = (text[c] == "").to_numpy()
        else:
            column = text[c].str.replace(",", ".") if layout.decimal == "," else text[c]
            numbers = pd.to_numeric(column, errors="coerce").to_numpy(dtype=float)
            bad[:, j] = ~np.isfinite(numbers)
    rows, cols = np.nonzero(bad)
    if rows.size:
        i, j = int(rows[0]), int(cols[0])  # row-major order: the first bad cell
        value = str(raw[i, j])
        got = "an empty value (missing column or blank line)" if value == "" else quoted(value)
        what = (
            "an ISO-8601 time"
            if text.columns[j] == iso_column
            else "a section name"
            if text.columns[j] == layout.roles.get("section")
            else "a finite number"
        )
        raise IngestError(
            f"expected {what}, got {got}",
            file=layout.path,
            line=layout.line_of_row(row0 + i),
            field=layout.fields[text.columns[j]],
        )
