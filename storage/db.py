"""Where the archive lives: database URL + file store root, engine, migrations.

One machine: a SQLite file and the file store under one root directory
(default ``./calib-archive``). A bigger lab: any SQLAlchemy URL (PostgreSQL,
``postgresql+psycopg://user@host/db``) with the file store on shared storage
(``CALIB_FILESTORE``). The schema is created and upgraded by Alembic
(storage/migrations), run from here so no alembic.ini is needed at run time.
"""

from __future__ import annotations

import ast
import functools
import json
import os
import sqlite3
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import quote

from sqlalchemy import Connection, Engine, create_engine, event, text
from sqlalchemy.engine import make_url
from sqlalchemy.exc import DBAPIError

if TYPE_CHECKING:
    from alembic.config import Config

DEFAULT_ROOT = Path("calib-archive")
MIGRATIONS = Path(__file__).parent / "migrations"
# The schema the migrations give a new SQLite database, recorded (`record_sqlite_head`).
SQLITE_HEAD = MIGRATIONS / "sqlite_head.json"
SQLITE_BUSY_TIMEOUT_MS = 30_000
# Any constant works; it only has to be the same for every process upgrading the database.
_PG_MIGRATION_LOCK = 0x63616C6962  # "calib"


def default_archive_url(root: Path) -> str:
    """SQLAlchemy URL of the SQLite archive file under `root` (root/archive.sqlite)."""
    return f"sqlite:///{(Path(root) / 'archive.sqlite').resolve()}"


@dataclass
class Archive:
    """An archive: its database URL and the root of its file store.

    Attributes
    ----------
    url : SQLAlchemy URL of the database.
    root : directory holding raw objects, run folders and Parquet samples.
    read_only : open the database read-only. Default (None): read-only when the
        SQLite file or its folder cannot be written (a read-only mount, an
        auditor's copy without write permission), else read-write. Reading
        commands then work as usual; a write fails with a message naming the file.
        Read-only SQLite is opened ``mode=ro`` (or ``immutable=1``) with
        ``query_only``; PostgreSQL in read-only transactions.
    reader_role : PostgreSQL and read-only only: if the connecting role may write,
        ``SET ROLE`` to this role (storage.roles) at every connection, and refuse
        to connect (PermissionError) if it cannot. None: no switch.
    """

    url: str
    root: Path
    read_only: bool | None = None
    reader_role: str | None = None
    _engine: Engine | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        if self.read_only is None:
            self.read_only = sqlite_read_only(self.url)
        if self.reader_role is not None:
            from storage.naming import check_safe_name

            check_safe_name(self.reader_role, "reader role")

    def __repr__(self) -> str:
        return f"Archive(url={self.display_url!r}, root={str(self.root)!r})"

    @property
    def display_url(self) -> str:
        """The URL with any password hidden, for messages and logs."""
        return make_url(self.url).render_as_string(hide_password=True)

    @property
    def is_sqlite(self) -> bool:
        return make_url(self.url).get_backend_name() == "sqlite"

    def engine(self) -> Engine:
        """The (cached) engine; SQLite gets foreign keys, WAL and a busy timeout."""
        if self._engine is None:
            self._engine = _make_engine(
                self.url, read_only=bool(self.read_only), reader_role=self.reader_role
            )
        return self._engine

    def upgrade(self) -> None:
        """Bring the schema to the newest migration (no-op if it is there already).

        Safe to call on every start and from several processes at once: on
        SQLite the migration runs in a ``BEGIN IMMEDIATE`` transaction, on
        PostgreSQL under an advisory lock, so concurrent callers queue up and
        the later ones find nothing to do. A read-only archive is only checked:
        ReadOnlyArchiveError if its schema is not the newest.
        """
        if self.read_only:
            self._check_schema_current()
            return
        if self._at_head():
            return  # the usual case; spares Alembic's import and script scan
        if self._create_sqlite_head():
            return  # a new SQLite archive, made without Alembic (its import and scan spared)
        self.migrate("head")

    def _at_head(self) -> bool:
        """Is the database at the newest migration? (False when unsure: Alembic decides.)"""
        head = migration_head()
        if head is None:
            return False
        try:
            with self.engine().connect() as conn:
                rows = conn.execute(text("SELECT version_num FROM alembic_version")).all()
        except DBAPIError:
            return False  # no schema yet (no alembic_version table)
        return [r[0] for r in rows] == [head]

    def _create_sqlite_head(self) -> bool:
        """Give an empty SQLite database the schema of the newest migration, as recorded
        in `SQLITE_HEAD` from the migrations themselves, and its Alembic revision.

        False, with nothing done, for any other database (PostgreSQL, an archive with
        tables, a recording of an older migration): Alembic then upgrades it. The check
        and the statements run in one ``BEGIN IMMEDIATE`` transaction, so of processes
        starting together on a new archive one creates the schema, the others find it.
        """
        if not self.is_sqlite:
            return False
        head = migration_head()
        recorded = _sqlite_head()
        if head is None or recorded.get("revision") != head:
            return False
        with self.engine().connect() as conn:
            conn.execution_options(sqlite_begin="IMMEDIATE")
            with conn.begin():
                if conn.execute(text("SELECT count(*) FROM sqlite_master")).scalar():
                    return False
                for statement in recorded["statements"]:
                    conn.exec_driver_sql(statement)
                conn.execute(text("INSERT INTO alembic_version VALUES (:v)"), {"v": head})
        return True

    def _check_schema_current(self) -> None:
        from alembic.script import ScriptDirectory

        head = ScriptDirectory.from_config(self.alembic_config()).get_current_head()
        current = self.schema_revision()
        if current != head:
            raise ReadOnlyArchiveError(
                f"archive {self.display_url} is read-only and its schema is at revision "
                f"{current or '(none)'}, this version of calib reads revision {head}: run any "
                "calib command on a writable copy to upgrade it, or use the calib that wrote it"
            )

    def migrate(self, target: str, *, down: bool = False) -> None:
        """Upgrade (or with `down`, downgrade) the schema to an Alembic revision."""
        if self.read_only:
            raise ReadOnlyArchiveError(f"archive {self.display_url} is read-only: never migrated")
        from alembic import command  # Alembic (slow to import) only where the schema is changed

        cfg = self.alembic_config()
        with self.engine().connect() as conn:
            conn.execution_options(sqlite_begin="IMMEDIATE")
            with conn.begin():
                if conn.dialect.name == "postgresql":
                    conn.execute(
                        text("SELECT pg_advisory_xact_lock(:k)"), {"k": _PG_MIGRATION_LOCK}
                    )
                cfg.attributes["connection"] = conn
                (command.downgrade if down else command.upgrade)(cfg, target)

    def alembic_config(self) -> Config:
        """Alembic configuration for this archive (no alembic.ini needed)."""
        from alembic.config import Config

        cfg = Config()
        cfg.set_main_option("script_location", str(MIGRATIONS))
        cfg.set_main_option("sqlalchemy.url", self.url.replace("%", "%%"))
        return cfg

    def schema_revision(self) -> str | None:
        """The Alembic revision the database is at (None: no schema yet)."""
        from alembic.runtime.migration import MigrationContext

        with self.engine().connect() as conn:
            return MigrationContext.configure(conn).get_current_revision()

    def dispose(self) -> None:
        """Close all pooled connections (tests, before deleting the database)."""
        if self._engine is not None:
            self._engine.dispose()
            self._engine = None


@functools.cache
def migration_head() -> str | None:
    """The newest revision among storage/migrations/versions, read from the scripts'
    ``revision`` and ``down_revision`` assignments without importing Alembic; None if
    there is not exactly one head (branches, a script written otherwise)."""
    revisions: set[str] = set()
    parents: set[str] = set()
    for script in (MIGRATIONS / "versions").glob("*.py"):
        for node in ast.parse(script.read_text("utf-8")).body:
            if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
                names = {t.id for t in node.targets if isinstance(t, ast.Name)}
                if "revision" in names and isinstance(node.value.value, str):
                    revisions.add(node.value.value)
                if "down_revision" in names and isinstance(node.value.value, str):
                    parents.add(node.value.value)
    heads = revisions - parents
    return heads.pop() if len(heads) == 1 else None


@functools.cache
def _sqlite_head() -> dict:
    """The recorded schema ({"revision", "statements"}; empty if the file is missing)."""
    try:
        return json.loads(SQLITE_HEAD.read_text("utf-8"))
    except FileNotFoundError:
        return {}


def sqlite_schema(conn: Connection) -> list[str]:
    """The CREATE statements of a SQLite database in the order they were made (tables,
    indexes, triggers; not the indexes SQLite makes itself for keys and unique columns)."""
    rows = conn.execute(text("SELECT sql FROM sqlite_master WHERE sql IS NOT NULL ORDER BY rowid"))
    return [sql for (sql,) in rows]


def record_sqlite_head(path: Path = SQLITE_HEAD) -> dict:
    """Record (in `path`) the schema the migrations give a new SQLite database.

    Run after adding a migration (``python -m storage.db``; tests/test_migrations.py
    fails until it is): until then new SQLite archives are made by Alembic, as before.
    Returns the document written.
    """
    with tempfile.TemporaryDirectory(prefix="calib-schema-") as tmp:
        archive = Archive(default_archive_url(Path(tmp)), Path(tmp))
        archive.migrate("head")
        with archive.engine().connect() as conn:
            doc = {"revision": archive.schema_revision(), "statements": sqlite_schema(conn)}
        archive.dispose()
    path.write_text(json.dumps(doc, indent=1) + "\n", "utf-8")
    return doc


class ReadOnlyArchiveError(RuntimeError):
    """A read-only archive cannot do what was asked (a write, a schema upgrade)."""


def sqlite_read_only(url: str) -> bool:
    """Whether the SQLite database of `url` exists but cannot be written (False otherwise).

    ``os.access`` answers for the file system too: a read-only mount is not
    writable even for root.
    """
    u = make_url(url)
    if u.get_backend_name() != "sqlite" or not u.database or u.database == ":memory:":
        return False
    if u.query.get("mode") == "ro" or u.query.get("immutable") == "1":
        return True
    db = Path(u.database)
    return db.is_file() and not (os.access(db, os.W_OK) and os.access(db.parent, os.W_OK))


def _read_only_sqlite_url(u) -> str:  # noqa: ANN001 - a sqlalchemy URL
    """A URI that opens the database read-only without creating or changing any file.

    ``mode=ro`` where SQLite can read its write-ahead log (the -wal and -shm files
    exist, or the folder is writable); otherwise (a read-only copy with no log,
    which is all in the main file) ``immutable=1``, which takes no locks at all.
    """
    if u.database.startswith("file:"):
        return u.render_as_string(hide_password=False)
    return f"sqlite:///{read_only_sqlite_uri(Path(u.database))}&uri=true"


def read_only_sqlite_uri(db: Path) -> str:
    """The SQLite URI (``file:...?mode=ro`` or ``?immutable=1``, `_read_only_sqlite_url`)
    that opens the file `db` read-only; for ``sqlite3.connect(uri, uri=True)``."""
    db = Path(db).resolve()
    wal = db.with_name(db.name + "-wal")
    shm = db.with_name(db.name + "-shm")
    can_log = (wal.exists() and shm.exists()) or os.access(db.parent, os.W_OK)
    mode = "mode=ro" if can_log else "immutable=1"
    return f"file:{quote(str(db))}?{mode}"


def _make_engine(url: str, *, read_only: bool = False, reader_role: str | None = None) -> Engine:
    u = make_url(url)
    if u.get_backend_name() != "sqlite":
        if read_only:
            return _read_only_pg_engine(url, reader_role)
        return create_engine(url, pool_pre_ping=True)
    if read_only:
        if not u.database or u.database == ":memory:":
            raise ValueError("an in-memory SQLite database cannot be opened read-only")
        url = _read_only_sqlite_url(u)
    elif u.database and u.database != ":memory:":
        Path(u.database).parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(url)

    # pysqlite's own transaction handling skips BEGIN before DDL and cannot take
    # the write lock up front; take over (SQLAlchemy's documented recipe) so a
    # transaction really is one, and writers can ask for BEGIN IMMEDIATE.
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn, _record) -> None:  # noqa: ANN001
        dbapi_conn.isolation_level = None
        cur = dbapi_conn.cursor()
        cur.execute("PRAGMA foreign_keys=ON")
        cur.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
        if read_only:
            cur.execute("PRAGMA query_only=ON")
        elif u.database and u.database != ":memory:":
            _enable_wal(cur)
        cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn) -> None:  # noqa: ANN001
        mode = conn.get_execution_options().get("sqlite_begin", "DEFERRED")
        conn.exec_driver_sql(f"BEGIN {mode}")

    return engine


def _read_only_pg_engine(url: str, reader_role: str | None) -> Engine:
    """PostgreSQL in read-only transactions, as `reader_role` if the login role may write."""
    engine = create_engine(
        url, pool_pre_ping=True, connect_args={"options": "-c default_transaction_read_only=on"}
    )
    if reader_role is None:
        return engine
    shown = make_url(url).render_as_string(hide_password=True)

    @event.listens_for(engine, "connect")
    def _as_reader(dbapi_conn, _record) -> None:  # noqa: ANN001
        with dbapi_conn.cursor() as cur:
            cur.execute("SELECT has_table_privilege(current_user, 'runs', 'INSERT')")
            (can_write,) = cur.fetchone()
            if can_write:
                try:  # the role name passed check_safe_name; quoted as an identifier
                    cur.execute(f'SET ROLE "{reader_role}"')
                except Exception as exc:
                    raise PermissionError(
                        f"the role of {shown} may write to the archive and cannot become the "
                        f"read-only role {reader_role!r} ({exc}); connect as {reader_role} "
                        "(storage.roles.apply_roles creates it)"
                    ) from exc
        dbapi_conn.commit()

    return engine


def _enable_wal(cur) -> None:  # noqa: ANN001 - a sqlite3 cursor
    """Put the database in WAL mode (stored in the file: a no-op once any connection did).

    Switching into WAL needs the database to itself, and SQLite answers "database
    is locked" at once instead of waiting out the busy timeout; so a connection
    that races another one's first use of a new archive (two workers starting
    together, one of them migrating) retries until the busy timeout.
    """
    deadline = time.monotonic() + SQLITE_BUSY_TIMEOUT_MS / 1000
    while True:
        try:
            cur.execute("PRAGMA journal_mode=WAL")
            return
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() >= deadline:
                raise
            time.sleep(0.01)


def resolve_archive(arg: str | None) -> Archive:
    """The archive named by a CLI argument.

    Parameters
    ----------
    arg : None (use env ``CALIB_ARCHIVE``, else ``./calib-archive``), a directory
        (SQLite file and file store under it), or a SQLAlchemy URL (the file
        store root is then env ``CALIB_FILESTORE``, else ``./calib-archive``).
    """
    if arg is None:
        arg = os.environ.get("CALIB_ARCHIVE") or str(DEFAULT_ROOT)
    if "://" in arg:
        make_url(arg)  # raises ArgumentError with the reason if malformed
        root = Path(os.environ.get("CALIB_FILESTORE") or DEFAULT_ROOT).resolve()
        return Archive(url=arg, root=root)
    root = Path(arg).expanduser().resolve()
    if root.exists() and not root.is_dir():
        raise ValueError(
            f"archive {arg!r}: expected a directory or a database URL, found a file "
            "(for a SQLite file give sqlite:///path/to/file.sqlite)"
        )
    return Archive(url=default_archive_url(root), root=root)


def open_archive(location: str | os.PathLike[str] | None = None) -> Archive:
    """Open an archive, creating or upgrading its schema (what every `calib` command does).

    Parameters
    ----------
    location : a directory (SQLite file ``archive.sqlite`` and the file store
        under it, created when missing), a SQLAlchemy URL such as
        ``postgresql+psycopg://user@host/db`` (file store: env ``CALIB_FILESTORE``),
        or None (env ``CALIB_ARCHIVE``, else ``./calib-archive``).

    Returns
    -------
    Archive, its schema at the newest migration. A read-only archive (file or
    folder not writable) is opened read-only and only checked.
    """
    archive = resolve_archive(None if location is None else os.fspath(location))
    archive.upgrade()
    return archive


if __name__ == "__main__":
    print(f"recorded revision {record_sqlite_head()['revision']} in {SQLITE_HEAD}")
