"""What went wrong when the archive could not be written, and what to do about it.

A full disk, a read-only mount or a missing permission surfaces as an OSError
(``[Errno 28] No space left on device``, often without a path) or as a
database error (SQLite: "database or disk is full", "attempt to write a
readonly database"; PostgreSQL: "could not extend file"). :func:`describe`
turns any of them, found anywhere in an exception's causes, into one sentence
naming the file or database and saying what to do; other errors give None.
Nothing half-written stays behind (a run's files are committed with its rows,
`storage.rawstore.PendingFiles`), so the advice is always to fix the cause and
run the same command again.
"""

from __future__ import annotations

import errno
from collections.abc import Iterator
from pathlib import Path

from sqlalchemy.engine import make_url

FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
READ_ONLY_ERRNOS = frozenset({errno.EROFS})
DENIED_ERRNOS = frozenset({errno.EACCES, errno.EPERM})

_DB_FULL = ("database or disk is full", "could not extend file", "no space left on device")
_DB_READ_ONLY = (
    "attempt to write a readonly database",
    "read-only transaction",
    "readonly database",
)
_DB_CANNOT_OPEN = ("unable to open database file",)
_DB_IO = ("disk i/o error",)
_PG_DENIED = "42501"  # PostgreSQL's insufficient_privilege: a role that may not write

AGAIN = "nothing was written; run the same command again once that is done"


def exception_chain(exc: BaseException) -> Iterator[BaseException]:
    """`exc`, its causes and contexts and any wrapped driver error (SQLAlchemy's ``orig``),
    each once."""
    seen: set[int] = set()
    stack: list[BaseException | None] = [exc]
    while stack:
        e = stack.pop()
        if e is None or id(e) in seen:
            continue
        seen.add(id(e))
        yield e
        stack += [getattr(e, "orig", None), e.__cause__, e.__context__]


def database_location(url: str) -> str:
    """The SQLite file of `url`, or the URL with its password hidden; `url` may also be an
    archive folder (as ``CALIB_ARCHIVE`` or ``--archive`` name one): its SQLite file."""
    if "://" not in url:
        from storage.db import default_archive_url

        url = default_archive_url(Path(url).expanduser())
    try:
        u = make_url(url)
    except Exception:  # noqa: BLE001 - any malformed name: shown as given
        return url
    if u.get_backend_name() == "sqlite" and u.database:
        return u.database.removeprefix("file:").split("?")[0]
    return u.render_as_string(hide_password=True)


def describe(exc: BaseException, database_url: str | None = None) -> str | None:
    """A message for a write that failed for lack of space, a read-only medium or permission.

    Parameters
    ----------
    exc : the error (its causes are searched too).
    database_url : the archive's database, named when the database refused the write.

    Returns None when `exc` is none of those.
    """
    for e in exception_chain(exc):
        if isinstance(e, OSError) and e.errno is not None:
            where = e.filename or "the archive's file store"
            if e.errno in FULL_ERRNOS:
                return (
                    f"no space left on the file system holding {where}: free space there "
                    f"(or move the archive to a larger disk); {AGAIN}"
                )
            if e.errno in READ_ONLY_ERRNOS:
                return (
                    f"{where} is on a read-only file system: writing needs a writable "
                    f"archive (reading commands work as they are); {AGAIN}"
                )
            if e.errno in DENIED_ERRNOS:
                return f"no permission to write {where}: check its owner and mode; {AGAIN}"
        text = str(e).lower()
        db = (
            f"the database {database_location(database_url)}"
            if database_url
            else "the archive's database"
        )
        if getattr(e, "sqlstate", None) == _PG_DENIED:
            first = str(e).splitlines()[0] if str(e) else "permission denied"
            return (
                f"{db} refused the write ({first}): connect as a role that may write "
                f"(the writer role or the owner); {AGAIN}"
            )
        if any(s in text for s in _DB_FULL):
            return f"no space left for {db}: free space on its disk (or move the archive); {AGAIN}"
        if any(s in text for s in _DB_READ_ONLY):
            return (
                f"{db} is read-only (a read-only mount or copy, or no write "
                f"permission on the file or its folder); {AGAIN}"
            )
        if any(s in text for s in _DB_IO):
            return (
                f"{db} could not be written (SQLite: disk I/O error), "
                f"most often because its disk is full: check the free space there; "
                f"{AGAIN}"
            )
        if any(s in text for s in _DB_CANNOT_OPEN):
            folder = Path(database_location(database_url)).parent if database_url else "its folder"
            return (
                f"cannot open {db}: check that {folder} exists and can be "
                f"read (and written, to archive); {AGAIN}"
            )
    return None


def with_path(exc: OSError, path: Path | str) -> OSError:
    """`exc` with `path` as its file name (an ENOSPC from write() carries none)."""
    if exc.filename is not None or exc.errno is None:
        return exc
    new = type(exc)(exc.errno, exc.strerror, str(path))
    new.__cause__ = exc
    return new
