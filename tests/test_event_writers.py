"""Events bound to their writer (storage.seal, migration 0009, storage.seal_check).

Known truth: the runs archived here, and events forged with calib's own chaining code
(`seal.append_event`), correctly linked, as a writer of the database could: what
`verify` must report, on a real SQLite file and a real PostgreSQL server.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlalchemy import select, text
from test_archive import make_run

from storage import seal
from storage.archive import archive_run
from storage.db import Archive
from storage.schema import AuditEvent
from storage.verify import verify


def _problems(archive: Archive) -> list[str]:
    return [p.detail for p in verify(archive, orphans=False).problems]


def test_each_event_records_its_database_writer(archive: Archive, tmp_path: Path) -> None:
    res = archive_run(archive, make_run(tmp_path / "in"))
    with archive.engine().connect() as conn:
        rows = conn.execute(select(AuditEvent.actor, AuditEvent.db_user)).all()
        expected = (
            conn.execute(text("SELECT session_user")).scalar()
            if archive.url.startswith("postgresql")
            else seal.process_user()
        )
    assert [r.db_user for r in rows] == [expected]
    assert rows[0].actor == seal.actor()  # the claimed actor, beside it
    assert res.status == "ok" and verify(archive, orphans=False).ok


def test_a_linked_event_for_a_run_that_does_not_exist_is_reported(
    archive: Archive, tmp_path: Path
) -> None:
    """Linked events for a missing run or revision, by the database's owner (the writer
    role's calls are refused by calib_append_event: tests/test_roles_guard.py)."""
    res = archive_run(archive, make_run(tmp_path / "in"))
    with archive.engine().begin() as conn:
        digest = conn.execute(text("SELECT digest FROM seals")).scalar()
        seal.append_event(conn, "archived", run_id="Rghost", revision=1, who="Ghost Writer")
        seal.append_event(conn, "revised", run_id=res.run_id, revision=7, digest=digest)
        seal.append_event(conn, "archived", run_id=res.run_id, revision=1, digest=digest)
    found = "\n".join(_problems(archive))
    assert "names run Rghost, which the archive does not hold" in found, found
    assert "event 2 (archived of Rghost) lacks its run, revision or digest" in found
    assert f"revision 7 of run {res.run_id}, which the archive does not hold" in found
    assert "seals revision 1 a second time" in found


@pytest.mark.postgres
def test_an_event_written_by_a_role_that_may_not_hold_it(postgres_url: str, tmp_path: Path) -> None:
    """A sealing event recorded as written by the reader role, an approval by a role that
    does not exist (the owner switched the guarding trigger off to write them): verify
    names both; the writer's own archiving passes."""
    from test_roles import _as

    from storage.roles import READER, WRITER, apply_roles

    owner = Archive(postgres_url, tmp_path / "store")
    owner.upgrade()
    apply_roles(owner)
    writer = _as(postgres_url, WRITER, owner.root)
    res = archive_run(writer, make_run(tmp_path / "in"))
    assert verify(owner, orphans=False).ok
    with owner.engine().begin() as conn:
        conn.execute(text("ALTER TABLE audit_events DISABLE TRIGGER event_writer"))
        seq, prev = seal.head(conn)
        for n, (action, who) in enumerate((("sealed", READER), ("approved", "nobody_here"))):
            ev = seal.Event(
                seq + 1 + n, seal.utcnow(), "Jane", action, res.run_id, 1, None, {}, None,
                prev, who,
            )  # fmt: skip
            row = {k: getattr(ev, k) for k in seal.EVENT_FIELDS}
            conn.execute(AuditEvent.__table__.insert(), {**row, "hash": ev.hash()})
            prev = ev.hash()
        conn.execute(text("ALTER TABLE audit_events ENABLE TRIGGER event_writer"))
    found = _problems(owner)
    assert any(f"by database role {READER}, which may not add runs" in d for d in found), found
    assert any("role nobody_here, which no longer exists" in d for d in found), found
    for a in (owner, writer):
        a.dispose()
