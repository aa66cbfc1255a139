"""PostgreSQL roles for the archive: a reader for queries, a writer for the pipeline, an
approver who signs.

- reader (default ``calib_reader``): CONNECT, and SELECT on every table. For
  auditors, dashboards and `calib query`.
- writer (default ``calib_writer``): SELECT and INSERT on every table but
  ``audit_events``, the sequences behind the ids, and UPDATE of the one column
  the archive ever changes, ``superseded_by`` (calibrations, thermal models; a
  trigger ``supersede_forward`` lets it change only from empty to a later
  revision of the same run), and of the derived tables ``unit_latest`` and
  ``unit_latest_values`` (storage.unit_latest: a unit's rows are upserted). Events
  are appended only through ``calib_append_event`` (SECURITY DEFINER), which
  refuses an event that does not follow the chain's head or is not dated now.
  No DELETE, no other UPDATE, no DDL: the append-only rule is enforced by the
  server, not only by the code.
- approver (default ``calib_approver``): SELECT on every table, and
  ``calib_append_event`` for approvals only (`calib approve`).

The function and the trigger (`guard_statements`) are made here, with the roles they hold
to, not by a migration: an archive without these roles is written by its owner,
whom neither could hold (the owner can drop them), and the schema's revision
stays as it was, so read-only copies made by earlier versions still open.

Schema migrations run as the database owner (the role that created the
tables), never as these roles. Grants on tables are per table, so run
`apply_roles` again after a migration that adds a table (it is idempotent);
``ALTER DEFAULT PRIVILEGES`` covers SELECT for the reader on tables the owner
creates later.

Role and database names are quoted as identifiers and passwords as literals
by psycopg's `sql` module (DDL takes no bound parameters).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sqlalchemy.engine import make_url

from storage import unit_latest
from storage.db import Archive
from storage.naming import check_safe_name
from storage.pgtools import libpq_dsn
from storage.schema import Base, UnitLatest

if TYPE_CHECKING:
    import psycopg
    from psycopg import sql  # imported where statements are made: the read-only opener
    # (storage.queries.readonly) takes READER from here, SQLite needs no psycopg

READER = "calib_reader"
WRITER = "calib_writer"
APPROVER = "calib_approver"
# The one way the writer and approver roles append an event: the link to the chain's head,
# the date, (for a role that cannot add runs) the action, and the revision an archiving or
# approving event names are checked, under the lock storage.seal.append_event takes; its
# writer (p_db_user) is checked by the trigger of migration 0009.
_APPEND_FUNCTION = """
CREATE OR REPLACE FUNCTION calib_append_event(
  p_at timestamptz, p_actor text, p_action text, p_run_id text, p_revision integer,
  p_reason text, p_detail json, p_digest text, p_prev_hash text, p_hash text, p_seq integer,
  p_db_user text
) RETURNS integer LANGUAGE plpgsql SECURITY DEFINER SET search_path = public, pg_temp AS $$
DECLARE
  head_seq integer;
  head_hash text;
BEGIN
  PERFORM pg_advisory_xact_lock(LOCK_KEY);
  SELECT seq, hash INTO head_seq, head_hash FROM audit_events ORDER BY seq DESC LIMIT 1;
  head_seq := coalesce(head_seq, 0);
  head_hash := coalesce(head_hash, repeat('0', 64));
  IF p_seq <> head_seq + 1 OR p_prev_hash <> head_hash THEN
    RAISE EXCEPTION 'calib archive: event % (previous hash %) does not follow the chain '
      'head, event % (hash %)', p_seq, left(p_prev_hash, 12), head_seq, left(head_hash, 12)
      USING ERRCODE = 'insufficient_privilege';
  END IF;
  IF p_at < now() - interval '5 minutes' OR p_at > clock_timestamp() + interval '5 minutes' THEN
    RAISE EXCEPTION 'calib archive: event % is dated %, the server''s clock says %: '
      'refused (an event is dated when it is written)', p_seq, p_at, clock_timestamp()
      USING ERRCODE = 'insufficient_privilege';
  END IF;
  IF p_action <> 'approved' AND NOT has_table_privilege(session_user, 'runs', 'INSERT') THEN
    RAISE EXCEPTION 'calib archive: role % may append approvals only, not %', session_user, p_action
      USING ERRCODE = 'insufficient_privilege';
  END IF;
  IF p_action IN ('archived', 'revised', 'sealed') AND NOT EXISTS (
       SELECT 1 FROM calibrations c JOIN runs r ON r.id = c.run_id
       JOIN seals s ON s.calibration_id = c.id
       WHERE r.run_id = p_run_id AND c.revision = p_revision AND s.digest = p_digest) THEN
    RAISE EXCEPTION 'calib archive: event % (%) names run % revision % sealed with digest %, '
      'which the archive does not hold', p_seq, p_action, coalesce(p_run_id, '(none)'),
      coalesce(p_revision::text, '(none)'), coalesce(left(p_digest, 12), '(none)')
      USING ERRCODE = 'insufficient_privilege';
  END IF;
  IF p_action IN ('archived', 'revised', 'sealed') AND EXISTS (
       SELECT 1 FROM audit_events WHERE action IN ('archived', 'revised', 'sealed')
       AND run_id = p_run_id AND revision = p_revision) THEN
    RAISE EXCEPTION 'calib archive: run % revision % has its sealing event already',
      p_run_id, p_revision USING ERRCODE = 'insufficient_privilege';
  END IF;
  IF p_action = 'approved' AND NOT EXISTS (
       SELECT 1 FROM calibrations c JOIN runs r ON r.id = c.run_id
       WHERE r.run_id = p_run_id AND c.revision = p_revision) THEN
    RAISE EXCEPTION 'calib archive: approval of run % revision %, which the archive does not '
      'hold', coalesce(p_run_id, '(none)'), coalesce(p_revision::text, '(none)')
      USING ERRCODE = 'insufficient_privilege';
  END IF;
  INSERT INTO audit_events (seq, at, actor, action, run_id, revision, reason, detail, digest,
                            prev_hash, hash, db_user)
  VALUES (p_seq, p_at, p_actor, p_action, p_run_id, p_revision, p_reason, p_detail, p_digest,
          p_prev_hash, p_hash, p_db_user);
  RETURN p_seq;
END $$
"""
# superseded_by: only from empty to a later revision of the same run (a later model of the
# same unit); the tables' owner is not held (it could drop the trigger).
_SUPERSEDE_FUNCTION = """
CREATE OR REPLACE FUNCTION calib_supersede_forward() RETURNS trigger LANGUAGE plpgsql AS $$
DECLARE
  ok boolean;
BEGIN
  IF NEW.superseded_by IS NOT DISTINCT FROM OLD.superseded_by
     OR pg_has_role(current_user, (SELECT relowner FROM pg_class WHERE oid = TG_RELID), 'USAGE')
  THEN
    RETURN NEW;  -- the table's owner (or a superuser) could drop the trigger anyway
  END IF;
  IF OLD.superseded_by IS NOT NULL OR NEW.superseded_by IS NULL THEN
    RAISE EXCEPTION 'calib archive: % row % is superseded by % already: that never changes',
      TG_TABLE_NAME, OLD.id, OLD.superseded_by USING ERRCODE = 'insufficient_privilege';
  END IF;
  IF TG_TABLE_NAME = 'calibrations' THEN
    SELECT EXISTS (SELECT 1 FROM calibrations c WHERE c.id = NEW.superseded_by
                   AND c.run_id = OLD.run_id AND c.revision > OLD.revision) INTO ok;
  ELSE
    SELECT EXISTS (SELECT 1 FROM thermal_models m WHERE m.id = NEW.superseded_by
                   AND m.device_id = OLD.device_id AND m.id > OLD.id) INTO ok;
  END IF;
  IF NOT ok THEN
    RAISE EXCEPTION 'calib archive: % row % can be superseded only by a later revision of '
      'its own (found %)', TG_TABLE_NAME, OLD.id, NEW.superseded_by
      USING ERRCODE = 'insufficient_privilege';
  END IF;
  RETURN NEW;
END $$
"""
SUPERSEDING = ("calibrations", "thermal_models")


def guard_statements() -> list[str]:
    """The SQL of the function and trigger the writer and approver are held by (idempotent)."""
    # storage.seal loads the file store (pyarrow): imported here, so that reading the role
    # names (storage.queries.readonly) stays light for the read-only commands.
    from storage.seal import APPEND_EVENT, PG_CHAIN_LOCK

    # The function before events recorded their writer (migration 0009): dropped, so that
    # no role keeps a way to append an event without it.
    old_append_event = APPEND_EVENT.replace(", text)", ")")

    stmts = [
        f"DROP FUNCTION IF EXISTS {old_append_event}",
        _APPEND_FUNCTION.replace("LOCK_KEY", str(PG_CHAIN_LOCK)).strip(),
        f"REVOKE ALL ON FUNCTION {APPEND_EVENT} FROM PUBLIC",
        _SUPERSEDE_FUNCTION.strip(),
    ]
    for table in SUPERSEDING:
        stmts += [
            f"DROP TRIGGER IF EXISTS supersede_forward ON {table}",
            f"CREATE TRIGGER supersede_forward BEFORE UPDATE OF superseded_by ON {table} "
            "FOR EACH ROW EXECUTE FUNCTION calib_supersede_forward()",
        ]
    return stmts


def _updatable() -> list[tuple[str, str]]:
    """(table, column) pairs the writer may UPDATE: the supersession links, and the
    derived picks of each unit (storage.unit_latest: rewritten when a run is archived)."""
    links = [
        (t.name, "superseded_by") for t in Base.metadata.sorted_tables if "superseded_by" in t.c
    ]
    derived = [(UnitLatest.__tablename__, c) for c in unit_latest.COLUMNS[1:]]
    values = [(unit_latest.VALUES_TABLE, c) for c in unit_latest.VALUE_COLUMNS[3:]]
    return links + derived + values


def role_statements(
    database: str,
    *,
    reader: str = READER,
    writer: str = WRITER,
    approver: str = APPROVER,
    tables: list[str] | None = None,
) -> list[sql.Composed]:
    """The GRANT statements for the three roles (the roles must exist).

    Parameters
    ----------
    database : the archive's database name.
    reader, writer, approver : role names (letters, digits, ``._-``).
    tables : the archive's data tables (default: those of storage.schema).
    """
    from psycopg import sql

    for name, what in (
        (reader, "reader role"),
        (writer, "writer role"),
        (approver, "approver role"),
        (database, "database"),
    ):
        check_safe_name(name, what)
    tables = tables or [t.name for t in Base.metadata.sorted_tables]
    r, w, db = sql.Identifier(reader), sql.Identifier(writer), sql.Identifier(database)
    a = sql.Identifier(approver)
    data = sql.SQL(", ").join(sql.Identifier(t) for t in tables)
    version = sql.Identifier("alembic_version")  # read by Archive.upgrade at every start
    from storage.seal import APPEND_EVENT

    append = sql.SQL(APPEND_EVENT)  # a constant, not a name from outside
    stmts = [
        *(sql.SQL(g) for g in guard_statements()),
        sql.SQL("GRANT CONNECT ON DATABASE {} TO {}, {}, {}").format(db, r, w, a),
        sql.SQL("GRANT USAGE ON SCHEMA public TO {}, {}, {}").format(r, w, a),
        sql.SQL("REVOKE CREATE ON SCHEMA public FROM {}, {}, {}").format(r, w, a),
        sql.SQL("GRANT SELECT ON {}, {} TO {}, {}, {}").format(data, version, r, w, a),
        sql.SQL("REVOKE INSERT, UPDATE, DELETE, TRUNCATE ON {}, {} FROM {}, {}").format(
            data, version, r, a
        ),
        sql.SQL("REVOKE INSERT, UPDATE, DELETE, TRUNCATE ON {} FROM {}").format(version, w),
        sql.SQL("REVOKE UPDATE, DELETE, TRUNCATE ON {} FROM {}").format(data, w),
        sql.SQL("GRANT INSERT ON {} TO {}").format(data, w),
        # events only through the function that checks their link and date (guard_statements)
        sql.SQL("REVOKE INSERT ON {} FROM {}").format(sql.Identifier("audit_events"), w),
        sql.SQL("REVOKE EXECUTE ON FUNCTION {} FROM {}").format(append, r),
        sql.SQL("GRANT EXECUTE ON FUNCTION {} TO {}, {}").format(append, w, a),
        sql.SQL("GRANT USAGE, SELECT ON ALL SEQUENCES IN SCHEMA public TO {}").format(w),
        sql.SQL("ALTER DEFAULT PRIVILEGES IN SCHEMA public GRANT SELECT ON TABLES TO {}").format(r),
    ]
    for table, column in _updatable():
        if table in tables:
            stmts.append(
                sql.SQL("GRANT UPDATE ({}) ON {} TO {}").format(
                    sql.Identifier(column), sql.Identifier(table), w
                )
            )
    return stmts


def apply_roles(
    archive: Archive,
    *,
    reader: str = READER,
    writer: str = WRITER,
    approver: str = APPROVER,
    reader_password: str | None = None,
    writer_password: str | None = None,
    approver_password: str | None = None,
) -> None:
    """Make the guard function and trigger and grant the three roles their privileges,
    creating a role that is missing where the connecting role may (idempotent).

    Run as the database owner after `archive.upgrade()`, again after every upgrade. The
    roles are made once by the database administrator (docs/postgresql.md: a superuser
    creates them, the owner need not be allowed to); then the owner changes a role only
    where it is not as it must be (a login, no superuser, database or role creation, no
    row-level security bypass) and sets a password only when one is given.

    Raises
    ------
    PermissionError : a role is missing, or is not as it must be, or a password is given,
        and the connecting role may not create or change roles: the message names the
        role and what the administrator runs.
    """
    if archive.is_sqlite:
        raise ValueError("roles exist only on PostgreSQL; a SQLite archive is a file")
    import psycopg

    url = make_url(archive.url)
    database = url.database or "postgres"
    logins = ((reader, reader_password), (writer, writer_password), (approver, approver_password))
    with psycopg.connect(libpq_dsn(archive.url), autocommit=True) as conn, conn.transaction():
        for role, password in logins:
            check_safe_name(role, "role")
            _login_role(conn, role, password)
        for stmt in role_statements(database, reader=reader, writer=writer, approver=approver):
            conn.execute(stmt)
        _functions_to_the_owner(conn)
    from storage.seal import record_event

    passwords = [r for r, p in logins if p]
    record_event(
        archive,
        "roles",
        detail={
            "reader": reader,
            "writer": writer,
            "approver": approver,
            "password_set": passwords,
        },
    )


def _functions_to_the_owner(conn: psycopg.Connection) -> None:
    """The guard functions belong to the tables' owner, also when a superuser made them, so
    that the owner can run `apply_roles` again (replacing a function takes its owner)."""
    from psycopg import sql

    from storage.seal import APPEND_EVENT

    owner = conn.execute(
        "SELECT tableowner FROM pg_tables WHERE schemaname = 'public' AND tablename = 'runs'"
    ).fetchone()
    if owner is None:
        return
    for function in (APPEND_EVENT, "calib_supersede_forward()"):
        conn.execute(
            sql.SQL("ALTER FUNCTION " + function + " OWNER TO {}").format(sql.Identifier(owner[0]))
        )


# What a role the archive's roles hold to must not be (pg_roles columns).
_POWERS = {
    "rolsuper": "SUPERUSER",
    "rolcreatedb": "CREATEDB",
    "rolcreaterole": "CREATEROLE",
    "rolbypassrls": "BYPASSRLS",
}


def _login_role(conn: psycopg.Connection, role: str, password: str | None) -> None:
    """Make `role` a login role without powers, changing only what differs; set `password`
    when given. PermissionError naming the administrator's statement when refused."""
    import psycopg
    from psycopg import sql

    cols = ", ".join(_POWERS)
    row = conn.execute(
        f"SELECT rolcanlogin, {cols} FROM pg_roles WHERE rolname = %s", (role,)
    ).fetchone()
    name = sql.Identifier(role)
    if row is None:
        stmt = sql.SQL("CREATE ROLE {} LOGIN").format(name)
        doing = f"create role {role}"
    else:
        changes = ([] if row[0] else ["LOGIN"]) + [
            "NO" + power for power, held in zip(_POWERS.values(), row[1:], strict=True) if held
        ]
        stmt = sql.SQL("ALTER ROLE {} " + " ".join(changes)).format(name) if changes else None
        doing = f"change role {role} ({' '.join(changes)})"
    if password is not None:
        if stmt is None:
            stmt = sql.SQL("ALTER ROLE {}").format(name)
            doing = f"set the password of role {role}"
        stmt += sql.SQL(" PASSWORD {}").format(sql.Literal(password))
    if stmt is None:
        return
    try:
        with conn.transaction():  # a savepoint: the refusal is reported, not the abort
            conn.execute(stmt)
    except psycopg.errors.InsufficientPrivilege:
        user = conn.execute("SELECT session_user").fetchone()[0]
        shown = stmt.as_string(conn).split(" PASSWORD ")[0]
        raise PermissionError(
            f"role {user} may not {doing}: the database administrator (a superuser) runs "
            f"`{shown}` once (docs/postgresql.md, step 3), then apply_roles again"
        ) from None


def role_sql(
    database: str, *, reader: str = READER, writer: str = WRITER, approver: str = APPROVER
) -> str:
    """The grants as SQL text, for a DBA to read or run by hand (docs/archive.md)."""
    stmts = role_statements(database, reader=reader, writer=writer, approver=approver)
    return "".join(s.as_string(None) + ";\n" for s in stmts)
