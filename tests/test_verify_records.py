"""`calib verify` finds a parameter changed behind the archive's back, in its row or in
the stored calibration document (both are written from the same Parameter objects).

Known truth: what `fill` archived; each tamper changes exactly one thing, and verify
must name run, parameter, field and both values.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlalchemy import select, text, update
from sqlalchemy.orm import Session
from test_seal import behind_the_archive
from test_verify_backup import fill

from storage.db import Archive
from storage.schema import CalibrationRow, ParameterRow
from storage.verify import verify


def _records(archive: Archive) -> list:
    """Rows-versus-document problems only (the seals, checked in test_seal.py, see more)."""
    return [p for p in verify(archive, orphans=False, seals=False).problems if p.kind == "record"]


def _one_parameter(archive: Archive) -> tuple[int, str, float]:
    with Session(archive.engine()) as s:
        row = s.execute(select(ParameterRow).order_by(ParameterRow.id).limit(1)).scalar_one()
        return row.calibration_id, row.name, row.value


def test_fresh_archive_rows_and_documents_agree(archive: Archive, tmp_path: Path) -> None:
    fill(archive, tmp_path)
    report = verify(archive, orphans=False)
    assert report.ok, report.problems


def test_value_changed_in_the_rows_is_found(archive: Archive, tmp_path: Path) -> None:
    ids = fill(archive, tmp_path)
    cal_id, name, value = _one_parameter(archive)
    with archive.engine().begin() as conn:
        conn.execute(text("UPDATE parameters SET value = value * 1.5"))
    found = _records(archive)
    # every parameter row of every calibration now disagrees with its document
    with Session(archive.engine()) as s:
        n_rows = len(s.execute(select(ParameterRow.id)).all())
    assert len(found) == n_rows > 0
    mine = [p for p in found if p.path == f"parameters/{name}" and f"{value * 1.5!r}" in p.detail]
    assert mine, found[:3]
    assert "value is" in mine[0].detail and repr(value) in mine[0].detail
    assert set(ids) >= {r for p in found for r in p.runs}


def test_value_changed_in_the_document_is_found(archive: Archive, tmp_path: Path) -> None:
    fill(archive, tmp_path)
    cal_id, name, value = _one_parameter(archive)
    with Session(archive.engine()) as s, s.begin():
        cal = s.get(CalibrationRow, cal_id)
        doc = dict(cal.document)
        doc["parameters"] = {**doc["parameters"], name: {**doc["parameters"][name], "std": 9.0}}
        s.execute(update(CalibrationRow).where(CalibrationRow.id == cal_id).values(document=doc))
    found = _records(archive)
    assert len(found) == 1, found
    assert found[0].path == f"parameters/{name}"
    assert "std is" in found[0].detail and "9.0 in the calibration document" in found[0].detail


def test_deleted_row_and_extra_row_are_found(archive: Archive, tmp_path: Path) -> None:
    fill(archive, tmp_path)
    cal_id, name, value = _one_parameter(archive)
    with behind_the_archive(archive) as conn:
        conn.execute(
            text("DELETE FROM parameters WHERE calibration_id = :c AND name = :n"),
            {"c": cal_id, "n": name},
        )
        conn.execute(
            text(
                "INSERT INTO parameters (calibration_id, name, value, std, unit) "
                "VALUES (:c, 'gyr.bias.z', 1.0, 0.1, 'rad/s')"
            ),
            {"c": cal_id},
        )
    details = sorted(p.detail for p in _records(archive))
    assert any(d.startswith(f"{name} ") and "no parameters row" in d for d in details), details
    if name != "gyr.bias.z":
        assert any(
            d.startswith("gyr.bias.z ") and "absent from the document" in d for d in details
        ), details


def test_duplicated_row_is_found(archive: Archive, tmp_path: Path) -> None:
    fill(archive, tmp_path)
    cal_id, name, value = _one_parameter(archive)
    with behind_the_archive(archive) as conn:
        conn.execute(
            text(
                "INSERT INTO parameters (calibration_id, name, value, std, unit) "
                "SELECT calibration_id, name, value, std, unit FROM parameters "
                "WHERE calibration_id = :c AND name = :n"
            ),
            {"c": cal_id, "n": name},
        )
    details = [p.detail for p in _records(archive)]
    assert details == [f"{name}: more than one parameters row in calibration id {cal_id}"]


@pytest.mark.slow
def test_parameter_row_round_trip() -> None:
    """One function each way between a Parameter and its archive row; nothing is lost."""
    from calib_core.calibration import Parameter

    p = Parameter("gyr.scale.x", 1.25e-3, 2.0e-5, cov_index=4)
    row = p.to_row(23.5)
    assert row == {
        "name": "gyr.scale.x",
        "value": 1.25e-3,
        "std": 2.0e-5,
        "unit": "1",
        "cov_index": 4,
        "temperature_c": 23.5,
    }
    assert Parameter.from_row(row) == p
    assert Parameter.from_row(Parameter("acc.bias.y", -0.01).to_row()).cov_index is None
