"""Checks for untrusted strings before they reach a file path or a query."""

from __future__ import annotations

import re

# Serials and other identifiers that become path components: letters, digits,
# dot, dash, underscore; no leading dot (so no "..", no hidden files); <= 64 chars.
_SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


def check_safe_name(value: str, what: str = "serial") -> str:
    """Return `value` if it can be used as one path component, else raise ValueError.

    Parameters
    ----------
    value : the untrusted string (a serial, a run id, a profile name).
    what : what the string is, for the error message.
    """
    if not isinstance(value, str) or not _SAFE_NAME.match(value) or ".." in value:
        raise ValueError(
            f"invalid {what} {value!r}: expected 1-64 characters of letters, digits, "
            "'.', '-', '_', not starting with '.' and without '..'"
        )
    return value


def is_one_line(text: str, max_chars: int = 200) -> bool:
    """Is `text` one line a person can read back: not blank, at most `max_chars`
    characters, no control character below U+0020 (a signer's name, a lab profile's
    texts)."""
    return bool(text.strip()) and len(text) <= max_chars and all(ord(c) >= 32 for c in text)
