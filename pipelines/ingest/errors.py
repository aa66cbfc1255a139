"""The one error type of ingest: it always says where the bad input is.

Every problem a lab can make in its files (a missing segment file, a truncated
log, a typo in the manifest) is reported as an :class:`IngestError` that names
the file, the line and/or the manifest field, and what was expected, so the
operator can fix the input without reading a traceback.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

QUOTE_LIMIT = 40  # characters of a value quoted from a file that a message shows
TOKEN_LIMIT = 300  # a longer run of characters without a space is cut (a 1M-character field)
# A number of 31 or more digits (a 300-digit rate from a damaged file) is shown in short.
_LONG_NUMBER = re.compile(r"""(?<![\w.'"])[-+]?\d[\d_]{30,}(?:\.\d*)?(?:[eE][-+]?\d+)?(?![\w.])""")
_LONG_TOKEN = re.compile(rf"\S{{{TOKEN_LIMIT + 1},}}")


class IngestError(ValueError):
    """Bad input found while reading a run.

    Parameters
    ----------
    problem : what is wrong and what was expected, e.g.
        ``"expected 8 numeric columns, got 7"``.
    file : the file (path or name) that holds the problem, if any.
    line : 1-based line number in `file`, if known.
    field : dotted manifest field (``"format.acc_unit"``, ``"segments[2].file"``)
        or a column name of a data file, if the problem is tied to one.

    The message reads ``"<file> line <line>: field '<field>': <problem>"`` with
    the parts that are unknown left out.
    """

    def __init__(
        self,
        problem: str,
        *,
        file: str | Path | None = None,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        self.problem = shortened(printable(problem))
        self.file = None if file is None else str(file)
        self.line = line
        self.field = None if field is None else shortened(printable(field))
        super().__init__(self._message())

    def _message(self) -> str:
        where = self.file or ""
        if self.line is not None:
            where = f"{where} line {self.line}" if where else f"line {self.line}"
        if self.field is not None:
            where = f"{where}: field '{self.field}'" if where else f"field '{self.field}'"
        return f"{where}: {self.problem}" if where else self.problem

    def __reduce__(self):  # keep the attributes when the error crosses a process pool
        return (_rebuild, (self.problem, self.file, self.line, self.field))


def file_head(path: str | Path, size: int) -> bytes:
    """The first `size` bytes of `path` (fewer in a shorter file); IngestError naming the
    file when it cannot be read."""
    try:
        with open(path, "rb") as fh:
            return fh.read(size)
    except OSError as exc:
        raise IngestError(f"cannot read file: {exc.strerror or exc}", file=path) from None


def printable(text: str) -> str:
    """`text` with control and other unprintable characters escaped (``\\x00``).

    Problems quote bytes from damaged files (a topic name, a header); a NUL or
    an escape sequence must not reach the operator's terminal, a log or a page
    as itself. Line breaks and tabs stay.
    """
    if text.isprintable():
        return text
    return "".join(
        c if c.isprintable() or c in "\n\t" else c.encode("unicode_escape").decode("ascii")
        for c in text
    )


def quoted(value: str, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)``, cut to its first `limit` characters with its length said."""
    if len(value) <= limit:
        return repr(value)
    return f"{value[:limit]!r}... ({len(value)} characters)"


def shortened(text: str) -> str:
    """`text` with numbers of 31+ digits in 6 significant digits and runs of more than
    `TOKEN_LIMIT` characters without a space cut, their length said: a value from a
    damaged file is named, not printed in full."""
    text = _LONG_NUMBER.sub(_short_number, text)
    return _LONG_TOKEN.sub(lambda m: f"{m.group()[:60]}... ({len(m.group())} characters)", text)


def _short_number(match: re.Match) -> str:
    digits = match.group()
    try:
        value = float(digits.replace("_", ""))
    except ValueError:
        value = math.inf
    if math.isfinite(value):
        return f"{value:.6g}"
    return f"{digits[:8]}... (a number of {len(digits)} characters)"


def naming_the_run(exc: Exception, run: str) -> str:
    """The refusal text of `exc` for a run at `run` (its folder): an IngestError names its
    file already; any other error (a solver's "every standard uncertainty ... must be
    > 0") gets the run's folder put first, so every refusal says where."""
    text = shortened(printable(str(exc)))
    if isinstance(exc, IngestError) and exc.file is not None:
        return text
    return text if run in text else f"{run}: {text}"


def _rebuild(problem: str, file: str | None, line: int | None, field: str | None) -> IngestError:
    return IngestError(problem, file=file, line=line, field=field)
