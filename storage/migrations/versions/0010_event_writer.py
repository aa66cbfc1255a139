"""The writer of every audit event: ``audit_events.db_user``.

An event's ``actor`` is who the writer says it is (``CALIB_USER``, or the OS user);
``db_user`` is who wrote it as the database knows it: PostgreSQL's ``session_user``
(the role that logged in, whatever role it switched to), the OS user on SQLite.
Events written before this revision have none (NULL), and their hash stays over the
fields it was computed over (storage.seal.Event). On PostgreSQL a trigger refuses an
event whose ``db_user`` is not the session's user, by whatever path it is inserted
(the owner could drop the trigger; the writer and approver roles cannot).

A downgrade drops the trigger but keeps the column: an event's hash is over its
writer, so dropping it would break the chain (the upgrade again adds it only if
missing).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0010_event_writer"
down_revision = "0009_validations"

_EVENT_WRITER = """
CREATE FUNCTION calib_event_writer() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
  IF NEW.db_user IS DISTINCT FROM session_user::text THEN
    RAISE EXCEPTION 'calib archive: event % names % as its writer, but % is writing it',
      NEW.seq, coalesce(NEW.db_user, 'nobody'), session_user
      USING ERRCODE = 'insufficient_privilege';
  END IF;
  RETURN NEW;
END $$
"""


def upgrade() -> None:
    columns = {c["name"] for c in sa.inspect(op.get_bind()).get_columns("audit_events")}
    if "db_user" not in columns:
        op.add_column("audit_events", sa.Column("db_user", sa.String(length=200), nullable=True))
    if op.get_bind().dialect.name == "postgresql":
        op.execute(_EVENT_WRITER)
        op.execute(
            "CREATE TRIGGER event_writer BEFORE INSERT ON audit_events "
            "FOR EACH ROW EXECUTE FUNCTION calib_event_writer()"
        )


def downgrade() -> None:
    if op.get_bind().dialect.name == "postgresql":
        op.execute("DROP TRIGGER IF EXISTS event_writer ON audit_events")
        op.execute("DROP FUNCTION IF EXISTS calib_event_writer()")
