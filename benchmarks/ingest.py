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

The logger routes (PX4 ULog, ArduPilot DataFlash, ROS 2 .db3 and ROS 1 .bag
bags) are timed on `N_LOG` samples written by tests/log_writers.py, each
against a bare read of the same file with the same library (pyulog's ULog
parse of the IMU topics; pymavlink's DFReader_binary matching the IMU records
and taking their fields; rosbags' Reader deserialising every Imu message and
taking its stamp and vectors). These libraries decode message by message in
Python, so `N_LOG` is smaller than `N`.

Peak memory of each of this project's reads is measured in a fresh child process
(resident-set high-water mark after the read minus before it, so C
allocations of zstd, HDF5 and Arrow count too, as does the one-time start of
Arrow's thread pool and allocator, ~20 MB) and divided by the bytes of the
decoded arrays (t, acc, gyr: 56 bytes per sample).

Progress goes to stderr; the last stdout line is one JSON object:
csv_ratio_to_pyarrow, mat_ratio_to_library (the worse of v5 and v7.3; each is
our time over the library's), mcap_msgs_per_s, mcap_speedup_vs_mcap_ros2 (the
library's time over ours), peak_mem_ratio (the worst format), ulog_ratio_to_library,
dataflash_ratio_to_library, rosbag2_ratio_to_library, rosbag1_ratio_to_library
(ours over the bare library read; target <= 1.3).

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
N_LOG = 20_000  # samples of each logger route (100 s at 200 Hz)
LOG_REPEATS = 4
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


CSV_ACC = ["acc_x", "acc_y", "acc_z"]  # the CSV's header after "t"
CSV_GYR = ["gyr_x", "gyr_y", "gyr_z"]


def write_csv(path: Path, data: dict) -> None:
    import pyarrow as pa
    import pyarrow.csv

    columns = {"t": data["t"]}
    columns |= {name: data["acc"][:, i] for i, name in enumerate(CSV_ACC)}
    columns |= {name: data["gyr"][:, i] for i, name in enumerate(CSV_GYR)}
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

    from calib_testing.ros_messages import IMU_MSGDEF, imu_cdr

    dt = imu_cdr(b"imu")
    msgs = np.zeros(N, dt)
    msgs["encapsulation"] = (0, 1, 0, 0)
    msgs["sec"], msgs["nanosec"] = np.divmod(data["stamps_ns"], 1_000_000_000)
    msgs["frame_len"], msgs["frame_id"] = 4, b"imu"
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
    """This project's read of `path`."""
    if kind == "csv":
        from pipelines.ingest.csv_reader import read_csv
        from pipelines.ingest.data_format import FormatSpec

        spec = FormatSpec(kind="csv", time_column="t", acc_columns=CSV_ACC, gyr_columns=CSV_GYR)
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


LOG_ROUTES = ("ulog", "dataflash", "rosbag2", "rosbag1")


def write_log(route: str, folder: Path, data: dict) -> Path:
    """One N_LOG-sample file of a logger route, by tests/log_writers.py."""
    from log_writers import write_dataflash, write_rosbag1, write_rosbag2, write_ulog

    from calib_core.recording import Recording

    rec = Recording(
        t=data["t"][:N_LOG] / 5.0,  # 200 Hz
        acc=data["acc"][:N_LOG],
        gyr=data["gyr"][:N_LOG],
        temp=np.linspace(20.0, 30.0, N_LOG),
    )
    if route == "ulog":
        write_ulog(folder / "run.ulg", rec)
        return folder / "run.ulg"
    if route == "dataflash":
        write_dataflash(folder / "run.bin", rec)
        return folder / "run.bin"
    if route == "rosbag1":
        write_rosbag1(folder / "run.bag", rec)
        return folder / "run.bag"
    return write_rosbag2(folder / "bag2", rec)


def log_reads(route: str, path: Path) -> tuple[Callable[[], object], Callable[[], object]]:
    """(this project's read, the bare library read) of a logger file."""
    if route == "ulog":
        from pyulog import ULog

        from pipelines.ingest.ulog_reader import TOPICS, read_ulog

        return (lambda: read_ulog(path)), (lambda: ULog(str(path), list(TOPICS)))
    if route == "dataflash":
        from pymavlink.DFReader import DFReader_binary

        from pipelines.ingest.dataflash_reader import FIELDS, read_dataflash

        def bare():
            reader = DFReader_binary(str(path), zero_time_base=False)
            rows = []
            while (m := reader.recv_match(type=["IMU"])) is not None:
                rows.append(tuple(getattr(m, f) for f in FIELDS))
            return rows

        return (lambda: read_dataflash(path)), bare
    from pipelines.ingest.rosbag_reader import read_rosbag

    def bare_bag():
        from rosbags.typesys import Stores, get_typestore

        if route == "rosbag1":
            from rosbags.rosbag1 import Reader
        else:
            from rosbags.rosbag2 import Reader
        store = get_typestore(Stores.ROS1_NOETIC if route == "rosbag1" else Stores.ROS2_HUMBLE)
        decode = store.deserialize_ros1 if route == "rosbag1" else store.deserialize_cdr
        rows = []
        with Reader(path) as reader:
            conns = [c for c in reader.connections if c.msgtype == "sensor_msgs/msg/Imu"]
            for conn, _, raw in reader.messages(connections=conns):
                m = decode(raw, conn.msgtype)
                a, w, st = m.linear_acceleration, m.angular_velocity, m.header.stamp
                rows.append((st.sec, st.nanosec, a.x, a.y, a.z, w.x, w.y, w.z))
        return rows

    return (lambda: read_rosbag(path)), bare_bag


def log_ratios(data: dict, folder: Path) -> dict[str, float]:
    """ours / library time of each logger route, best of REPEATS, in the same run."""
    out = {}
    for route in LOG_ROUTES:
        path = write_log(route, folder, data)
        ours_fn, lib_fn = log_reads(route, path)
        rec = ours_fn()
        assert len(rec) == N_LOG, f"{route}: {len(rec)} samples"
        assert np.allclose(rec.acc, data["acc"][:N_LOG], rtol=1e-6, atol=1e-5), route
        # Interleaved, best of LOG_REPEATS each: a busy machine slows both alike.
        t_ours, t_lib = float("inf"), float("inf")
        for _ in range(LOG_REPEATS):
            t_ours = min(t_ours, best_time(ours_fn, 1))
            t_lib = min(t_lib, best_time(lib_fn, 1))
        out[f"{route}_ratio_to_library"] = t_ours / t_lib
        log(
            f"{route:9s} ours {t_ours:6.3f} s  library {t_lib:6.3f} s  ratio {t_ours / t_lib:5.2f}"
            f"  ({N_LOG / t_ours:,.0f} samples/s, {path.stat().st_size / 1e6:.1f} MB)"
        )
    return out


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
        logs = log_ratios(data, folder)
    mcap = results["mcap"]
    figures = {
        "csv_ratio_to_pyarrow": (
            results["csv"]["ours_s"] / results["csv"]["library_s"] if "csv" in results else None
        ),
        "mat_ratio_to_library": max(
            results[k]["ours_s"] / results[k]["library_s"] for k in ("mat5", "mat73")
        ),
        "mcap_msgs_per_s": N / mcap["ours_s"],
        "mcap_speedup_vs_mcap_ros2": mcap["library_s"] / mcap["ours_s"],
        "peak_mem_ratio": max(r["peak_mem_ratio"] for r in results.values()),
        **logs,
    }
    log(f"done in {time.perf_counter() - total:.0f} s")
    print(json.dumps(figures))


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--peak-memory":
        peak_memory_child(sys.argv[2], sys.argv[3])
    else:
        main()
