"""A process killed (SIGKILL) while archiving leaves a consistent archive that verifies.

A child process archives runs; the test kills it

- at fixed points, where the child's own wrapper of an archive function writes a flag
  file and sleeps: after the files are written but before the transaction ("files",
  after ``storage.archive._write_files``), and inside the open transaction after every
  row was sent ("commit", after ``storage.seal.seal_calibration``, the last statement);
- at random moments while it archives a stream of runs (several seeds).

Truth: the run is then either wholly in the database (run, calibration,
parameters, raw files) or not at all, `verify` passes (left-over files are
orphans, never problems), and archiving the same run again completes it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import func, select
from test_archive import make_run

from storage.archive import archive_run
from storage.db import Archive
from storage.run_input import raw_hash_of, run_id_of
from storage.schema import Base
from storage.verify import verify

pytestmark = pytest.mark.slow

TESTS = Path(__file__).parent
CHILD = textwrap.dedent(
    """
    import os, sys, time
    from pathlib import Path
    sys.path.insert(0, {tests!r})
    from test_archive import make_run
    from storage import archive as archive_module, seal
    from storage.archive import archive_run
    from storage.db import Archive

    def pause_after(module, name, flag):
        original = getattr(module, name)
        def paused(*args, **kwargs):
            out = original(*args, **kwargs)
            Path(flag).write_text(str(os.getpid()))
            time.sleep(3600)  # the test kills this process here
            return out
        setattr(module, name, paused)

    PAUSE_AT = {{"files": (archive_module, "_write_files"), "commit": (seal, "seal_calibration")}}
    if {pause!r}:
        stage, flag = {pause!r}
        pause_after(*PAUSE_AT[stage], flag)

    archive = Archive({url!r}, Path({root!r}))
    for seed in range({first}, {first} + {count}):
        run = make_run(Path({src!r}) / f"in{{seed}}", serial=f"U{{seed % 3}}", seed=seed)
        archive_run(archive, run, {{"protocol.txt": b"p"}})
        print(seed, flush=True)
    """
)
PAUSE_TIMEOUT_S = 60


def child(archive: Archive, src: Path, first: int, count: int, pause: tuple | None = None):  # noqa: ANN201
    """The archiving child; `pause`: (stage, flag file) where it stops until killed."""
    code = CHILD.format(
        tests=str(TESTS),
        url=archive.url,
        root=str(archive.root),
        src=str(src),
        first=first,
        count=count,
        pause=pause,
    )
    return subprocess.Popen(
        [sys.executable, "-c", code],
        stdout=subprocess.PIPE,
        text=True,
    )


def counts(archive: Archive) -> dict[str, int]:
    with archive.engine().connect() as conn:
        return {
            t.name: conn.execute(select(func.count()).select_from(t)).scalar_one()
            for t in Base.metadata.sorted_tables
        }


def assert_consistent(archive: Archive) -> None:
    """Every run whole (verify's invariants + per-calibration rows), and every file verifies."""
    report = verify(archive)
    assert report.ok, report.problems
    c = counts(archive)
    # make_run: 3 raw files, 1 equipment, 2 steps, 4 parameters, 1 check per revision 1.
    assert (c["raw_files"], c["run_equipment"]) == (3 * c["runs"], c["runs"])
    assert (c["processing_steps"], c["parameters"], c["check_results"]) == (
        2 * c["calibrations"],
        4 * c["calibrations"],
        c["calibrations"],
    )
    assert c["calibrations"] == c["runs"]
    assert c["seals"] == c["audit_events"] == c["calibrations"]  # sealed in the same transaction


@pytest.mark.parametrize("stage", ["files", "commit"])
def test_kill_between_file_writes_and_commit(archive: Archive, tmp_path: Path, stage: str) -> None:
    flag = tmp_path / "paused"
    proc = child(archive, tmp_path / "src", 0, 1, (stage, str(flag)))
    deadline = time.monotonic() + PAUSE_TIMEOUT_S
    while not flag.exists():
        assert proc.poll() is None, "the child ended before reaching the pause point"
        assert time.monotonic() < deadline, "the child never reached the pause point"
        time.sleep(0.05)
    # The files of the run are on disk now; at "commit" its rows are in an open transaction.
    run_id = run_id_of(
        raw_hash_of([f.sha256 for f in make_run(tmp_path / "again", serial="U0", seed=0).raw_files])
    )
    assert list((archive.root / "runs").rglob(run_id))
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    archive.dispose()

    assert set(counts(archive).values()) == {0}  # nothing of the run is in the database
    report = verify(archive)
    assert report.ok
    assert any(run_id in o for o in report.orphans)  # its files are harmless leftovers

    # Archiving the run again completes it; then nothing is orphaned any more but raw objects
    # of nothing (none here: the same bytes are archived).
    res = archive_run(archive, make_run(tmp_path / "again", serial="U0", seed=0), {"p.txt": b"p"})
    assert (res.status, res.run_id) == ("ok", run_id)
    report = verify(archive)
    assert report.ok and report.orphans == []
    assert_consistent(archive)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_kill_at_random_moments(archive: Archive, tmp_path: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    proc = child(archive, tmp_path / "src", 0, 40)
    first = proc.stdout.readline()  # one run archived: the child is in its stream
    assert first.strip(), "the child archived nothing"
    # An archive_run takes ~20-100 ms here: kill at a moment no test code chooses,
    # within the next few runs (file writes, transaction or commit).
    time.sleep(float(rng.uniform(0.0, 0.3)))
    os.kill(proc.pid, signal.SIGKILL)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL, "the child finished before it was killed"
    reported = 1 + len(out.split())
    archive.dispose()
    assert_consistent(archive)
    # Every run the child reported as archived is there (one more may be: killed after commit).
    assert reported <= counts(archive)["runs"] <= reported + 1
    # The stream can be taken up again: the killed run is archived whole.
    for i in range(reported + 1):  # in this process: the same runs as the child's
        run = make_run(tmp_path / "src" / f"in{i}", serial=f"U{i % 3}", seed=i)
        archive_run(archive, run, {"protocol.txt": b"p"})
    assert counts(archive)["runs"] == reported + 1
    assert_consistent(archive)
    # What may be left: a temporary file of a write the kill interrupted (never a live name).
    leftovers = verify(archive).orphans
    assert all(Path(o).name.startswith(".") and o.endswith(".tmp") for o in leftovers), leftovers
