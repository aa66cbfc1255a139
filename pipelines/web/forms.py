"""Query parameters of the browser's pages: validated, with a clear 400 (or 404) naming
the parameter, what was expected and what was found."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import TypeVar

from fastapi import Request
from starlette.exceptions import HTTPException

T = TypeVar("T")


def params(request: Request, allowed: Iterable[str]) -> dict[str, str]:
    """The query parameters as a dict; 400 for an unknown or repeated one."""
    allowed = set(allowed)
    out: dict[str, str] = {}
    for key, value in request.query_params.multi_items():
        if key not in allowed:
            expected = ", ".join(sorted(allowed)) or "none"
            raise HTTPException(400, f"unknown query parameter {key!r}; expected: {expected}")
        if key in out:
            raise HTTPException(400, f"query parameter {key!r} given more than once")
        out[key] = value
    return out


def integer(q: dict[str, str], name: str, default: int, lo: int, hi: int) -> int:
    """A whole number lo..hi (default when absent or empty), else 400."""
    text = q.get(name, "")
    if text == "":
        return default
    if not text.isascii() or not text.isdigit() or not lo <= int(text) <= hi:
        raise HTTPException(400, f"{name}: expected a whole number {lo}..{hi}, got {text!r}")
    return int(text)


def choice(q: dict[str, str], name: str, options: Iterable[str], default: str) -> str:
    """One of `options` (default when absent), else 400."""
    options = list(options)
    text = q.get(name, "") or default
    if text not in options:
        raise HTTPException(400, f"{name}: expected one of {', '.join(options)}, got {text!r}")
    return text


def checked(fn: Callable[..., T], *args, **kwargs) -> T:  # noqa: ANN002, ANN003
    """Call a storage query: its ValueError (bad input) is a 400, LookupError a 404."""
    try:
        return fn(*args, **kwargs)
    except KeyError:  # a LookupError too, but a programming error here, not a missing row
        raise
    except LookupError as exc:
        raise HTTPException(404, str(exc.args[0] if exc.args else exc)) from exc
    except ValueError as exc:
        raise HTTPException(400, str(exc)) from exc
