"""PostgreSQL roles that cannot forge (storage.roles: grants, guard function and trigger).

Truth: PostgreSQL's own privilege checks and the guard function and trigger. Each
refused statement must fail with SQLSTATE 42501 (insufficient_privilege), not with
any other error; each allowed one must succeed. The forgeries tried are those of the
writer role in the threat model (docs/archive.md): an event inserted directly (even
correctly linked), one appended through the function but unlinked or backdated, a
revision made current again or pointed at another run's.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from sqlalchemy import text
from sqlalchemy.exc import ProgrammingError
from test_archive import make_run
from test_roles import _as, _denied

from storage import seal
from storage.approval import approve, generate_key, load_key
from storage.archive import archive_run
from storage.db import Archive
from storage.roles import APPROVER, READER, WRITER, apply_roles
from storage.verify import verify

pytestmark = pytest.mark.postgres
PASS = "correct horse battery"


@pytest.fixture
def roles(postgres_url: str, tmp_path: Path):  # noqa: ANN201
    owner = Archive(postgres_url, tmp_path / "store")
    owner.upgrade()
    apply_roles(owner)
    by_role = {r: _as(postgres_url, r, owner.root) for r in (READER, WRITER, APPROVER)}
    yield owner, by_role
    for a in (owner, *by_role.values()):
        a.dispose()


def _linked_insert(conn, action: str = "archived", **fields: object) -> str:  # noqa: ANN001
    """An event correctly linked to the head, as calib computes it; the SQL of a direct
    INSERT of it."""
    seq, prev = seal.head(conn)
    ev = seal.Event(seq + 1, seal.utcnow(), "mallory", action, None, None, None, {}, None, prev)
    return (
        f"INSERT INTO audit_events (seq, at, actor, action, detail, prev_hash, hash) VALUES "
        f"({ev.seq}, '{ev.at.isoformat()}', 'mallory', '{action}', '{{}}', '{prev}', "
        f"'{ev.hash()}')"
    )


def _through_function(  # noqa: ANN001 - conn: a Connection
    conn, *, seq_off: int = 1, at: str = "now()", action: str = "archived", prev: str | None = None
) -> str:
    seq, head = seal.head(conn)
    return (
        f"SELECT calib_append_event({at}, 'mallory', '{action}', NULL, NULL, NULL, "
        f"'{{}}'::json, NULL, '{prev or head}', repeat('7', 64), {seq + seq_off}, session_user)"
    )


def _linked_call(conn, db_user: str, action: str, run_id: str, revision: int, digest: str) -> str:  # noqa: ANN001
    """A call of the function with an event linked to the head and hashed as calib hashes it,
    under a made-up actor, claiming `db_user` as its writer."""
    seq, prev = seal.head(conn)
    ev = seal.Event(
        seq + 1, seal.utcnow(), "Ghost Writer", action, run_id, revision, None, {}, digest, prev,
        db_user,
    )  # fmt: skip
    return (
        f"SELECT calib_append_event('{ev.at.isoformat()}', 'Ghost Writer', '{action}', "
        f"'{run_id}', {revision}, NULL, '{{}}'::json, '{digest}', '{prev}', '{ev.hash()}', "
        f"{ev.seq}, '{db_user}')"
    )


def test_the_writer_appends_only_through_the_archive(roles, tmp_path: Path) -> None:  # noqa: ANN001
    owner, r = roles
    writer = r[WRITER]
    run = make_run(tmp_path / "in")
    assert archive_run(writer, run).status == "ok"  # allowed: runs, seals, events
    assert archive_run(writer, replace(run, settings={"outlier_sigma": 4.0})).revision == 2
    assert archive_run(writer, make_run(tmp_path / "in2", serial="77", seed=2)).status == "ok"
    with owner.engine().connect() as conn:
        direct = _linked_insert(conn)
        unlinked = _through_function(conn, prev="1" * 64)
        skipped = _through_function(conn, seq_off=2)
        backdated = _through_function(conn, at="'2020-06-01T00:00:00+00'")
    _denied(writer, direct)  # no INSERT on audit_events, even of a correctly linked event
    _denied(writer, unlinked)
    _denied(writer, skipped)
    _denied(writer, backdated)
    # which revision is current: never back, never to another run's revision
    _denied(writer, "UPDATE calibrations SET superseded_by = NULL WHERE superseded_by IS NOT NULL")
    newest = "(SELECT max(id) FROM calibrations)"  # a revision of the other run
    _denied(
        writer,
        f"UPDATE calibrations SET superseded_by = {newest} "
        f"WHERE superseded_by IS NULL AND id < {newest}",
    )
    _denied(writer, "DELETE FROM unit_latest_values")
    _denied(writer, "DELETE FROM unit_latest")
    _denied(writer, "DELETE FROM audit_events")
    assert verify(owner, orphans=False).ok


def test_events_name_their_writer_and_an_existing_revision(roles, tmp_path: Path) -> None:  # noqa: ANN001
    """A linked `archived` event for a run that does not exist, under
    a made-up actor; and events claiming another writer, or a second sealing event."""
    owner, r = roles
    writer = r[WRITER]
    res = archive_run(writer, make_run(tmp_path / "in"))
    with owner.engine().connect() as conn:
        digest = conn.execute(text("SELECT digest FROM seals")).scalar()
        writers = (
            conn.execute(
                text("SELECT DISTINCT db_user FROM audit_events WHERE action = 'archived'")
            )
            .scalars()
            .all()
        )
        ghost_run = _linked_call(conn, WRITER, "archived", "Rnothere", 1, digest)
        ghost_rev = _linked_call(conn, WRITER, "revised", res.run_id, 2, digest)
        again = _linked_call(conn, WRITER, "archived", res.run_id, 1, digest)
        as_owner = _linked_call(conn, "postgres", "approved", res.run_id, 1, digest)
        no_run_approval = _linked_call(conn, WRITER, "approved", "Rnothere", 1, digest)
    assert writers == [WRITER]  # the session user, recorded beside the claimed actor
    for forged in (ghost_run, ghost_rev, again, as_owner, no_run_approval):
        _denied(writer, forged)
    assert verify(owner, orphans=False).ok


def test_the_approver_signs_and_does_nothing_else(roles, tmp_path: Path) -> None:  # noqa: ANN001
    owner, r = roles
    approver = r[APPROVER]
    res = archive_run(r[WRITER], make_run(tmp_path / "in"))
    key = tmp_path / "jane.key"
    generate_key(key, "Jane Approver", PASS)
    ev = approve(approver, res.run_id, load_key(key, PASS), signer="Jane Approver")  # allowed
    assert ev.action == "approved"
    with owner.engine().connect() as conn:
        other = _through_function(conn, at="now()", action="archived")
        direct = _linked_insert(conn, action="approved")
    _denied(approver, other)  # only approvals
    _denied(approver, direct)
    _denied(
        approver,
        "INSERT INTO devices (serial, model, manufacturer, created_at) "
        "VALUES ('x', 'm', 'n', now())",
    )
    _denied(approver, "UPDATE runs SET operator = 'mallory'")
    _denied(approver, "UPDATE calibrations SET superseded_by = NULL")
    _denied(approver, "DELETE FROM parameters")
    with approver.engine().connect() as conn:  # allowed: reading
        assert conn.execute(text("SELECT count(*) FROM runs")).scalar() == 1
    assert verify(owner, orphans=False).ok


def test_the_reader_reads_only(roles, tmp_path: Path) -> None:  # noqa: ANN001
    owner, r = roles
    reader = r[READER]
    archive_run(owner, make_run(tmp_path / "in"))
    with reader.engine().connect() as conn:  # allowed
        assert conn.execute(text("SELECT count(*) FROM audit_events")).scalar() == 2
    with owner.engine().connect() as conn:
        call = _through_function(conn, action="approved")
        direct = _linked_insert(conn)
    _denied(reader, call)  # no EXECUTE on the function
    _denied(reader, direct)
    _denied(reader, "UPDATE calibrations SET superseded_by = NULL")
    _denied(reader, "DELETE FROM unit_latest_values")


def test_the_guard_keeps_the_owner_to_the_chain_too(roles) -> None:  # noqa: ANN001
    """The function is the same for every role: an unlinked event is refused even to the
    owner calling it (who could insert directly: the owner is outside the guard)."""
    owner, _ = roles
    with owner.engine().connect() as conn:
        unlinked = _through_function(conn, prev="1" * 64)
    with pytest.raises(ProgrammingError) as info, owner.engine().begin() as conn:
        conn.execute(text(unlinked))
    assert "does not follow the chain head" in str(info.value)
