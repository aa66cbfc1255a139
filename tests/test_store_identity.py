"""A PostgreSQL archive writes its files only into its own file store (storage.store_identity).

Truth: the folder the first write used. A writer started with another folder (no
CALIB_FILESTORE, run from elsewhere) must be refused before anything is written,
naming both folders; the right folder keeps working, and a backup restored to a
new folder carries the store's identity with it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from test_archive import make_run

from storage.archive import archive_run
from storage.db import Archive
from storage.store_identity import MARKER, StoreMismatchError, recorded
from storage.verify import verify

pytestmark = pytest.mark.postgres


def test_the_first_write_records_the_store_and_others_are_refused(
    postgres_url: str, tmp_path: Path
) -> None:
    home = Archive(postgres_url, tmp_path / "home")
    home.upgrade()
    run = make_run(tmp_path / "in")
    assert archive_run(home, run).status == "ok"
    known = recorded(home)
    assert known is not None and known["root"] == str((tmp_path / "home").resolve())
    assert verify(home, orphans=False).ok  # recorded in the chain, nothing else changed
    assert (tmp_path / "home" / MARKER).is_file()

    elsewhere = Archive(postgres_url, tmp_path / "elsewhere")
    with pytest.raises(StoreMismatchError) as info:
        archive_run(elsewhere, replace(run, settings={"outlier_sigma": 4.0}))
    said = str(info.value)
    assert str(tmp_path / "home") in said and str(tmp_path / "elsewhere") in said, said
    assert "CALIB_FILESTORE" in said and "nothing was written" in said
    assert not (tmp_path / "elsewhere").exists()  # not even the folder
    # verify from the wrong folder says why the files are missing, naming both folders
    said = [p.detail for p in verify(elsewhere, orphans=False).problems if p.path == ""]
    assert len(said) == 1 and str(tmp_path / "home") in said[0], said
    assert str(tmp_path / "elsewhere") in said[0]
    second = archive_run(home, replace(run, settings={"outlier_sigma": 4.0}))
    assert second.status == "revised"
    for a in (home, elsewhere):
        a.dispose()


def test_a_folder_of_another_archive_is_not_taken_over(
    postgres_url: str, postgres_server: str, tmp_path: Path
) -> None:
    from conftest import _fresh_pg_database
    from sqlalchemy import text
    from test_seal import behind_the_archive
    from test_verify_backup import fill

    first = Archive(postgres_url, tmp_path / "store")
    first.upgrade()
    fill(first, tmp_path)
    with _fresh_pg_database(postgres_server) as url2:  # another archive, the same folder
        second = Archive(url2, tmp_path / "store")
        second.upgrade()
        with pytest.raises(StoreMismatchError, match="is the file store of another archive"):
            archive_run(second, make_run(tmp_path / "in8", seed=8))
        second.dispose()
    # An archive from before stores were recorded, named with a folder holding none of its
    # runs: refused too (the record is removed as by an older calib that never made one).
    with behind_the_archive(first) as conn:
        conn.execute(
            text("UPDATE audit_events SET detail = '{}' WHERE detail ->> 'file_store' IS NOT NULL")
        )
    empty = tmp_path / "empty"
    empty.mkdir()
    other = Archive(postgres_url, empty)
    with pytest.raises(StoreMismatchError, match="holds runs whose folders are not in"):
        archive_run(other, make_run(tmp_path / "in9", seed=9))
    assert not (empty / MARKER).exists()
    first.dispose()
    other.dispose()


def test_the_cli_names_both_folders(
    postgres_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from typer.testing import CliRunner

    from pipelines.cli import app

    samples = Path(__file__).resolve().parent.parent / "data_samples"
    runner = CliRunner()
    monkeypatch.setenv("CALIB_FILESTORE", str(tmp_path / "home"))
    res = runner.invoke(
        app, ["process", str(samples / "mpu6000_MPU0001"), "--archive", postgres_url]
    )
    assert res.exit_code == 0, res.output
    monkeypatch.delenv("CALIB_FILESTORE")
    monkeypatch.chdir(tmp_path)  # ./calib-archive of another folder
    res = runner.invoke(
        app, ["process", str(samples / "csv_IMU-2026-0042"), "--archive", postgres_url]
    )
    assert res.exit_code != 0
    said = " ".join(res.output.split())
    assert str(tmp_path / "home") in said and str(tmp_path / "calib-archive") in said, said
    assert "Traceback" not in res.output
