"""Property-based fuzzing of the binary readers: damaged files read or raise IngestError.

Valid small files (MCAP from mcap-ros2-support, MAT v5 from scipy, v7.3 from
hdf5storage) get 500 random byte mutations and truncations each. Each reader
must either return a valid Recording or raise an IngestError naming the file and
the place (byte offset, message, variable) unless the whole file is unreadable;
any other exception type (or a hang: hypothesis would sit on it) fails the test.

Then whole runs (a copy of the sample CSV run with run.toml or its data file
mutated, and the inputs that once escaped: a 1M-character field, run.toml nested
1000 deep, a million-digit integer, a 300-digit rate, a segment whose means have
no scatter) go through `process_run`: none may end as an internal error, every
refusal names the run's folder and the file (and line or segment) it is about.
"""

from __future__ import annotations

import atexit
import functools
import shutil
import tempfile
from pathlib import Path

import hdf5storage
import numpy as np
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType
from test_ingest_mcap import write_run
from test_reader_fuzz import assert_names_the_place

from calib_core.recording import Recording
from pipelines.ingest.detect import detect_format
from pipelines.ingest.errors import IngestError
from pipelines.ingest.matlab import read_mat
from pipelines.ingest.mcap_reader import read_mcap

pytestmark = pytest.mark.slow

FUZZ = settings(
    max_examples=500,  # at least 500 mutated inputs per reader
    deadline=None,
    derandomize=True,  # reproducible in CI; a new seed is a code change
    database=None,  # no .hypothesis folder in the repository
    suppress_health_check=[HealthCheck.too_slow],
)
_WORKDIR = Path(tempfile.mkdtemp(prefix="fuzz_ingest_"))
atexit.register(shutil.rmtree, _WORKDIR, ignore_errors=True)


def write_valid(path: Path, kind: str, **mcap) -> Path:
    """One small valid file of `kind` at `path`: "mcap..." (written with `mcap`, the MCAP
    writer's options), "mat5" (MAT v5) or else MAT v7.3; returns `path`."""
    rng = np.random.default_rng(0)
    n = 60
    data = {
        "t": 0.01 * np.arange(n),
        "acc": rng.normal(size=(n, 3)),
        "gyr": rng.normal(size=(n, 3)),
    }
    if kind.startswith("mcap"):
        write_run(path, n=n, temperature=True, joint_state=True, **mcap)
    elif kind == "mat5":
        scipy.io.savemat(path, {"imu": data})
    else:
        hdf5storage.savemat(str(path), {"imu": data}, format="7.3")
    return path


@functools.cache
def valid_file(kind: str) -> bytes:
    """Bytes of one small valid file of `kind`, made once per session."""
    path = _WORKDIR / f"valid_{kind.replace('.', '')}.bin"
    if not kind.startswith("mcap") and kind != "mat5":
        path = path.with_suffix(".mat")
    # Uncompressed chunks and, for "mcap_nocrc", no CRCs: mutations then reach the
    # record headers and the CDR payloads instead of stopping at the CRC check.
    mcap = {"chunk_size": 4096, "compression": CompressionType.NONE, "enable_crcs": kind == "mcap"}
    return write_valid(path, kind, **mcap).read_bytes()


def read(kind: str, path: Path) -> Recording:
    if kind.startswith("mcap"):
        return read_mcap(
            path, temperature_topic="/imu/temperature", table_topic="/table/joint_states"
        )
    return read_mat(path, variables={"t": "imu.t", "acc": "imu.acc", "gyr": "imu.gyr"})


def mutated(kind: str):
    """A strategy: the valid file with up to 8 bytes replaced and possibly truncated."""
    size = len(valid_file(kind))
    edits = st.lists(st.tuples(st.integers(0, size - 1), st.integers(0, 255)), max_size=8)
    cut = st.one_of(st.none(), st.integers(0, size - 1))
    return st.tuples(edits, cut)


def apply(kind: str, edits, cut) -> Path:
    data = bytearray(valid_file(kind))
    for pos, value in edits:
        data[pos] = value
    if cut is not None:
        del data[cut:]
    path = _WORKDIR / f"case_{kind}.bin"
    path.write_bytes(bytes(data))
    return path


def check(kind: str, edits, cut) -> None:
    path = apply(kind, edits, cut)
    try:
        fmt = detect_format(path)
        rec = read(kind, path)
    except IngestError as exc:
        assert_names_the_place(exc, path)
        return
    assert fmt in ("mcap", "mat5", "mat73")
    if kind == "mcap":  # with CRCs every surviving file is the original samples, or
        full = read(kind, apply(kind, [], None)).acc  # a cut file read to its last whole
        if rec.findings:  # record: a prefix of them, with the finding naming the cut
            assert [f["name"] for f in rec.findings] == [f"record:cut:{path.name}"]
            np.testing.assert_array_equal(rec.acc, full[: len(rec)])
        else:
            np.testing.assert_array_equal(rec.acc, full)
    assert isinstance(rec, Recording) and len(rec) > 0
    assert np.isfinite(rec.acc).all() and np.all(np.diff(rec.t) > 0)


@pytest.mark.parametrize("kind", ["mcap", "mcap_nocrc", "mat5", "mat73"])
def test_valid_files_read(kind):
    rec = read(kind, apply(kind, [], None))
    assert len(rec) == 60


@pytest.mark.parametrize("kind", ["mcap", "mcap_nocrc", "mat5", "mat73"])
@FUZZ
@given(data=st.data())
def test_mutations(kind: str, data: st.DataObject) -> None:
    check(kind, *data.draw(mutated(kind), label="case"))


@FUZZ
@given(st.binary(max_size=2048))
def test_random_bytes(data):
    path = _WORKDIR / "random.bin"
    path.write_bytes(data)
    for reader in (detect_format, lambda p: read("mcap", p), lambda p: read("mat5", p)):
        try:
            reader(path)
        except IngestError as exc:
            assert str(path) in str(exc)


# --- Whole runs: inputs that once escaped as internal errors or named no file -------------

CSV_RUN = Path(__file__).resolve().parents[1] / "data_samples" / "csv_IMU-2026-0042"


def _edit_csv_field(row: int, column: int, value: str):
    def edit(folder: Path) -> None:
        path = folder / "imu.csv"
        lines = path.read_text().splitlines()
        fields = lines[row].split(",")
        fields[column] = value
        lines[row] = ",".join(fields)
        path.write_text("\n".join(lines) + "\n")

    return edit


def _edit_toml(old: str, new: str):
    def edit(folder: Path) -> None:
        path = folder / "run.toml"
        assert old in path.read_text()
        path.write_text(path.read_text().replace(old, new, 1))

    return edit


def _constant_segment(folder: Path) -> None:
    """Every row of x_up (0 .. 21.98 s) the same: its means have no scatter (the solver's
    refusal names no file of its own)."""
    path = folder / "imu.csv"
    lines = path.read_text().splitlines()
    for i in range(2, 1100):
        t = lines[i].split(",")[0]
        lines[i] = ",".join([t, *lines[1].split(",")[1:]])
    path.write_text("\n".join(lines) + "\n")


# name -> (edit of a copy of the sample CSV run, the file and the place the refusal must
# name; for run.toml the text starting the line it must name)
RUN_CASES = {
    "1M-character number": (_edit_csv_field(5, 1, "1" * 1_000_000), "imu.csv", "line 6"),
    "1M-character word": (_edit_csv_field(5, 2, "x" * 1_000_000), "imu.csv", "line 6"),
    # refused at read, beyond what any IMU measures: the field and sample (data line 6)
    "300-digit gyro rate": (_edit_csv_field(5, 4, "9" * 300), "imu.csv", "field 'gyr': sample 4"),
    "toml nested 1000 deep": (
        _edit_toml("gyro_range_dps = 2000.0", "deep = " + "[" * 1000 + "]" * 1000),
        "run.toml",
        "deep =",
    ),
    "million-digit integer": (
        _edit_toml("humidity_pct = 46.0", "humidity_pct = " + "9" * 1_000_000),
        "run.toml",
        "humidity_pct =",
    ),
    "segment without scatter": (_constant_segment, "", ""),
}


@pytest.fixture(scope="module")
def fuzz_archive(tmp_path_factory):
    from storage.db import resolve_archive

    archive = resolve_archive(str(tmp_path_factory.mktemp("fuzz_archive") / "archive"))
    archive.upgrade()
    yield archive
    archive.dispose()


@pytest.mark.parametrize("case", list(RUN_CASES))
def test_fuzzed_run_is_a_clean_refusal_naming_the_file(case, tmp_path, fuzz_archive) -> None:
    """Refused, never an internal error; the refusal names the file and the line or
    segment, and quotes no value in full (a message stays short)."""
    from pipelines.ingest import discover_runs
    from pipelines.process import process_run

    edit, name, place = RUN_CASES[case]
    folder = tmp_path / "run"
    shutil.copytree(CSV_RUN, folder)
    edit(folder)
    (source,) = discover_runs([folder])
    outcome = process_run(source, fuzz_archive)
    error = outcome["error"] or ""
    if name == "run.toml":  # the refusal names file and line: "<file> line <n>: ..."
        lines = (folder / name).read_text().splitlines()
        place = f"line {next(i for i, s in enumerate(lines, 1) if s.startswith(place))}:"
    assert outcome["status"] == "failed", case
    assert "internal error" not in error, error[:500]
    assert error.startswith(str(folder / name) if name else f"{folder}:"), error[:500]
    assert place in error, error[:500]
    assert len(error) < 600, error[:700]


def test_segment_without_scatter_is_refused_before_any_uncertainty(tmp_path, fuzz_archive):
    """The constant segment is refused by name before a standard uncertainty is taken:
    no RuntimeWarning (a NaN from a square root or a division) on the way."""
    import warnings

    from pipelines.ingest import discover_runs
    from pipelines.process import process_run

    folder = tmp_path / "run"
    shutil.copytree(CSV_RUN, folder)
    _constant_segment(folder)
    (source,) = discover_runs([folder])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        outcome = process_run(source, fuzz_archive)
    assert outcome["status"] == "failed"
    assert outcome["error"].startswith(f"{folder}: segment x_up, accelerometer x: ")
    assert "show no scatter" in outcome["error"], outcome["error"]


def test_refusal_texts_name_the_run_and_stay_short() -> None:
    from pipelines.ingest.errors import naming_the_run

    solver = ValueError("every standard uncertainty of a position mean must be > 0")
    assert naming_the_run(solver, "/lab/run7") == f"/lab/run7: {solver}"
    named = IngestError("expected a finite number", file="/lab/run7/imu.csv", line=3)
    assert naming_the_run(named, "/lab/run7") == str(named)
    huge = IngestError(f"gyro x reads {'9' * 300}.000 deg/s", file="f.csv")
    assert huge.problem == "gyro x reads 1e+300 deg/s"
    word = IngestError(f"unknown unit {'x' * 10**6}", file="f.csv")
    assert word.problem.endswith("... (1000000 characters)") and len(word.problem) < 120


RUN_BREAKERS = [
    "",
    ",",
    "nan",
    "1e400",
    "[",
    "]]]",
    "=",
    '"',
    "\x00",
    "9" * 300,
    "x" * 100_000,
    "[" * 1000,
    "9" * 5000,
    "-",
    "\n",
]


@pytest.mark.slow
@settings(
    max_examples=100,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(
    file=st.sampled_from(["run.toml", "imu.csv"]),
    edits=st.lists(
        st.tuples(st.floats(0.0, 1.0), st.sampled_from(RUN_BREAKERS)), min_size=1, max_size=3
    ),
)
def test_fuzzed_runs_end_as_outcomes_naming_the_run(fuzz_archive, file, edits) -> None:
    """Whole runs with run.toml or the data file mutated (breakers, a 100k-character word,
    nesting 1000 deep, a 5000-digit integer): every run ends ok or refused; a refusal is
    never an internal error, names the run's folder (and the file when it is the file's),
    and stays short."""
    from pipelines.ingest import discover_runs
    from pipelines.process import process_run

    folder = _WORKDIR / "fuzzed_run"
    shutil.rmtree(folder, ignore_errors=True)
    shutil.copytree(CSV_RUN, folder)
    path = folder / file
    text = path.read_text()
    for where, value in sorted(edits, reverse=True):
        pos = int(where * (len(text) - 1))
        text = text[:pos] + value + text[pos + 1 :]
    path.write_text(text)
    (source,) = discover_runs([folder])
    outcome = process_run(source, fuzz_archive)
    error = outcome["error"] or ""
    assert outcome["status"] in ("ok", "failed", "duplicate"), outcome
    assert "internal error" not in error, error[:500]
    assert outcome["status"] != "failed" or error.startswith(str(folder)), error[:500]
    assert len(error) < 2000, error[:700]
