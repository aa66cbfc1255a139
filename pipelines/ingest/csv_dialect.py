"""How a delimited text file is written: metadata lines, header, delimiter, decimal mark, units.

Spreadsheet exports and loggers differ: some write metadata lines (device,
date, firmware) before the header; European exports use ``;`` between fields
and ``,`` as decimal mark; headers carry units (``gyro_x [deg/s]``,
``acc_z (g)``); fields may be quoted. :func:`sniff` finds all of it from the
first lines of the file, and the manifest can override each
(``skip_lines``, ``delimiter``, ``decimal``, the ``*_unit`` fields).

Rules (docs/manifest.md):

- the first *data line* is the first line whose fields are all numbers (or
  ISO-8601 times, or a short word: a section column) with at least 2 numbers,
  for some delimiter among ``,`` ``;`` tab and whitespace (the one giving the
  most fields; a ``,`` with numbers on both sides inside ``;``- or
  tab-separated fields is a decimal comma);
- with a header, the header is the last non-blank line before it; the lines
  before the header are metadata and skipped;
- a header name ``base [unit]`` or ``base (unit)`` is recognised by its base
  and gives its unit.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

from pipelines.ingest.data_format import FormatSpec
from pipelines.ingest.errors import IngestError

PROBE_LINES = 200  # lines examined to find the header and the data
_CANDIDATES = (",", ";", "\t", "whitespace")
_ISO = re.compile(r"^\d{4}-\d\d-\d\d[T ]\d\d:\d\d")
_WORD = re.compile(r"^[A-Za-z][A-Za-z0-9_.+-]{0,31}$")
_UNIT = re.compile(r"^(?P<base>.*?)\s*[\[(](?P<unit>[^\[\]()]+)[\])]\s*$")
# Unit spellings seen in headers -> calib_core.units names.
UNIT_ALIASES = {
    "m/s²": "m/s^2", "m/s/s": "m/s^2", "ms^-2": "m/s^2", "m s^-2": "m/s^2", "m/s2": "m/s^2",
    "°/s": "deg/s", "dps": "deg/s", "deg/sec": "deg/s", "°/sec": "deg/s",
    "rad/sec": "rad/s", "rps": "rad/s",
    "sec": "s", "msec": "ms", "µs": "us", "usec": "us", "nsec": "ns",
    "degc": "degC", "°c": "degC", "c": "degC", "deg c": "degC", "celsius": "degC",
}  # fmt: skip


@dataclass(frozen=True)
class Dialect:
    """What :func:`sniff` found.

    Attributes
    ----------
    delimiter : ``,``, ``;``, ``\\t`` or ``whitespace``.
    decimal : ``.`` or ``,``.
    header_line : 1-based line of the header (0 when the file has none).
    data_start : 1-based line of the first data line.
    names : the header's fields (unquoted, stripped), or ``c0, c1, ...``.
    metadata : the lines before the header (shown by ``calib inspect``).
    """

    delimiter: str
    decimal: str
    header_line: int
    data_start: int
    names: list[str]
    metadata: list[str]


def split_fields(line: str, delimiter: str) -> list[str]:
    """The fields of one line: quotes honoured (``"a,b"`` is one field), stripped."""
    if delimiter == "whitespace":
        return [f.strip('"') for f in line.split()]
    return [f.strip() for f in next(csv.reader([line], delimiter=delimiter))]


def is_number(field: str, decimal: str = ",") -> bool:
    """Whether `field` reads as a number with `decimal` as its mark ("," also takes ".")."""
    try:
        float(field.replace(",", ".") if decimal == "," else field)
    except ValueError:
        return False
    return True


def _data_like(line: str, delimiter: str) -> tuple[int, str] | None:
    """(fields, decimal mark) if `line` reads as a data line with `delimiter`, else None."""
    fields = split_fields(line, delimiter)
    decimal = "," if delimiter != "," and any("," in f for f in fields) else "."
    numbers = sum(is_number(f, decimal) for f in fields)
    # Empty fields pass here (a trailing delimiter, a missing value): the reader names them.
    others = all(not f or is_number(f, decimal) or _ISO.match(f) or _WORD.match(f) for f in fields)
    return (len(fields), decimal) if numbers >= 2 and others else None


def _lines(path: Path) -> list[str]:
    """The first `PROBE_LINES` lines, decoded as UTF-8 (a BOM dropped; bad bytes replaced)."""
    try:
        with path.open("r", encoding="utf-8-sig", errors="replace", newline="") as fh:
            out = []
            for line in fh:
                out.append(line.rstrip("\r\n"))
                if len(out) >= PROBE_LINES:
                    break
            return out
    except FileNotFoundError:
        raise IngestError("file not found", file=path) from None
    except OSError as exc:
        raise IngestError(f"cannot read file: {exc.strerror or exc}", file=path) from None


def sniff(path: Path, fmt: FormatSpec) -> Dialect:
    """Find the header, the data start, the delimiter and the decimal mark of a text file.

    The manifest's ``skip_lines``, ``delimiter`` and ``decimal`` win over what is
    found. Raises IngestError naming the file when it is empty or no line of
    numbers is found in its first `PROBE_LINES` lines.
    """
    lines = _lines(path)
    if not any(line.strip() for line in lines):
        raise IngestError("file is empty", file=path)
    skip = fmt.skip_lines
    found = _first_data(lines, fmt, skip or 0)
    nonblank = [i for i in range(skip or 0, len(lines)) if lines[i].strip()]
    if not nonblank:
        raise IngestError(
            f"nothing after the {skip} lines skipped (format.skip_lines)",
            file=path,
            field="format.skip_lines",
        )
    if found is None:
        raise IngestError(
            f"no data rows: no line of numbers separated by ',', ';', tab or spaces in the "
            f"first {len(lines)} lines; the first line reads {lines[nonblank[0]][:60]!r}",
            file=path,
        )
    before = [i for i in nonblank if i < found[0]]
    if fmt.header and (not before or _numeric(lines[before[-1]], found)):
        # No header-like line before the first data line: the first line is the header
        # and a data line is broken (or there are none); the reader names the bad line.
        found, before = None, nonblank[:1]
    if found is None:  # a broken data line: as without metadata, the reader finds it
        first = lines[nonblank[0]]
        delimiter = fmt.delimiter or _count_delimiter(first)
        found = (nonblank[0] + 1 if fmt.header else nonblank[0], delimiter, fmt.decimal or ".")
    data_index, delimiter, decimal = found
    if fmt.header:
        header_index = before[0] if skip is not None else before[-1]
        names = split_fields(lines[header_index], delimiter)
        metadata = [line for line in lines[:header_index] if line.strip()]
        data_start = header_index + 2
        header_line = header_index + 1
    else:
        count = len(split_fields(lines[data_index], delimiter))
        names = [f"c{i}" for i in range(count)]
        metadata = [line for line in lines[:data_index] if line.strip()]
        data_start, header_line = data_index + 1, 0
    return Dialect(delimiter, decimal, header_line, data_start, names, metadata)


def _first_data(lines: list[str], fmt: FormatSpec, skip: int) -> tuple[int, str, str] | None:
    """(0-based index, delimiter, decimal) of the first data line at or after `skip`."""
    candidates = (fmt.delimiter,) if fmt.delimiter else _CANDIDATES
    for i in range(skip, len(lines)):
        if not lines[i].strip():
            continue
        following = next((line for line in lines[i + 1 :] if line.strip()), None)
        best = None
        for delimiter in candidates:
            seen = _data_like(lines[i], delimiter)
            if not seen or (best is not None and seen[0] <= best[0]):
                continue
            # Two lines alike: a metadata line such as "Date 2024 05 01" is not taken for data.
            after = _data_like(following, delimiter) if following is not None else seen
            if after and after[0] == seen[0]:
                best = (seen[0], delimiter, seen[1])
        if best is not None:
            decimal = fmt.decimal or best[2]
            return i, best[1], decimal
    return None


def _numeric(line: str, found: tuple[int, str, str] | None) -> bool:
    """True if half or more of the fields of `line` are numbers (a data line, not a header)."""
    if found is None:
        return False
    fields = split_fields(line, found[1])
    return 2 * sum(is_number(f, found[2]) for f in fields) >= len(fields)


def _count_delimiter(line: str) -> str:
    """The most frequent of ``, ; \t`` in `line`; whitespace if none."""
    counts = {d: line.count(d) for d in (",", ";", "\t")}
    best = max(counts, key=counts.__getitem__)
    return best if counts[best] else "whitespace"


def split_unit(name: str) -> tuple[str, str | None]:
    """(base, unit or None) of a header name: ``"gyro_x [deg/s]"`` -> ``("gyro_x", "deg/s")``."""
    m = _UNIT.match(name)
    if m is None or not m["base"]:
        return name, None
    unit = m["unit"].strip()
    return m["base"], UNIT_ALIASES.get(unit.lower(), UNIT_ALIASES.get(unit, unit))
