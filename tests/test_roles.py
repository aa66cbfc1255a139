"""PostgreSQL roles on the real server of the fixtures: the reader reads, the writer appends.

Truth: PostgreSQL's own privilege checks. Each forbidden statement must fail
with SQLSTATE 42501 (insufficient_privilege), not with any other error.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from sqlalchemy import text
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ProgrammingError
from test_archive import make_run

from storage import queries
from storage.archive import archive_run
from storage.db import Archive
from storage.roles import READER, WRITER, apply_roles, role_sql

pytestmark = pytest.mark.postgres


def _as(url: str, role: str, root: Path) -> Archive:
    return Archive(make_url(url).set(username=role).render_as_string(hide_password=False), root)


def _denied(archive: Archive, sql: str) -> None:
    with pytest.raises(ProgrammingError) as info, archive.engine().begin() as conn:
        conn.execute(text(sql))
    assert info.value.orig.sqlstate == "42501", info.value  # insufficient_privilege


@pytest.fixture
def roles(postgres_url: str, tmp_path: Path):  # noqa: ANN201
    owner = Archive(postgres_url, tmp_path / "store")
    owner.upgrade()
    apply_roles(owner)
    apply_roles(owner)  # idempotent: a second run (e.g. after a migration) changes nothing
    reader = _as(postgres_url, READER, owner.root)
    writer = _as(postgres_url, WRITER, owner.root)
    yield owner, reader, writer
    for a in (owner, reader, writer):
        a.dispose()


def test_reader_reads_and_cannot_write(roles, tmp_path: Path) -> None:  # noqa: ANN001
    owner, reader, _ = roles
    run = make_run(tmp_path / "in")
    res = archive_run(owner, run)
    reader.upgrade()  # what every CLI start does: a no-op at head, allowed for the reader
    assert queries.history(reader, "0012")["run_id"].tolist() == [res.run_id]
    assert queries.lineage(reader, res.run_id, "acc.bias.x")["run"]["operator"] == run.operator
    _denied(
        reader,
        "INSERT INTO devices (serial, model, manufacturer, created_at) "
        "VALUES ('x', 'm', 'n', now())",
    )
    _denied(reader, "UPDATE runs SET operator = 'mallory'")
    _denied(reader, "DELETE FROM parameters")
    _denied(reader, "UPDATE alembic_version SET version_num = '0001'")
    _denied(reader, "CREATE TABLE evil (id int)")
    with pytest.raises(ProgrammingError):
        archive_run(reader, make_run(tmp_path / "in2", seed=5))
    assert queries.history(owner, "0012")["run_id"].tolist() == [res.run_id]


def test_writer_appends_and_cannot_change_history(roles, tmp_path: Path) -> None:  # noqa: ANN001
    owner, _, writer = roles
    run = make_run(tmp_path / "in")
    first = archive_run(writer, run)
    assert first.status == "ok"
    # A revision updates the one column it may: superseded_by.
    second = archive_run(writer, replace(run, settings={"outlier_sigma": 4.0}))
    assert (second.status, second.revision) == ("revised", 2)
    assert queries.history(owner, "0012")["superseded"].tolist() == [True, False]
    _denied(writer, "DELETE FROM runs")
    _denied(writer, "DELETE FROM parameters")
    _denied(writer, "UPDATE parameters SET value = 0")
    _denied(writer, "UPDATE calibrations SET verdict = 'pass'")
    _denied(writer, "UPDATE runs SET operator = 'mallory'")
    _denied(writer, "TRUNCATE check_results")
    _denied(writer, "UPDATE alembic_version SET version_num = '0001'")
    _denied(writer, "CREATE TABLE evil (id int)")


def test_sealed_rows_and_the_audit_chain_are_guarded(roles, tmp_path: Path) -> None:  # noqa: ANN001
    """The writer appends runs and events, and changes nothing sealed.

    Grants refuse UPDATE and DELETE; the triggers of migration 0004 refuse what a
    grant cannot tell apart (a row added to an archived calibration), and refuse
    changes to seals and events even to the owner.
    """
    owner, _, writer = roles
    archive_run(writer, make_run(tmp_path / "in"))
    _denied(writer, "UPDATE seals SET digest = repeat('0', 64)")
    _denied(writer, "DELETE FROM seals")
    _denied(writer, "UPDATE audit_events SET actor = 'mallory'")
    _denied(writer, "DELETE FROM audit_events")
    _denied(writer, "TRUNCATE audit_events")
    _denied(
        writer,
        "INSERT INTO parameters (calibration_id, name, value, std, unit) "
        "VALUES (1, 'gyr.bias.z', 1.0, 0.1, 'rad/s')",
    )
    _denied(
        writer,
        "INSERT INTO check_results (calibration_id, name, passed, detail) "
        "VALUES (1, 'forged', true, '')",
    )
    _denied(
        writer,
        "INSERT INTO raw_files (run_id, name, sha256, size, format, stored_path) "
        "SELECT 1, 'x', sha256, size, format, stored_path FROM raw_files LIMIT 1",
    )
    _denied(owner, "UPDATE audit_events SET actor = 'mallory'")
    _denied(owner, "DELETE FROM seals")
    assert archive_run(writer, make_run(tmp_path / "in2", seed=3)).status == "ok"


def test_role_sql_quotes_names_and_refuses_unsafe_ones() -> None:
    text_ = role_sql("calib")
    grant_select = next(line for line in text_.splitlines() if line.startswith("GRANT SELECT ON"))
    assert '"devices"' in grant_select and '"audit_events"' in grant_select
    assert 'GRANT UPDATE ("superseded_by") ON "calibrations" TO "calib_writer"' in text_
    assert "DELETE" not in text_.replace("REVOKE INSERT, UPDATE, DELETE", "").replace(
        "REVOKE UPDATE, DELETE", ""
    )
    with pytest.raises(ValueError, match="invalid reader role"):
        role_sql("calib", reader='x"; DROP TABLE runs; --')
