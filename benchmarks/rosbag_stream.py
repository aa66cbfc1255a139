"""A long static record in a ROS 1 bag through `calib process`, streamed and in memory.

Writes a still unit at 1 kHz as ROS 1 ``sensor_msgs/Imu`` messages (payloads serialised
with numpy in batches, written by rosbags' ROS 1 Writer in its 1 MiB uncompressed chunks)
until the bag holds `--size-gb`, then in child processes (peak resident memory of each
one's process tree sampled every 0.1 s: `longlog.run_child`), `calib process --json` of a
static_bias run of it into a new archive:

- streamed: ``memory_limit_mb`` from `--memory-limit-gb` (below the bag's size), the
  route of `pipelines.ingest.rosbag_reader.stream_rosbag`;
- memory: a limit above the bag's size, the same reader's chunks joined in memory
  (`read_rosbag`) and solved; skipped with `--no-memory`.

The last stdout line is a JSON object: size_gb, messages, and per route seconds,
peak_rss_gb and mb_per_s; max_param_rel_diff, the largest relative difference of a
parameter's value between the routes (scaled by its std where that is larger). The bag is
deleted at the end (`--keep` keeps it).

    .venv/bin/python benchmarks/rosbag_stream.py --size-gb 1.2 --dir /tmp
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from longlog import MANIFEST, RATE, T0_NS, run_child

from calib_testing.calib_command import CALIB
from calib_testing.ros_messages import imu_ros1

BLOCK_ROWS = 250_000  # messages serialised at a time

IMU_ROS1 = imu_ros1(b"imu_link")
BAG_FORMAT = """[format]
kind = "rosbag"
imu_topic = "/imu/data"
"""


def write_bag(path: Path, size_bytes: int, seed: int = 0) -> int:
    """A still unit at 1 kHz until the bag holds `size_bytes`; returns the messages."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    rng = np.random.default_rng(seed)
    step = int(1e9 / RATE)
    rows, walk = 0, np.zeros(3)
    block = np.zeros(BLOCK_ROWS, IMU_ROS1)
    block["frame_len"], block["frame_id"] = 8, b"imu_link"
    block["orientation"][:, 3] = 1.0
    size = IMU_ROS1.itemsize
    store = get_typestore(Stores.ROS1_NOETIC)
    with Writer(path) as w:
        conn = w.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store)
        while path.stat().st_size < size_bytes:
            ns = T0_NS + step * (rows + np.arange(BLOCK_ROWS, dtype=np.int64))
            block["seq"] = rows + np.arange(BLOCK_ROWS)
            block["sec"], block["nsec"] = ns // 1_000_000_000, ns % 1_000_000_000
            steps = rng.normal(0.0, 1e-7, (BLOCK_ROWS, 3))
            block["gyr"] = rng.normal(0.0, 1e-3, (BLOCK_ROWS, 3)) + walk + np.cumsum(steps, 0)
            walk = walk + steps.sum(axis=0)
            block["acc"] = rng.normal(0.0, 0.01, (BLOCK_ROWS, 3)) + [0.0, 0.0, 9.80665]
            data = memoryview(block.tobytes())
            for i, t in enumerate((ns + 250_000).tolist()):  # logged 0.25 ms after the stamp
                w.write(conn, t, data[i * size : (i + 1) * size])
            rows += BLOCK_ROWS
            w.bio.flush()
    return rows


def process(src: Path, work: Path, limit_mb: float) -> tuple[float, float, dict]:
    """(s, peak RSS bytes, run document) of `calib process --json` on a run of `src`."""
    run = work / "run"
    run.mkdir()
    src.rename(run / src.name)
    text = MANIFEST.format(limit_mb=round(limit_mb), data=src.name, format=BAG_FORMAT)
    (run / "run.toml").write_text(text, encoding="utf-8")
    env = {"CALIB_ARCHIVE": str(work / "archive"), "CALIB_ISSUE_CERTIFICATES": "0"}
    try:
        seconds, peak, out = run_child([CALIB, "process", str(run), "--json"], env)
    finally:
        (run / src.name).rename(src)
        shutil.rmtree(run)
    (doc,) = json.loads(out)["runs"]
    if doc["status"] != "ok":
        raise SystemExit(f"calib process failed: {doc['error']}")
    return seconds, peak, doc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size-gb", type=float, default=1.2)
    ap.add_argument("--memory-limit-gb", type=float, default=1.0)
    ap.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()))
    ap.add_argument("--no-memory", action="store_true", help="skip the in-memory route")
    ap.add_argument("--keep", action="store_true")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="rosbag-stream-", dir=args.dir))
    result: dict = {}
    try:
        src = work / "static.bag"
        t0 = time.perf_counter()
        result["messages"] = write_bag(src, int(args.size_gb * 1e9))
        size = src.stat().st_size
        result["size_gb"] = round(size / 1e9, 3)
        result["write_s"] = round(time.perf_counter() - t0, 1)
        limits = {"streamed": args.memory_limit_gb * 1000}
        if not args.no_memory:
            limits["memory"] = 2 * size / 1e6
        docs = {}
        for route, limit_mb in limits.items():
            (work / route).mkdir()
            seconds, peak, docs[route] = process(src, work / route, limit_mb)
            result[route] = {
                "seconds": round(seconds, 1),
                "peak_rss_gb": round(peak / 2**30, 3),
                "mb_per_s": round(size / 1e6 / seconds, 1),
            }
            print(f"{route}: {result[route]}", file=sys.stderr)
        if "memory" in docs:
            mem, got = docs["memory"]["parameters"], docs["streamed"]["parameters"]
            result["max_param_rel_diff"] = max(
                abs(got[k]["value"] - p["value"]) / max(abs(p["value"]), p["std"] or 0.0, 1e-300)
                for k, p in mem.items()
            )
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
