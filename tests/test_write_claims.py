"""No write claims success it did not have (`calib impact --apply`, `approve`, `reprocess`).

Known truth: rate-table runs whose table read RATE_PPM fast (tests/test_impact.py),
archived by the real pipeline. The archive is made read-only in a way root cannot
bypass: the SQLite file opened with ``mode=ro`` (a URI), PostgreSQL as the reader
role; each writing command must exit non-zero naming what it did not write, and the
archive must hold what it held before.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from sqlalchemy.engine import make_url
from test_impact import RATE_PPM, apply_rate_error, archive_rate_table_runs
from test_trust import _approvers, _key
from typer.testing import CliRunner

from pipelines.cli import app
from pipelines.reprocess import changed_pairs, plan_reprocess, reprocess_in_process
from storage import queries
from storage.db import Archive, resolve_archive
from storage.roles import READER, apply_roles

PASS = "correct horse battery"
IMPACT = ["impact", "RT-7", "--from", "2026-03-01", "--to", "2026-03-31"]
IMPACT += ["--error", f"rate_error_ppm={RATE_PPM}", "--apply"]


def _read_only_sqlite(arch: Archive) -> str:
    """The archive's SQLite file as a read-only URI (SQLite refuses every write, also root's)."""
    return f"sqlite:///file:{make_url(arch.url).database}?mode=ro&uri=true"


def _cli(args: list[str], root: Path, monkeypatch: pytest.MonkeyPatch):  # noqa: ANN202
    monkeypatch.setenv("CALIB_FILESTORE", str(root))
    monkeypatch.setenv("CALIB_KEY_PASSPHRASE", PASS)
    return CliRunner().invoke(app, args)


@pytest.fixture(scope="module")
def rate_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Archive, dict[str, str]]:
    tmp = tmp_path_factory.mktemp("claims")
    arch = resolve_archive(str(tmp / "archive"))
    arch.upgrade()
    return arch, archive_rate_table_runs(arch, tmp, "ABC")


def _revisions(arch: Archive, run_id: str) -> int:
    return queries.run_summary(arch, run_id).calibration.revision


def test_impact_apply_on_a_read_only_sqlite_archive_names_the_runs_not_written(
    rate_runs, monkeypatch: pytest.MonkeyPatch
) -> None:
    arch, runs = rate_runs
    res = _cli([*IMPACT, "--archive", _read_only_sqlite(arch)], arch.root, monkeypatch)
    assert res.exit_code == 1, res.output
    assert f"not written: {runs['A']}" in res.output
    assert "NOT written" in res.output and "revisions archived" not in res.output
    assert "read-only" in res.output  # the run's error says why
    assert _revisions(arch, runs["A"]) == 1  # nothing archived
    as_json = _cli(
        [*IMPACT, "--json", "--archive", _read_only_sqlite(arch)], arch.root, monkeypatch
    )
    assert as_json.exit_code == 1
    assert json.loads(as_json.stdout)["not_written"] == [runs["A"]]


@pytest.mark.postgres
def test_impact_apply_as_the_reader_role_names_the_runs_not_written(
    postgres_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    arch = Archive(postgres_url, tmp_path / "store")
    arch.upgrade()
    apply_roles(arch)
    runs = archive_rate_table_runs(arch, tmp_path, "A")
    reader = make_url(postgres_url).set(username=READER).render_as_string(hide_password=False)
    res = _cli([*IMPACT, "--archive", reader], arch.root, monkeypatch)
    assert res.exit_code == 1, res.output
    assert f"not written: {runs['A']}" in res.output
    assert "refused the write" in res.output
    assert _revisions(arch, runs["A"]) == 1
    arch.dispose()


def test_approve_refuses_a_key_outside_the_approvers_file_and_a_failed_write(
    rate_runs, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    arch, runs = rate_runs
    jane = _key(tmp_path / "keys", "jane.key", "Jane Approver")
    mallory = _key(tmp_path / "keys", "mallory.key", "Jane Approver")  # a key in her name
    trusted = _approvers(tmp_path, jane.with_name("jane.key.pub"))
    sign = ["approve", runs["B"], "--approvers", str(trusted), "--archive", str(arch.root)]
    res = _cli([*sign, "--key", str(mallory)], arch.root, monkeypatch)
    assert res.exit_code == 2 and f"is not in the approvers file {trusted}" in res.output
    assert queries.audit_trail(arch)[-1]["action"] != "approved"  # nothing signed
    read_only = [*sign[:-1], _read_only_sqlite(arch), "--key", str(jane)]
    res = _cli(read_only, arch.root, monkeypatch)
    assert res.exit_code == 2 and f"run {runs['B']}: not signed" in res.output, res.output
    res = _cli([*sign, "--key", str(jane)], arch.root, monkeypatch)  # writable: signed
    assert res.exit_code == 0, res.output


def test_reprocess_on_a_read_only_archive_names_the_run_not_written(
    rate_runs, monkeypatch: pytest.MonkeyPatch
) -> None:
    from pipelines import process

    arch, runs = rate_runs
    monkeypatch.setattr(process, "SOFTWARE_VERSION", "99.0-claims")  # a revision is due
    args = ["reprocess", runs["C"], "--reason", "new solver", "--json"]
    res = _cli([*args, "--archive", _read_only_sqlite(arch)], arch.root, monkeypatch)
    assert res.exit_code == 1, res.output
    assert f"not written: {runs['C']}" in res.output
    doc = json.loads(res.stdout)
    assert doc["summary"]["failed"] == 1 and doc["changes"]["runs"] == 0
    assert _revisions(arch, runs["C"]) == 1


def test_the_change_report_of_a_reprocessing_lists_only_what_it_revised(rate_runs) -> None:
    """After `impact --apply` revised run A, a reprocessing that revises nothing reports no
    change (before: A's impact revision was listed as the reprocessing's)."""
    arch, runs = rate_runs
    if _revisions(arch, runs["A"]) == 1:
        assert apply_rate_error(arch)["runs"][0]["status"] == "revised"
    todo, skipped = plan_reprocess(arch, {})
    outcomes = reprocess_in_process(arch, todo, skipped, "nothing new")
    assert {o["status"] for o in outcomes} == {"duplicate"}, outcomes
    assert changed_pairs(arch, outcomes, "nothing new") == []


def test_a_checkpoint_that_cannot_be_written_leaves_no_file(
    rate_runs, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A full file system (a small tmpfs, filled; mounting needs root, else skipped): exit 2
    naming the file, and no empty checkpoint left to be taken for one."""
    from test_disk_readonly import fill, tmpfs

    arch, _ = rate_runs
    with tmpfs(tmp_path / "full", 64) as disk:
        fill(disk, 0)
        out = disk / "head.json"
        res = _cli(
            ["checkpoint", "-o", str(out), "--archive", str(arch.root)], arch.root, monkeypatch
        )
        assert res.exit_code == 2 and f"{out}: cannot be written" in res.output, res.output
        assert not out.exists()
        (disk / "filler").unlink()
        res = _cli(
            ["checkpoint", "-o", str(out), "--archive", str(arch.root)], arch.root, monkeypatch
        )
        assert res.exit_code == 0 and out.is_file(), res.output
