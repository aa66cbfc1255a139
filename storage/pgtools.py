"""Where the PostgreSQL client tools are, and the libpq form of an archive URL.

`storage.backup` runs ``pg_dump`` / ``pg_restore``; `storage.roles` and the backup
connect with psycopg, which takes a libpq connection string.
"""

from __future__ import annotations

import glob
import shutil
from pathlib import Path


def bindir() -> Path | None:
    """Folder holding initdb, pg_ctl, pg_dump, pg_restore (newest version), or None."""
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    return Path(initdb).parent if initdb else None


def tool(name: str) -> Path:
    """Path of a PostgreSQL client tool (``pg_dump``, ``pg_restore``...).

    Raises FileNotFoundError naming the tool when it is not installed.
    """
    d = bindir()
    if d is not None and (d / name).exists():
        return d / name
    found = shutil.which(name)
    if found:
        return Path(found)
    raise FileNotFoundError(
        f"{name} not found (looked in /usr/lib/postgresql/*/bin and PATH): "
        "install the PostgreSQL client tools (apt-get install postgresql-client)"
    )


def libpq_dsn(url: str) -> str:
    """A SQLAlchemy PostgreSQL URL as a libpq connection string (for psycopg, pg_dump)."""
    from sqlalchemy.engine import make_url

    u = make_url(url)
    return u.set(drivername="postgresql").render_as_string(hide_password=False)
