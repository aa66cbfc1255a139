"""Reader of delimited text files (CSV) described by the manifest's ``[format]`` section.

The columns and units are the manifest's (``FormatSpec``); values are
converted to SI with calib_core.units. The whole file is parsed by pandas' C
engine in one pass; only when that pass finds a problem is the file read
again as text to name the first bad line and column.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from calib_core.recording import Recording
from calib_core.units import acceleration_factor, angular_rate_factor, time_factor
from pipelines.ingest.errors import IngestError
from pipelines.ingest.manifest import Column, FormatSpec


def detect_delimiter(first_line: str) -> str:
    """The delimiter of a CSV file from its first line: ``,``, ``;``, tab or ``whitespace``.

    The most frequent of ``, ; \\t`` wins; a line with none of them is
    whitespace-separated.
    """
    counts = {d: first_line.count(d) for d in (",", ";", "\t")}
    best = max(counts, key=counts.__getitem__)
    return best if counts[best] else "whitespace"


def _first_line(path: Path) -> tuple[str, int]:
    """First non-blank line of the file and its 1-based number."""
    try:
        with path.open("r", encoding="utf-8-sig", errors="replace") as fh:
            for number, line in enumerate(fh, start=1):
                if line.strip():
                    return line.rstrip("\r\n"), number
    except FileNotFoundError:
        raise IngestError("file not found", file=path) from None
    raise IngestError("file is empty", file=path)


def read_csv(path: Path, fmt: FormatSpec) -> Recording:
    """Read a whole delimited text file into a Recording in SI units.

    Parameters
    ----------
    path : the data file.
    fmt : the manifest's format section (kind ``"csv"``): delimiter, header,
        column names (or 0-based indices without a header) and units.

    Returns
    -------
    Recording with t (N,) s, acc (N, 3) m/s^2, gyr (N, 3) rad/s, temp (N,)
    deg C if ``temp_column`` is given, reference channels from
    ``reference_columns``; no label; source = the path.

    Raises
    ------
    IngestError naming the file, and the line and column where it applies: an
    empty file, a named column that is not in the file, a non-numeric,
    missing or non-finite value, time that does not increase.
    """
    path = Path(path)
    if fmt.time_column is None or fmt.acc_columns is None or fmt.gyr_columns is None:
        raise IngestError("format needs time_column, acc_columns and gyr_columns", field="format")
    first, first_no = _first_line(path)
    delimiter = fmt.delimiter or detect_delimiter(first)
    sep = r"\s+" if delimiter == "whitespace" else delimiter
    wanted = list(dict.fromkeys(fmt.columns()))  # unique, in manifest order
    header_lines = first_no if fmt.header else first_no - 1  # lines before the first data row
    _check_columns(path, fmt, first, sep, wanted, first_no)

    options = {
        "sep": sep,
        "header": 0 if fmt.header else None,
        "usecols": wanted,
        "skip_blank_lines": False,  # keep row i on line header_lines + 1 + i
        "skiprows": first_no - 1,
        "engine": "c",
        "encoding": "utf-8-sig",
    }
    try:
        frame = pd.read_csv(path, dtype=dict.fromkeys(wanted, "float64"), **options)
        values = frame[wanted].to_numpy()
    except pd.errors.ParserError as exc:
        m = re.search(r"line (\d+)", str(exc))
        line = int(m.group(1)) + first_no - 1 if m else None
        raise IngestError(
            f"cannot split the line into columns: {exc}", file=path, line=line
        ) from None
    except ValueError:  # text in a numeric column: find it below
        values = None

    if values is not None:
        # A file may end in blank lines; they are not samples.
        filled = ~np.isnan(values).all(axis=1)
        values = values[: (np.flatnonzero(filled)[-1] + 1) if filled.any() else 0]
    if values is None or not np.isfinite(values).all():
        _diagnose(path, options, wanted, header_lines)
        raise IngestError("could not parse the numeric columns", file=path)  # not reached
    if values.shape[0] == 0:
        raise IngestError("no data rows", file=path)

    col = {c: i for i, c in enumerate(wanted)}
    t = seconds(values[:, col[fmt.time_column]], fmt.time_unit)
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = bad[0] + 1
        raise IngestError(
            f"time {t[i]:.9g} s is not after the previous row's {t[i - 1]:.9g} s "
            "(time must increase)",
            file=path,
            line=header_lines + 1 + i,
            field=str(fmt.time_column),
        )
    acc = values[:, [col[c] for c in fmt.acc_columns]] * acceleration_factor(fmt.acc_unit)
    gyr = values[:, [col[c] for c in fmt.gyr_columns]] * angular_rate_factor(fmt.gyr_unit)
    temp = None if fmt.temp_column is None else values[:, col[fmt.temp_column]].copy()
    reference = {name: values[:, col[c]].copy() for name, c in fmt.reference_columns.items()}
    return Recording(t=t, acc=acc, gyr=gyr, temp=temp, reference=reference, source=str(path))


MATLAB_UNIX_EPOCH_DATENUM = 719529.0  # datenum of 1970-01-01


def seconds(values: np.ndarray, unit: str) -> np.ndarray:
    """Time values in `unit` (s, ms, us, ns, or MATLAB ``datenum`` days) as seconds.

    datenum becomes Unix seconds: (dn - 719529) * 86400.
    """
    if unit == "datenum":
        return (values - MATLAB_UNIX_EPOCH_DATENUM) * 86400.0
    return values * time_factor(unit)


def _check_columns(
    path: Path, fmt: FormatSpec, first: str, sep: str, wanted: list[Column], first_no: int
) -> None:
    """Every column the manifest names must exist in the file."""
    present = re.split(sep, first.strip()) if sep == r"\s+" else first.split(sep)
    present = [p.strip().strip('"') for p in present]
    for name in wanted:
        if fmt.header and name not in present:
            raise IngestError(
                f"column {name!r} named in the manifest is not in the header; "
                f"the header has: {', '.join(present)}",
                file=path,
                line=first_no,
                field=_field_of(fmt, name),
            )
        if not fmt.header and not (isinstance(name, int) and 0 <= name < len(present)):
            raise IngestError(
                f"column {name!r}: without a header, columns are 0-based indices "
                f"below {len(present)} (the first line has {len(present)} columns)",
                file=path,
                line=first_no,
                field=_field_of(fmt, name),
            )


def _field_of(fmt: FormatSpec, column: Column) -> str:
    """The manifest field that names `column`, for error messages."""
    for field in ("time_column", "temp_column"):
        if getattr(fmt, field) == column:
            return f"format.{field}"
    for field in ("acc_columns", "gyr_columns"):
        if column in (getattr(fmt, field) or []):
            return f"format.{field}"
    return "format.reference_columns"


def _diagnose(path: Path, options: dict, wanted: list[Column], header_lines: int) -> None:
    """Raise IngestError at the first value that is not a finite number (slow path)."""
    text = pd.read_csv(path, dtype=str, keep_default_na=False, **options)[wanted]
    raw = text.to_numpy(dtype=str)
    numbers = text.apply(pd.to_numeric, errors="coerce").to_numpy(dtype=float)
    bad = ~np.isfinite(numbers)
    # Trailing blank lines are not samples.
    filled = (raw != "").any(axis=1)
    last = np.flatnonzero(filled)[-1] + 1 if filled.any() else 0
    bad[last:] = False
    rows, cols = np.nonzero(bad)
    if rows.size:
        i, j = rows[0], cols[0]  # row-major order: the first bad cell
        value = str(raw[i, j])
        got = "an empty value (missing column or blank line)" if value == "" else repr(value)
        raise IngestError(
            f"expected a finite number, got {got}",
            file=path,
            line=header_lines + 1 + int(i),
            field=str(wanted[j]),
        )
