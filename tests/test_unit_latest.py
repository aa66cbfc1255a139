"""The derived table unit_latest (storage.unit_latest) on both back ends.

Known truth: the runs archived, their start times, the order they were archived in and
their verdicts, from which each unit's latest run and latest valid calibration follow.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

from sqlalchemy import select, text
from test_archive import make_run

from storage import queries, unit_latest
from storage.archive import archive_run
from storage.db import Archive
from storage.schema import CalibrationRow, Device, Run, UnitLatest
from storage.verify import verify

MAY, MARCH = datetime(2024, 5, 1, 8, 30, tzinfo=UTC), datetime(2024, 3, 1, 8, 30, tzinfo=UTC)


def _row(archive: Archive, serial: str) -> dict:
    """The unit's row with its ids as the archive names them: run id and revision."""
    cal, valid = CalibrationRow.__table__.alias("cal"), CalibrationRow.__table__.alias("valid")
    stmt = (
        select(
            Run.run_id,
            cal.c.revision,
            UnitLatest.verdict,
            valid.c.run_id.label("valid_run_pk"),
            valid.c.revision.label("valid_revision"),
        )
        .join(Device, Device.id == UnitLatest.device_id)
        .join(Run, Run.id == UnitLatest.run_id)
        .outerjoin(cal, cal.c.id == UnitLatest.calibration_id)
        .outerjoin(valid, valid.c.id == UnitLatest.valid_calibration_id)
        .where(Device.serial == serial)
    )
    with archive.engine().connect() as conn:
        r = dict(conn.execute(stmt).one()._mapping)
        pk = r.pop("valid_run_pk")
        r["valid_run"] = None if pk is None else conn.scalar(select(Run.run_id).where(Run.id == pk))
    return r


def _fleet_agrees(archive: Archive) -> None:
    """The browser's fleet (from unit_latest) gives the CLI's fleet (walking the runs)."""
    mine = queries.fleet_values(archive, "MPU-6000", "acc.bias.x")
    cli = queries.fleet(archive, "MPU-6000", "acc.bias.x")
    assert [(r["serial"], r["value"]) for r in mine] == list(
        zip(cli["serial"], cli["value"], strict=True)
    )
    with archive.engine().connect() as conn:
        assert unit_latest.differences(conn) == []
        assert unit_latest.value_differences(conn) == []


def test_kept_through_out_of_order_runs_and_revisions(archive: Archive, tmp_path: Path) -> None:
    may = make_run(tmp_path / "may", seed=1, started_at=MAY)
    a = archive_run(archive, may).run_id
    assert _row(archive, "0012") == {
        "run_id": a,
        "revision": 1,
        "verdict": "pass",
        "valid_run": a,
        "valid_revision": 1,
    }
    # An earlier run archived later is not the latest; a failed one is not valid.
    b = archive_run(
        archive, make_run(tmp_path / "mar", seed=2, started_at=MARCH, verdict="fail")
    ).run_id
    assert _row(archive, "0012")["run_id"] == a and _row(archive, "0012")["valid_run"] == a
    archive_run(archive, make_run(tmp_path / "u77", serial="77", seed=3, verdict="fail"))
    assert _row(archive, "77") == {
        "run_id": _row(archive, "77")["run_id"],
        "revision": 1,
        "verdict": "fail",
        "valid_run": None,
        "valid_revision": None,
    }
    _fleet_agrees(archive)
    # The latest run revised to fail: still the latest, no valid calibration left.
    archive_run(archive, replace(may, settings={"outlier_sigma": 4.0}, verdict="fail"))
    assert _row(archive, "0012") == {
        "run_id": a,
        "revision": 2,
        "verdict": "fail",
        "valid_run": None,
        "valid_revision": None,
    }
    assert b != a
    _fleet_agrees(archive)
    # A third revision passes again: valid is that revision.
    archive_run(archive, replace(may, settings={"outlier_sigma": 3.0}))
    assert _row(archive, "0012") == {
        "run_id": a,
        "revision": 3,
        "verdict": "pass",
        "valid_run": a,
        "valid_revision": 3,
    }
    _fleet_agrees(archive)


def test_verify_reports_a_row_that_disagrees(archive: Archive, tmp_path: Path) -> None:
    a = archive_run(archive, make_run(tmp_path / "a", seed=1)).run_id
    archive_run(archive, make_run(tmp_path / "b", serial="77", seed=2))
    assert verify(archive).ok
    with archive.engine().begin() as conn:  # what no code path does: a derived row edited
        conn.execute(
            text(
                "UPDATE unit_latest SET valid_calibration_id = NULL, verdict = 'fail' "
                "WHERE device_id = (SELECT id FROM devices WHERE serial = '0012')"
            )
        )
    report = verify(archive)  # the row, and the values a fleet reads through it (none)
    assert [(p.kind, p.runs) for p in report.problems] == [("database", [a]), ("database", [])]
    assert "unit 0012: unit_latest holds" in report.problems[0].detail
    assert "unit 0012: unit_latest_values of acc.bias.x, acc.bias.y" in report.problems[1].detail
    assert "'verdict': 'fail'" in report.problems[0].detail
    assert "'verdict': 'pass'" in report.problems[0].detail
    with archive.engine().begin() as conn:
        assert unit_latest.rebuild(conn) == 2
    assert verify(archive).ok
    with archive.engine().begin() as conn:  # a derived value edited
        conn.execute(
            text(
                "UPDATE unit_latest_values SET value = value + 1 "
                "WHERE serial = '77' AND name = 'acc.bias.y'"
            )
        )
    report = verify(archive)
    assert [(p.kind, p.runs) for p in report.problems] == [("database", [])]
    assert "unit 77: unit_latest_values of acc.bias.y differ" in report.problems[0].detail
    with archive.engine().begin() as conn:
        unit_latest.rebuild(conn)
    assert verify(archive).ok


def test_nearest_takes_the_value_nearest_20_c() -> None:
    rows = [
        ("a", 1.0, 40.0),
        ("a", 2.0, 25.0),
        ("a", 3.0, 15.0),
        ("a", 4.0, 15.0),
        ("b", 5.0, None),
        ("b", 6.0, 20.5),
        ("c", 7.0, float("nan")),
        ("c", 8.0, 20.0),
    ]
    assert unit_latest.nearest(rows) == {"a": (3.0, 15.0), "b": (5.0, None), "c": (7.0, rows[6][2])}
