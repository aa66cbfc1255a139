"""Ingest benchmark: this project's readers against the plain library reads of the same files.

Generates 1M IMU samples in every input format in a temporary folder, then for
each format times this project's reader and the plain library read of the same
file in the same run (best of `REPEATS`, so both see a warm page cache):

- CSV: pipelines.ingest.csv_reader.read_csv vs pyarrow.csv.read_csv
- MAT v5: read_mat vs scipy.io.loadmat; MAT v7.3: read_mat vs h5py reading the datasets
- MCAP: read_mcap vs mcap's reader with mcap-ros2-support's decoder, taking the
  stamp and the two vectors out of each decoded message. That decoder runs at
  ~30k msg/s, so it is timed on the first `ROS2_SUBSET` messages and scaled
  linearly to the whole file (its cost per message is constant).

Peak memory of each of this project's reads is measured in a fresh child process
(resident-set high-water mark after the read minus before it, so C
allocations of zstd, HDF5 and Arrow count too, as does the one-time start of
Arrow's thread pool and allocator, ~20 MB) and divided by the bytes of the
decoded arrays (t, acc, gyr: 56 bytes per sample).

Progress goes to stderr; the last stdout line is one JSON object:
csv_ratio_to_pyarrow, mat_ratio_to_library (the worse of v5 and v7.3; each is
our time over the library's), mcap_msgs_per_s, mcap_speedup_vs_mcap_ros2 (the
library's time over ours), peak_mem_ratio (the worst format).

Run: ``.venv/bin/python benchmarks/ingest.py`` (about a minute on 2 cores).
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

N = 1_000_000
RATE_HZ = 1000.0
REPEATS = 2
ROS2_SUBSET = 100_000
T0_NS = 1_700_000_000_000_000_000
DECODED_BYTES = N * (8 + 3 * 8 + 3 * 8)  # t, acc, gyr as float64
MAT_VARIABLES = {"t": "t", "acc": "acc", "gyr": "gyr"}


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def best_time(fn: Callable[[], object], repeats: int = REPEATS) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


# --- file generation ---------------------------------------------------------------


def simulated() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    stamps_ns = T0_NS + np.arange(N, dtype=np.int64) * int(1e9 / RATE_HZ)
    return {
        "stamps_ns": stamps_ns,
        "t": (stamps_ns - T0_NS) / 1e9,
        "acc": rng.normal(0.0, 9.81, (N, 3)),
        "gyr": rng.normal(0.0, 1.0, (N, 3)),
    }


def write_csv(path: Path, data: dict) -> None:
    import pyarrow as pa
    import pyarrow.csv

    columns = {"t": data["t"]}
    columns |= {f"acc_{c}": data["acc"][:, i] for i, c in enumerate("xyz")}
    columns |= {f"gyr_{c}": data["gyr"][:, i] for i, c in enumerate("xyz")}
    pyarrow.csv.write_csv(pa.table(columns), path)


def write_mat(path5: Path, path73: Path, data: dict) -> None:
    import hdf5storage
    import scipy.io

    arrays = {"t": data["t"], "acc": data["acc"], "gyr": data["gyr"]}
    scipy.io.savemat(path5, arrays)
    hdf5storage.savemat(str(path73), arrays, format="7.3", matlab_compatible=True)


def write_mcap(path: Path, data: dict) -> None:
    """sensor_msgs/msg/Imu in little-endian CDR, packed with a numpy structured array.

    The layout (checked against mcap-ros2-support's decoder by the baseline below):
    encapsulation 00 01 00 00, stamp, frame_id "imu\\0", then 37 doubles aligned to 8.
    """
    from mcap.writer import Writer
    from test_ingest_mcap import IMU_MSGDEF

    dt = np.dtype(
        [("encap", "u1", 4), ("sec", "<i4"), ("nanosec", "<u4"), ("len", "<u4"),
         ("frame", "S4"), ("orientation", "<f8", 4), ("oc", "<f8", 9),
         ("gyr", "<f8", 3), ("gc", "<f8", 9), ("acc", "<f8", 3), ("ac", "<f8", 9)]
    )  # fmt: skip
    msgs = np.zeros(N, dt)
    msgs["encap"] = (0, 1, 0, 0)
    msgs["sec"], msgs["nanosec"] = np.divmod(data["stamps_ns"], 1_000_000_000)
    msgs["len"], msgs["frame"] = 4, b"imu"
    msgs["orientation"][:, 3] = 1.0
    msgs["gyr"], msgs["acc"] = data["gyr"], data["acc"]
    raw = msgs.tobytes()
    size = dt.itemsize
    log_ns = data["stamps_ns"].tolist()
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="benchmarks/ingest.py")
        sid = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", IMU_MSGDEF.encode())
        cid = w.register_channel("/imu/data", "cdr", sid)
        for i in range(N):
            w.add_message(cid, log_ns[i], raw[i * size : (i + 1) * size], log_ns[i])
        w.finish()


# --- the reads -------------------------------------------------------------------------


def ours(kind: str, path: Path):
    """This project's read of `path`; None for CSV if its reader is not there yet."""
    if kind == "csv":
        try:
            from pipelines.ingest.csv_reader import read_csv
            from pipelines.ingest.manifest import FormatSpec
        except ImportError:
            return None
        spec = FormatSpec(
            kind="csv",
            time_column="t",
            acc_columns=["acc_x", "acc_y", "acc_z"],
            gyr_columns=["gyr_x", "gyr_y", "gyr_z"],
        )
        return lambda: read_csv(path, spec)
    if kind in ("mat5", "mat73"):
        from pipelines.ingest.matlab import read_mat

        return lambda: read_mat(path, variables=MAT_VARIABLES)
    from pipelines.ingest.mcap_reader import read_mcap

    return lambda: read_mcap(path)


def library(kind: str, path: Path) -> Callable[[], object]:
    if kind == "csv":
        import pyarrow.csv

        return lambda: pyarrow.csv.read_csv(path)
    if kind == "mat5":
        import scipy.io

        return lambda: scipy.io.loadmat(path)
    if kind == "mat73":
        import h5py

        def load():
            with h5py.File(path, "r") as f:
                return {key: f[key][()] for key in MAT_VARIABLES}

        return load
    raise ValueError(kind)


def mcap_ros2_per_message(path: Path, data: dict) -> float:
    """Seconds per message of mcap + mcap-ros2-support on the first ROS2_SUBSET messages."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    def run():
        out = []
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, _, _, msg in reader.iter_decoded_messages():
                a, w, s = msg.linear_acceleration, msg.angular_velocity, msg.header.stamp
                out.append((s.sec, s.nanosec, a.x, a.y, a.z, w.x, w.y, w.z))
                if len(out) == ROS2_SUBSET:
                    break
        return out

    start = time.perf_counter()
    rows = run()
    elapsed = time.perf_counter() - start
    # guard the comparison: the library decodes the same numbers from the same bytes
    got = np.array(rows)
    assert np.array_equal(got[:, 2:5], data["acc"][:ROS2_SUBSET]), "baseline decoded other data"
    return elapsed / ROS2_SUBSET


def peak_rss() -> int:
    """Peak resident memory of this process, bytes.

    VmHWM, not getrusage's ru_maxrss: after fork + exec the child's ru_maxrss
    starts from the parent's, which here holds all the generated data.
    """
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # not Linux: best effort


def peak_memory_child(kind: str, path: str) -> None:
    """In a child process: print the peak RSS growth (bytes) of this project's read."""
    fn = ours(kind, Path(path))
    before = peak_rss()
    rec = fn()
    after = peak_rss()
    assert len(rec) == N
    print(after - before)


def peak_memory(kind: str, path: Path) -> float:
    out = subprocess.run(
        [sys.executable, __file__, "--peak-memory", kind, str(path)],
        capture_output=True,
        text=True,
        check=True,
    )
    return int(out.stdout.strip().splitlines()[-1]) / DECODED_BYTES


def main() -> None:
    total = time.perf_counter()
    data = simulated()
    results: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(prefix="ingest_bench_") as tmp:
        folder = Path(tmp)
        paths = {
            "csv": folder / "run.csv",
            "mat5": folder / "run_v5.mat",
            "mat73": folder / "run_v73.mat",
            "mcap": folder / "run.mcap",
        }
        log(f"writing {N} samples per format to {folder} ...")
        write_csv(paths["csv"], data)
        write_mat(paths["mat5"], paths["mat73"], data)
        start = time.perf_counter()
        write_mcap(paths["mcap"], data)
        log(f"  mcap written in {time.perf_counter() - start:.1f} s")
        for kind, path in paths.items():
            fn = ours(kind, path)
            if fn is None:
                log(f"{kind}: skipped (pipelines.ingest.csv_reader not available)")
                continue
            rec = fn()
            assert np.array_equal(rec.acc, data["acc"]), f"{kind}: samples differ"
            t_ours = best_time(fn)
            if kind == "mcap":
                t_lib = mcap_ros2_per_message(path, data) * N
            else:
                t_lib = best_time(library(kind, path))
            mem = peak_memory(kind, path)
            results[kind] = {"ours_s": t_ours, "library_s": t_lib, "peak_mem_ratio": mem}
            log(
                f"{kind:6s} ours {t_ours:6.3f} s ({N / t_ours / 1e6:5.2f} M samples/s)  "
                f"library {t_lib:7.3f} s  ratio ours/library {t_ours / t_lib:5.2f}  "
                f"peak memory {mem:4.2f} x decoded arrays  ({path.stat().st_size / 1e6:.0f} MB)"
            )
    mcap = results["mcap"]
    figures = {
        "csv_ratio_to_pyarrow": (
            results["csv"]["ours_s"] / results["csv"]["library_s"] if "csv" in results else None
        ),
        "mat_ratio_to_library": max(
            results[k]["ours_s"] / results[k]["library_s"] for k in ("mat5", "mat73")
        ),  # fmt: skip
        "mcap_msgs_per_s": N / mcap["ours_s"],
        "mcap_speedup_vs_mcap_ros2": mcap["library_s"] / mcap["ours_s"],
        "peak_mem_ratio": max(r["peak_mem_ratio"] for r in results.values()),
    }
    log(f"done in {time.perf_counter() - total:.0f} s")
    print(json.dumps(figures))


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--peak-memory":
        peak_memory_child(sys.argv[2], sys.argv[3])
    else:
        main()
