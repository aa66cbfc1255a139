"""Seals and the audit chain (storage.seal): a change behind the archive's back is found.

Known truth: what `fill` archived (three runs, one of them revised, each with a
protocol file). Each tamper changes exactly one thing with raw SQL on the real
SQLite file or the real PostgreSQL server, as an attacker with database access
would; verify must name the run and the table/row/field with both values.
Before seals, verify reported OK after every one of them.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
from sqlalchemy import Connection, select, text
from test_archive import make_run
from test_verify_backup import fill

from storage import queries
from storage.archive import archive_run
from storage.db import Archive
from storage.schema import AuditEvent, CalibrationRow, Run, Seal
from storage.verify import Problem, verify


@contextlib.contextmanager
def behind_the_archive(archive: Archive) -> Iterator[Connection]:
    """A transaction as the database superuser with PostgreSQL's guard triggers off.

    That is what an attacker with full database access can do (and the most an
    archive can face); the guards themselves are tested in test_roles.py.
    """
    with archive.engine().begin() as conn:
        if conn.dialect.name == "postgresql":
            conn.execute(text("SET LOCAL session_replication_role = replica"))
        yield conn


def _tamper(archive: Archive, sql: str, **params: object) -> None:
    with behind_the_archive(archive) as conn:
        assert conn.execute(text(sql), params).rowcount >= 1, sql


def _problems(archive: Archive, kind: str | None = None) -> list[Problem]:
    report = verify(archive, orphans=False)
    return [p for p in report.problems if kind is None or p.kind == kind]


def _first_run(archive: Archive) -> str:
    with archive.engine().connect() as conn:
        return conn.execute(select(Run.run_id).order_by(Run.id).limit(1)).scalar_one()


def test_fresh_archive_is_sealed_and_chained(archive: Archive, tmp_path: Path) -> None:
    ids = fill(archive, tmp_path)
    report = verify(archive, orphans=False)
    assert report.ok, report.problems
    assert report.seals_checked == 4  # three runs, one of them with a second revision
    with archive.engine().connect() as conn:
        events = conn.execute(select(AuditEvent).order_by(AuditEvent.seq)).all()
        files = [r["files"] for r in conn.execute(select(Seal.record)).scalars()]
    assert [e.action for e in events] == ["archived"] * 3 + ["revised"]
    assert report.chain_head == (4, events[-1].hash)
    assert events[3].run_id == ids[0] and events[3].reason.startswith("processed again")
    assert all(e.actor for e in events)
    # every revision sealed the protocol file it wrote
    assert sorted(len(f) for f in files) == [1, 1, 1, 1]


@pytest.mark.parametrize(
    ("sql", "path_part", "found"),
    [
        ("UPDATE parameters SET value = value * 1.5 WHERE id = 1", "/value", None),
        ("UPDATE check_results SET passed = NOT passed WHERE id = 1", "/passed", None),
        (
            "UPDATE calibrations SET verdict = 'pass-forged' WHERE id = 1",
            "calibrations/verdict",
            '"pass-forged"',
        ),
        ("UPDATE runs SET operator = 'Mallory' WHERE id = 1", "runs/operator", '"Mallory"'),
        ("UPDATE runs SET manifest_text = 'forged' WHERE id = 1", "runs/manifest_text", '"forged"'),
        (
            "UPDATE calibrations SET settings = '{\"outlier_sigma\": 99}' WHERE id = 1",
            "calibrations/settings/outlier_sigma",
            "99",
        ),
        (
            "UPDATE processing_steps SET statistics = '{\"n\": -1}' WHERE id = 1",
            "processing_steps/0:",
            "-1",
        ),
        ("UPDATE devices SET model = 'Other' WHERE id = 1", "devices/model", '"Other"'),
        ("UPDATE runs SET model = 'Other' WHERE id = 1", "runs/model", '"Other"'),
        ("UPDATE runs SET specification = NULL WHERE id = 1", "runs/specification", "null"),
        (
            "UPDATE run_equipment SET calibration_due = '2099-01-01' WHERE id = 1",
            "run_equipment/rate_table:RT-7/calibration_due",
            '"2099-01-01"',
        ),
    ],
)
def test_each_changed_value_is_named(
    archive: Archive, tmp_path: Path, sql: str, path_part: str, found: str | None
) -> None:
    _assert_named(archive, tmp_path, sql, path_part, found)


@pytest.mark.parametrize(
    ("sql", "path_part"),
    [
        ("DELETE FROM parameters WHERE id = 2", "parameters/"),
        ("DELETE FROM check_results WHERE id = 1", "check_results/"),
        ("DELETE FROM processing_steps WHERE id = 1", "processing_steps/0:"),
    ],
)
def test_each_deleted_row_is_named(
    archive: Archive, tmp_path: Path, sql: str, path_part: str
) -> None:
    _assert_named(archive, tmp_path, sql, path_part, "(absent)")


def _assert_named(
    archive: Archive, tmp_path: Path, sql: str, path_part: str, found: str | None
) -> None:
    """After `sql` on a filled archive, verify names the first run, a path holding
    `path_part`, the sealed value and the one found (`found`, when given)."""
    fill(archive, tmp_path)
    run_id = _first_run(archive)
    _tamper(archive, sql)
    records = _problems(archive, "record")
    sealed = [p for p in records if path_part in p.path and "sealed" in p.detail]
    assert sealed, records
    assert run_id in sealed[0].runs
    assert ": sealed " in sealed[0].detail and ", found " in sealed[0].detail
    if found is not None:
        assert sealed[0].detail.endswith(f"found {found}"), sealed[0].detail


def test_the_calibration_document_edited_is_named(archive: Archive, tmp_path: Path) -> None:
    fill(archive, tmp_path)
    with behind_the_archive(archive) as conn:
        cal = conn.execute(select(CalibrationRow.id, CalibrationRow.document).limit(1)).one()
        doc = {**cal.document, "procedure": "forged"}
        conn.execute(
            CalibrationRow.__table__.update()
            .where(CalibrationRow.id == cal.id)
            .values(document=doc)
        )
    paths = [p.path for p in _problems(archive, "record")]
    assert paths == ["calibrations/document/procedure"]


def test_a_protocol_file_edited_is_named(archive: Archive, tmp_path: Path) -> None:
    fill(archive, tmp_path)
    protocol = next(archive.root.glob("runs/*/*/*/protocol.txt"))
    protocol.write_bytes(b"verdict: pass")
    rel = protocol.relative_to(archive.root).as_posix()
    found = _problems(archive, "record")
    assert [p.path for p in found] == [f"files/{rel}"]


def test_a_forged_row_in_an_archived_calibration_is_found(archive: Archive, tmp_path: Path) -> None:
    fill(archive, tmp_path)
    _tamper(
        archive,
        "INSERT INTO parameters (calibration_id, name, value, std, unit) "
        "VALUES (1, 'gyr.bias.z', 1.0, 0.1, 'rad/s')",
    )
    paths = [p.path for p in _problems(archive, "record")]
    assert "parameters/gyr.bias.z" in paths, paths


def test_a_deleted_run_breaks_the_chain(archive: Archive, tmp_path: Path) -> None:
    """Delete the rows of the second run, its seal and its event: the chain shows the gap."""
    ids = fill(archive, tmp_path)
    victim = ids[1]
    with behind_the_archive(archive) as conn:
        for sql in (
            "DELETE FROM seals WHERE calibration_id IN (SELECT id FROM calibrations "
            "WHERE run_id = (SELECT id FROM runs WHERE run_id = :r))",
            *(
                f"DELETE FROM {t} WHERE calibration_id IN (SELECT id FROM calibrations WHERE "
                "run_id = (SELECT id FROM runs WHERE run_id = :r))"
                for t in ("parameters", "check_results", "processing_steps")
            ),
            "DELETE FROM calibrations WHERE run_id = (SELECT id FROM runs WHERE run_id = :r)",
            *(
                f"DELETE FROM {t} WHERE run_id = (SELECT id FROM runs WHERE run_id = :r)"
                for t in ("raw_files", "run_equipment")
            ),
            "DELETE FROM runs WHERE run_id = :r",
            "DELETE FROM audit_events WHERE run_id = :r",
        ):
            conn.execute(text(sql), {"r": victim})
    chain = _problems(archive, "chain")
    assert any("events 2..2 are missing" in p.detail for p in chain), chain
    assert any("does not follow the event before it" in p.detail for p in chain), chain


def test_deleted_rows_of_a_sealed_run_are_found(archive: Archive, tmp_path: Path) -> None:
    """Rows gone, seal and events left: the seal names the run whose rows are gone."""
    ids = fill(archive, tmp_path)
    _tamper(archive, "DELETE FROM seals WHERE calibration_id = 2")
    chain = _problems(archive, "chain")
    assert any(ids[1] in p.runs and "its seal row is gone" in p.detail for p in chain), chain
    assert any(ids[1] in p.runs and "has no seal" in p.detail for p in chain), chain


def test_an_edited_event_or_reordered_events_break_the_chain(
    archive: Archive, tmp_path: Path
) -> None:
    fill(archive, tmp_path)
    _tamper(archive, "UPDATE audit_events SET actor = 'someone else' WHERE seq = 2")
    assert any(
        "event 2 (archived" in p.detail and "was changed" in p.detail
        for p in _problems(archive, "chain")
    )
    _tamper(archive, "UPDATE audit_events SET seq = seq + 10 WHERE seq = 3")
    _tamper(archive, "UPDATE audit_events SET seq = 3 WHERE seq = 4")
    _tamper(archive, "UPDATE audit_events SET seq = 4 WHERE seq = 13")
    details = [p.detail for p in _problems(archive, "chain")]
    assert any("event 3 (revised" in d and "does not follow" in d for d in details), details


def test_a_seal_rewritten_to_match_the_tamper_is_found(archive: Archive, tmp_path: Path) -> None:
    """Changing a value and its seal's record and digest still leaves the chain's digest."""
    fill(archive, tmp_path)
    with behind_the_archive(archive) as conn:
        conn.execute(text("UPDATE runs SET operator = 'Mallory' WHERE id = 1"))
    from storage.seal_record import canonical, digest_of, records

    with behind_the_archive(archive) as conn:
        rec = records(conn, [1])[1]
        rec["files"] = conn.execute(
            select(Seal.record).where(Seal.calibration_id == 1)
        ).scalar_one()["files"]
        conn.execute(
            Seal.__table__.update()
            .where(Seal.calibration_id == 1)
            .values(record=json.loads(canonical(rec)), digest=digest_of(rec))
        )
    chain = _problems(archive, "chain")
    assert any("the seal of" in p.detail and "was changed" in p.detail for p in chain), chain


def test_migration_seals_an_existing_archive(archive: Archive, tmp_path: Path) -> None:
    """An archive from before 0004 (its rows, no seals) gets one seal and event per revision."""
    fill(archive, tmp_path)
    archive.migrate("0003", down=True)  # drops seals and chain: the archive as 0003 had it
    archive.upgrade()
    report = verify(archive, orphans=False)
    assert report.ok, report.problems
    assert report.seals_checked == 4 and report.chain_head[0] == 4
    with archive.engine().connect() as conn:
        actors = set(conn.execute(select(AuditEvent.actor)).scalars())
    assert actors == {"migration 0004"}
    _tamper(archive, "UPDATE parameters SET std = 0.5 WHERE id = 3")
    assert [
        p.path.rsplit("/", 1)[1] for p in _problems(archive, "record") if "sealed" in p.detail
    ] == ["std"]


def test_each_run_keeps_its_own_description_sealed(archive: Archive, tmp_path: Path) -> None:
    """A later run of serial 0012 that names another model keeps that model; so does the
    first; both descriptions are sealed and a change of either is named."""
    ids = fill(archive, tmp_path)
    other = replace(
        make_run(tmp_path / "relabelled", serial="0012", seed=9),
        device_model="ICM-20602",
        manufacturer="TDK",
    )
    later = archive_run(archive, other, {"protocol.txt": b"run 9"}).run_id
    assert verify(archive, orphans=False).ok
    for run_id, model, maker in ((ids[0], "MPU-6000", "InvenSense"), (later, "ICM-20602", "TDK")):
        device = queries.run_summary(archive, run_id).device
        assert (device.serial, device.model, device.manufacturer) == ("0012", model, maker)
        assert queries.export_calibration(archive, run_id)["unit"]["model"] == model
    _tamper(archive, "UPDATE runs SET model = 'MPU-6000' WHERE run_id = :r", r=later)
    found = [p for p in _problems(archive, "record") if p.path == "runs/model"]
    assert [p.runs for p in found] == [[later]], found
    assert found[0].detail.endswith('sealed "ICM-20602", found (absent)'), found[0].detail


def _sealed_formats(archive: Archive) -> list:
    with archive.engine().connect() as conn:
        return conn.execute(select(Seal.record["format"]).order_by(Seal.id)).scalars().all()


def test_seals_of_format_1_still_verify_and_name_a_change(
    archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Seals written before format 2 (every value decoded in the record) keep verifying
    beside new ones, and a change to a JSON column is named inside the JSON."""
    from storage import seal

    monkeypatch.setattr(seal, "FORMAT", 1)
    fill(archive, tmp_path)
    monkeypatch.undo()
    archive_run(archive, make_run(tmp_path / "new", serial="SN-NEW", seed=9), {})
    assert _sealed_formats(archive) == [None] * 4 + [2]
    assert verify(archive, orphans=False).ok
    with behind_the_archive(archive) as conn:
        cal = conn.execute(select(CalibrationRow.id, CalibrationRow.document).limit(1)).one()
        conn.execute(
            CalibrationRow.__table__.update()
            .where(CalibrationRow.id == cal.id)
            .values(document={**cal.document, "procedure": "forged"})
        )
    assert [p.path for p in _problems(archive)] == ["calibrations/document/procedure"]


def test_a_json_column_rewritten_as_equal_json_is_found(archive: Archive, tmp_path: Path) -> None:
    """Format 2 seals the stored text of a JSON column: other text for the same JSON is
    still a change, shown by the two hashes."""
    fill(archive, tmp_path)
    assert set(_sealed_formats(archive)) == {2}
    with behind_the_archive(archive) as conn:
        cast_ = (
            "CAST(' ' || CAST(settings AS TEXT) AS JSON)"
            if conn.dialect.name == "postgresql"
            else "' ' || settings"
        )
        assert (
            conn.execute(text(f"UPDATE calibrations SET settings = {cast_} WHERE id = 1")).rowcount
            == 1
        )
    found = _problems(archive)
    assert [p.path for p in found] == ["calibrations/settings"], found
    assert found[0].detail.count('"sha256:') == 2, found[0].detail


def test_a_seal_in_a_format_this_version_cannot_read_is_named(
    archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Seals a later version wrote (format 3 here) are named, not reported as tampered."""
    from storage import seal

    monkeypatch.setattr(seal, "FORMAT", 3)
    fill(archive, tmp_path)
    monkeypatch.undo()
    found = _problems(archive)
    assert len(found) == 4 and {p.kind for p in found} == {"chain"}, found
    assert all("record format 3" in p.detail and "cannot read" in p.detail for p in found)
