"""Run manifest, the free text: every text value a lab writes, within the archive's limits.

The manifest's names, labels and descriptions end up in archive columns and in
reports, so they are checked before any model sees them: a length the archive
keeps on every database back end, and no control character.
"""

from __future__ import annotations

import re
import unicodedata
from typing import Any

from pipelines.ingest.errors import IngestError

# Limits of free text (characters), the same on every database back end (check_free_text).
TEXT_MAX_CHARS = 200  # names, operator, labels, file names: one line (the archive's columns)
# Fields whose archive column is shorter (list indices written as []).
TEXT_MAX_BY_FIELD = {
    "run.procedure": 100,
    "equipment[].kind": 100,
    "equipment[].accuracy_class": 100,
}
LONG_TEXT_MAX_CHARS = 4000  # descriptions, which may hold line breaks
LONG_TEXT_FIELDS = frozenset({"unit.specification", "environment.vibration"})


def check_free_text(data: Any, source: str = "run.toml", field: str = "") -> None:
    """Every text value of a manifest within the archive's limits, whichever database follows.

    A value is at most `TEXT_MAX_CHARS` characters (`LONG_TEXT_MAX_CHARS` in
    `LONG_TEXT_FIELDS`, which may also hold line breaks and tabs) and holds no
    other control character (NUL included: PostgreSQL refuses it, SQLite keeps
    it). Raises IngestError naming the field, the limit and what was found.
    """
    if isinstance(data, dict):
        for key, value in data.items():
            check_free_text(value, source, f"{field}.{key}" if field else str(key))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            check_free_text(value, source, f"{field}[{i}]")
    elif isinstance(data, str):
        generic = re.sub(r"\[\d+\]", "[]", field)
        long = generic in LONG_TEXT_FIELDS
        limit = LONG_TEXT_MAX_CHARS if long else TEXT_MAX_BY_FIELD.get(generic, TEXT_MAX_CHARS)
        if len(data) > limit:
            raise IngestError(
                f"text of {len(data)} characters; at most {limit} are allowed here",
                file=source,
                field=field,
            )
        allowed = "\t\n\r" if long else ""
        bad = next((i for i, c in enumerate(data) if _is_control(c) and c not in allowed), None)
        if bad is not None:
            raise IngestError(
                f"control character {data[bad]!r} (U+{ord(data[bad]):04X}) at character "
                f"{bad + 1}; expected printable text" + ("" if long else " on one line"),
                file=source,
                field=field,
            )


def _is_control(c: str) -> bool:
    return unicodedata.category(c) == "Cc"
