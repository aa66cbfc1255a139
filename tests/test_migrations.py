"""Alembic migrations build exactly the schema of storage/schema.py, on both back ends."""

from __future__ import annotations

import json
import threading
from dataclasses import replace
from pathlib import Path

from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import insert, inspect, select, text
from test_archive import make_run

from storage.archive import archive_run
from storage.db import Archive
from storage.schema import TABLES, Base, Device, Run
from storage.verify import verify


def _head(archive: Archive) -> str:
    return ScriptDirectory.from_config(archive.alembic_config()).get_current_head()


def _snapshot(archive: Archive) -> dict:
    """Tables with their columns, indexes, unique constraints and foreign keys."""
    with archive.engine().connect() as conn:
        insp = inspect(conn)
        return {
            t: (
                [(c["name"], str(c["type"]), c["nullable"]) for c in insp.get_columns(t)],
                sorted(i["name"] for i in insp.get_indexes(t)),
                sorted(u["name"] or "" for u in insp.get_unique_constraints(t)),
                sorted(str(fk["constrained_columns"]) for fk in insp.get_foreign_keys(t)),
            )
            for t in sorted(insp.get_table_names())
        }


def test_upgrade_from_empty_matches_the_models(empty_archive: Archive) -> None:
    assert empty_archive.schema_revision() is None
    empty_archive.upgrade()
    assert empty_archive.schema_revision() == _head(empty_archive)
    with empty_archive.engine().connect() as conn:
        assert set(inspect(conn).get_table_names()) == {*TABLES, "alembic_version"}
        # What autogenerate would add to a new migration: nothing, if 0001.. == schema.py.
        diffs = compare_metadata(MigrationContext.configure(conn), Base.metadata)
    assert diffs == []


def test_upgrade_twice_is_a_no_op_and_keeps_data(empty_archive: Archive) -> None:
    empty_archive.upgrade()
    with empty_archive.engine().begin() as conn:
        conn.execute(insert(Device).values(serial="0012", model="m", manufacturer="x"))
    before = _snapshot(empty_archive)
    empty_archive.upgrade()
    assert _snapshot(empty_archive) == before
    assert empty_archive.schema_revision() == _head(empty_archive)
    with empty_archive.engine().connect() as conn:
        assert conn.execute(select(Device.serial)).scalars().all() == ["0012"]


def test_each_revision_upgrades_from_its_predecessor(empty_archive: Archive) -> None:
    """Walk base -> head one revision at a time, then down to base and up again."""
    script = ScriptDirectory.from_config(empty_archive.alembic_config())
    revisions = [r.revision for r in reversed(list(script.walk_revisions()))]
    for rev in revisions:
        empty_archive.migrate(rev)
        assert empty_archive.schema_revision() == rev
    head_schema = _snapshot(empty_archive)
    empty_archive.migrate("base", down=True)
    assert empty_archive.schema_revision() is None
    assert set(_snapshot(empty_archive)) <= {"alembic_version"}
    empty_archive.upgrade()
    assert _snapshot(empty_archive) == head_schema


def test_concurrent_upgrades_of_an_empty_database(empty_archive: Archive) -> None:
    """Two workers starting at once: both succeed, the schema is built once."""
    errors: list[BaseException] = []
    barrier = threading.Barrier(2)

    def start() -> None:
        try:
            barrier.wait(timeout=10)
            empty_archive.upgrade()
        except BaseException as exc:  # noqa: BLE001 - collected and asserted below
            errors.append(exc)

    threads = [threading.Thread(target=start) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert errors == []
    assert empty_archive.schema_revision() == _head(empty_archive)


def test_upgrade_at_head_is_read_without_alembic(empty_archive: Archive) -> None:
    """calib's start checks the revision with one SELECT (storage.db.migration_head reads the
    scripts); an archive one revision behind is still upgraded by Alembic."""
    from storage.db import migration_head

    assert migration_head() == _head(empty_archive)
    empty_archive.upgrade()
    assert empty_archive._at_head()
    previous = (
        ScriptDirectory.from_config(empty_archive.alembic_config())
        .get_revision(migration_head())
        .down_revision
    )
    empty_archive.migrate(previous, down=True)
    assert not empty_archive._at_head()
    empty_archive.upgrade()
    assert empty_archive.schema_revision() == migration_head()


def test_0006_gives_each_run_its_device_description(archive: Archive, tmp_path: Path) -> None:
    """Runs archived before 0006 get their unit's description (two units, two descriptions),
    and every seal, made over the device row's description, still verifies."""
    runs = [
        make_run(tmp_path / "a", serial="0012", seed=1),
        replace(
            make_run(tmp_path / "b", serial="77", seed=2),
            device_model="ADXL355",
            manufacturer="Analog Devices",
            specification=None,
        ),
    ]
    for run in runs:
        archive_run(archive, run, {"protocol.txt": run.serial.encode()})
    archive.migrate("0005", down=True)
    with archive.engine().connect() as conn:
        assert "model" not in {c["name"] for c in inspect(conn).get_columns("runs")}
    archive.upgrade()
    with archive.engine().connect() as conn:
        rows = conn.execute(
            select(Device.serial, Run.model, Run.manufacturer, Run.specification)
            .join(Device, Device.id == Run.device_id)
            .order_by(Device.serial)
        ).all()
    assert [tuple(r) for r in rows] == [
        ("0012", "MPU-6000", "InvenSense", "consumer grade"),
        ("77", "ADXL355", "Analog Devices", None),
    ]
    report = verify(archive, orphans=False)
    assert report.ok and report.seals_checked == 2, report.problems


def test_new_sqlite_archive_from_the_recorded_schema(tmp_path) -> None:
    """storage/migrations/sqlite_head.json is what the migrations give a new SQLite database
    (else: record it again with `python -m storage.db`), and `upgrade` of a new SQLite archive,
    which executes it without Alembic, gives the schema, the revision and the stored CREATE
    text of an archive upgraded by Alembic."""
    from storage.db import SQLITE_HEAD, default_archive_url, migration_head, sqlite_schema

    by_alembic = Archive(default_archive_url(tmp_path / "a"), tmp_path / "a")
    by_alembic.migrate("head")
    recorded = Archive(default_archive_url(tmp_path / "b"), tmp_path / "b")
    recorded.upgrade()
    with by_alembic.engine().connect() as a, recorded.engine().connect() as b:
        expected = sqlite_schema(a)
        assert json.loads(SQLITE_HEAD.read_text("utf-8")) == {
            "revision": migration_head(),
            "statements": expected,
        }
        assert sqlite_schema(b) == expected
        master = "SELECT type, name, tbl_name, sql FROM sqlite_master ORDER BY rowid"
        assert b.execute(text(master)).all() == a.execute(text(master)).all()
    assert recorded.schema_revision() == by_alembic.schema_revision() == migration_head()
    assert _snapshot(recorded) == _snapshot(by_alembic)
    by_alembic.dispose()
    recorded.dispose()


# What a migration may import: it runs as written for as long as archives of its revision
# exist, so it never imports the code of today's calib (which changes with it).
MIGRATION_IMPORTS = {"__future__", "alembic", "sqlalchemy", "storage.migrations.ddl"}


def test_every_migration_is_self_contained() -> None:
    import ast
    import sys

    folder = Path(__file__).resolve().parents[1] / "storage" / "migrations"
    bad = []
    for path in sorted([folder / "ddl.py", *(folder / "versions").glob("*.py")]):
        for node in ast.walk(ast.parse(path.read_text("utf-8"))):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            for name in names:
                top = name.split(".")[0]
                if (
                    name not in MIGRATION_IMPORTS
                    and top not in MIGRATION_IMPORTS
                    and (top not in sys.stdlib_module_names)
                ):
                    bad.append(f"{path.name} line {node.lineno}: imports {name}")
    assert bad == [], "\n".join(bad)


def test_0004_and_0007_derive_seals_and_unit_picks_of_archived_runs(
    archive: Archive, tmp_path: Path
) -> None:
    """Runs archived, the archive taken back to 0003 (no seals, no chain, no unit_latest)
    and upgraded: 0004 seals each revision (format 1, no files) with one "sealed" event,
    0007 derives each unit's picks, and verify finds the seals, the chain and the picks
    as today's code computes them."""
    from storage.schema import AuditEvent, Seal, UnitLatest

    runs = [
        make_run(tmp_path / "a", serial="0012", seed=1),
        make_run(tmp_path / "b", serial="0012", seed=2),
        make_run(tmp_path / "c", serial="77", seed=3),
    ]
    for run in runs:
        archive_run(archive, run, {"protocol.txt": run.serial.encode()})
    archive.migrate("0003", down=True)
    archive.upgrade()
    with archive.engine().connect() as conn:
        actions = conn.execute(select(AuditEvent.action, AuditEvent.actor)).all()
        records = conn.execute(select(Seal.record)).scalars().all()
        units = conn.execute(select(UnitLatest.device_id)).all()
    assert [tuple(a) for a in actions] == [("sealed", "migration 0004")] * 3
    assert [r["files"] for r in records] == [{}] * 3 and all("format" not in r for r in records)
    assert len(units) == 2
    report = verify(archive, orphans=False)
    assert report.ok and report.seals_checked == 3, report.problems
