"""A large CSV log ingests in memory bounded by its decoded arrays, not by the file's size.

The file holds 14 columns (a lab logger's magnetometer, quaternion, ... next
to the IMU) of which the reader needs 7, so its text is about three times the
decoded arrays (t, acc, gyr: 56 bytes per sample). The read runs in a fresh
child process, which reports the growth of its peak resident memory (VmHWM
after the read minus before it; C allocations of Arrow and pandas count too;
a small read before it starts Arrow's thread pool and allocator, ~20 MB once
per process, which benchmarks/ingest.py counts in its cold measurement):
it must stay within 2x the decoded arrays, which is below the file's size, so
neither the text nor the unused columns are ever held whole. It is measured
with and without the progress bar (which a multi-GB log shows).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv
import pytest

pytestmark = pytest.mark.slow

ROWS = 800_000
DECODED_BYTES = ROWS * 7 * 8

CHILD = r"""
import json, sys
from pathlib import Path

def peak_rss():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024

import rich.progress  # noqa: F401 - module code is not sample memory: load it before measuring
from pipelines.ingest import csv_reader
from pipelines.ingest.data_format import FormatSpec

path, stream = Path(sys.argv[1]), sys.argv[2] == "progress"
fmt = FormatSpec(kind="csv", time_unit="ms", acc_unit="g", gyr_unit="deg/s")  # names recognised
# Warm up on the first 2000 lines: Arrow's thread pool and allocator start once per process.
small = path.with_name(f"head_{sys.argv[2]}.csv")
with path.open() as f:
    small.write_text("".join(next(f) for _ in range(2000)))
csv_reader.read_csv(small, fmt)
before = peak_rss()
rec = csv_reader.read_csv(path, fmt, progress=stream)
after = peak_rss()
print(json.dumps({"growth": after - before, "n": len(rec), "acc_sum": float(rec.acc.sum()),
                  "t_last": float(rec.t[-1])}))
"""


@pytest.fixture(scope="module")
def big_csv(tmp_path_factory) -> tuple[Path, dict]:
    rng = np.random.default_rng(3)
    columns = {"time": np.arange(ROWS, dtype=np.float64)}  # ms at 1 kHz
    for name in ("ax", "ay", "az", "gx", "gy", "gz"):
        columns[name] = np.round(rng.normal(0.0, 1.0, ROWS), 4)
    for name in ("mx", "my", "mz", "qw", "qx", "qy", "qz"):  # not needed by the reader
        columns[name] = np.round(rng.normal(0.0, 1.0, ROWS), 7)
    path = tmp_path_factory.mktemp("large") / "log.csv"
    pyarrow.csv.write_csv(pa.table(columns), path)
    return path, columns


@pytest.mark.parametrize("mode", ["quiet", "progress"])
def test_peak_memory_is_bounded_by_the_decoded_arrays(big_csv, mode: str) -> None:
    path, columns = big_csv
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(path), mode],
        capture_output=True,
        text=True,
        cwd=root,
    )
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["n"] == ROWS and got["t_last"] == (ROWS - 1) * 1e-3
    # The samples made it through (sum of all acc in g -> m/s^2, same addition order
    # up to rounding: 1e-9 relative).
    expected = sum(float(columns[c].sum()) for c in ("ax", "ay", "az")) * 9.80665
    assert got["acc_sum"] == pytest.approx(expected, rel=1e-9, abs=1e-6)
    assert path.stat().st_size > 2 * DECODED_BYTES  # the bound below is below the file size
    print(f"{mode}: peak growth {got['growth'] / DECODED_BYTES:.2f} x decoded arrays")
    assert got["growth"] <= 2 * DECODED_BYTES, (
        f"{mode}: peak memory grew {got['growth'] / 1e6:.0f} MB for "
        f"{DECODED_BYTES / 1e6:.0f} MB of decoded arrays"
    )
