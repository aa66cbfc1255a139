"""Run ids accepted by any unique prefix, as git takes commit ids."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_verify_backup import cli, fill

from storage import queries
from storage.db import Archive
from storage.queries import runs


def test_full_id_unique_prefix_and_the_errors(
    archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ids = fill(archive, tmp_path)
    for run_id in ids:
        assert queries.full_run_id(archive, run_id) == run_id
        # the shortest prefix no other run shares
        shared = [sum(i.startswith(run_id[:k]) for i in ids) for k in range(len(run_id) + 1)]
        n = next(k for k in range(4, len(run_id)) if shared[k] == 1)
        assert queries.full_run_id(archive, run_id[:n]) == run_id
    with pytest.raises(ValueError, match="at least 4 characters"):
        queries.full_run_id(archive, ids[0][:3])
    with pytest.raises(ValueError, match="letters and digits only"):
        queries.full_run_id(archive, ids[0][:5] + "%")
    with pytest.raises(LookupError, match="no run 'Rzzzzzz'"):
        queries.full_run_id(archive, "Rzzzzzz")
    monkeypatch.setattr(runs, "MIN_RUN_ID_PREFIX", 1)
    with pytest.raises(LookupError, match="ambiguous: " + ", ".join(sorted(set(ids)))):
        queries.full_run_id(archive, "R")  # every run id starts with R


@pytest.mark.slow
def test_cli_show_takes_a_cut_run_id(
    archive: Archive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ids = fill(archive, tmp_path)
    res = cli(archive, "show", ids[0][:10], "--json", monkeypatch=monkeypatch)
    assert res.exit_code == 0, res.output
    assert ids[0] in res.stdout
    res = cli(archive, "show", "Rzzzzzz", monkeypatch=monkeypatch)
    assert res.exit_code == 2 and "no run 'Rzzzzzz'" in res.output
