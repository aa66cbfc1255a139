"""PostgreSQL: events are appended only through ``calib_append_event``; a revision is made
current only by a later one.

The writer and approver roles get no INSERT on ``audit_events`` (storage.roles): they
append through ``calib_append_event``, a SECURITY DEFINER function that holds the
chain's advisory lock, refuses an event that does not follow the chain's head (its
``seq`` and ``prev_hash``) or is dated outside a few minutes of the server's clock (no
backdating into a key's validity), lets a role that cannot add runs append only
approvals, and inserts the row. A trigger on ``calibrations`` and ``thermal_models``
lets ``superseded_by`` change only from empty to a later revision of the same run (a
later model of the same unit): no revision is made current again, none is pointed at
another run's. The tables' owner is not held by it (it could drop the trigger).
SQLite: nothing (a SQLite archive is one file; whoever can write it can write
anything, docs/archive.md).

Self-contained: plain SQL of its day, no import of storage modules. The lock key is
storage.seal's ``_PG_CHAIN_LOCK`` (0x63616C6963) as it was when this was written.
"""

from __future__ import annotations

from alembic import op

revision = "0009_chain_guard"
down_revision = "0008_seal_texts"

_SIGNATURE = ("timestamptz, text, text, text, integer, text, json, text, text, text, integer")
_APPEND = """
CREATE FUNCTION calib_append_event(
  p_at timestamptz, p_actor text, p_action text, p_run_id text, p_revision integer,
  p_reason text, p_detail json, p_digest text, p_prev_hash text, p_hash text, p_seq integer
) RETURNS integer LANGUAGE plpgsql SECURITY DEFINER SET search_path = public, pg_temp AS $$
DECLARE
  head_seq integer;
  head_hash text;
BEGIN
  PERFORM pg_advisory_xact_lock(426836257123);
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
  INSERT INTO audit_events (seq, at, actor, action, run_id, revision, reason, detail, digest,
                            prev_hash, hash)
  VALUES (p_seq, p_at, p_actor, p_action, p_run_id, p_revision, p_reason, p_detail, p_digest,
          p_prev_hash, p_hash);
  RETURN p_seq;
END $$
"""
_SUPERSEDE = """
CREATE FUNCTION calib_supersede_forward() RETURNS trigger LANGUAGE plpgsql AS $$
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
_TABLES = ("calibrations", "thermal_models")


def upgrade() -> None:
    if op.get_bind().dialect.name != "postgresql":
        return
    op.execute(_APPEND)
    op.execute(f"REVOKE ALL ON FUNCTION calib_append_event({_SIGNATURE}) FROM PUBLIC")
    op.execute(_SUPERSEDE)
    for table in _TABLES:
        op.execute(f"CREATE TRIGGER supersede_forward BEFORE UPDATE OF superseded_by ON {table} "
                   "FOR EACH ROW EXECUTE FUNCTION calib_supersede_forward()")  # fmt: skip


def downgrade() -> None:
    if op.get_bind().dialect.name != "postgresql":
        return
    for table in _TABLES:
        op.execute(f"DROP TRIGGER IF EXISTS supersede_forward ON {table}")
    op.execute("DROP FUNCTION IF EXISTS calib_supersede_forward()")
    op.execute(f"DROP FUNCTION IF EXISTS calib_append_event({_SIGNATURE})")
