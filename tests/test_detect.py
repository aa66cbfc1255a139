"""Format detection by content: files from the real writers, and what is not one of them."""

from __future__ import annotations

import h5py
import hdf5storage
import numpy as np
import pytest
import scipy.io
from mcap.writer import Writer

from pipelines.ingest.detect import detect_format
from pipelines.ingest.errors import IngestError


def test_real_writers_are_recognised_whatever_the_suffix(tmp_path):
    data = {"acc": np.zeros((4, 3))}
    mat5 = tmp_path / "run.dat"  # suffixes lie; content decides
    scipy.io.savemat(mat5, data)
    written = tmp_path / "v73.mat"  # hdf5storage insists on the .mat suffix
    hdf5storage.savemat(str(written), data, format="7.3")
    mat73 = written.rename(tmp_path / "run.bin")
    plain_h5 = tmp_path / "run.h5"
    with h5py.File(plain_h5, "w") as f:
        f["acc"] = data["acc"]
    mcap = tmp_path / "run.mat"
    with open(mcap, "wb") as f:
        w = Writer(f)
        w.start()
        w.finish()
    text = tmp_path / "run.mcap"
    text.write_text("t;ax;ay;az\n0;0,1;0,2;9,8\n")
    assert detect_format(mat5) == "mat5"
    assert detect_format(mat73) == "mat73"
    assert detect_format(plain_h5) == "mat73"
    assert detect_format(mcap) == "mcap"
    assert detect_format(text) == "text"


def test_utf8_text_cut_inside_a_character_at_the_probe_end(tmp_path):
    path = tmp_path / "run.txt"
    # 'µ' is 2 bytes in UTF-8: 65535 ASCII bytes put its first byte at the 64 KiB boundary.
    path.write_bytes(b"a" * 65535 + "µs\n".encode())
    assert detect_format(path) == "text"


def _raises(path, match):
    with pytest.raises(IngestError, match=match) as info:
        detect_format(path)
    assert str(path) in str(info.value)


def test_unknown_content_shows_first_bytes(tmp_path):
    path = tmp_path / "run.zip"
    path.write_bytes(b"PK\x03\x04\x14\x00" + bytes(100))
    _raises(path, "unknown file format.*first bytes: 50 4b 03 04 14 00")
    path.write_bytes(b"t,ax\n0,1\n\x00\x00")  # a NUL makes it binary
    _raises(path, "not UTF-8 text")
    path.write_bytes(b"caf\xe9 latin-1\n")  # not UTF-8
    _raises(path, "unknown file format")


def test_empty_and_missing_files(tmp_path):
    path = tmp_path / "empty.csv"
    path.write_bytes(b"")
    _raises(path, "file is empty")
    _raises(tmp_path / "nope.mat", "cannot read file")


def test_damaged_mat_headers(tmp_path):
    good = tmp_path / "good.mat"
    scipy.io.savemat(good, {"x": np.arange(3.0)})
    data = good.read_bytes()
    bad = tmp_path / "bad.mat"
    bad.write_bytes(data[:100])
    _raises(bad, "header is truncated")
    bad.write_bytes(data[:124] + b"\x00\x02IM" + data[128:])
    _raises(bad, "bad version/endian bytes 00 02 49 4d")
    v73 = tmp_path / "v73.mat"
    hdf5storage.savemat(str(v73), {"x": np.arange(3.0)}, format="7.3")
    bad.write_bytes(v73.read_bytes()[:512])
    _raises(bad, "no HDF5 signature at byte 512")
