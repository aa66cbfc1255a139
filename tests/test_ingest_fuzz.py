"""Property-based fuzzing of the binary readers: damaged files read or raise IngestError.

Valid small files (MCAP from mcap-ros2-support, MAT v5 from scipy, v7.3 from
hdf5storage) get 500 random byte mutations and truncations each. Each reader
must either return a valid Recording or raise an IngestError naming the file and
the place (byte offset, message, variable) unless the whole file is unreadable;
any other exception type (or a hang: hypothesis would sit on it) fails the test.
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


@functools.cache
def valid_file(kind: str) -> bytes:
    """Bytes of one small valid file of `kind`, made once per session."""
    rng = np.random.default_rng(0)
    n = 60
    data = {"t": 0.01 * np.arange(n), "acc": rng.normal(size=(n, 3)),
            "gyr": rng.normal(size=(n, 3))}  # fmt: skip
    path = _WORKDIR / f"valid_{kind.replace('.', '')}.bin"
    if kind.startswith("mcap"):
        # Uncompressed chunks and, for "mcap_nocrc", no CRCs: mutations then reach the
        # record headers and the CDR payloads instead of stopping at the CRC check.
        write_run(path, n=n, temperature=True, joint_state=True, chunk_size=4096,
                  compression=CompressionType.NONE, enable_crcs=kind == "mcap")  # fmt: skip
    elif kind == "mat5":
        scipy.io.savemat(path, {"imu": data})
    else:
        path = path.with_suffix(".mat")
        hdf5storage.savemat(str(path), {"imu": data}, format="7.3")
    return path.read_bytes()


def read(kind: str, path: Path) -> Recording:
    if kind.startswith("mcap"):
        return read_mcap(path, temperature_topic="/imu/temperature",
                         table_topic="/table/joint_states")  # fmt: skip
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
    if kind == "mcap":  # with CRCs every surviving file must be the original samples
        np.testing.assert_array_equal(rec.acc, read(kind, apply(kind, [], None)).acc)
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
