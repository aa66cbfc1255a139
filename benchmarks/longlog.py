"""A long static record (several GB of 1 kHz CSV) through the streamed static-bias route.

Writes a static record of `--size-gb` of CSV (1 kHz, time in s, six channels in SI with
7 decimals, as loggers print them) under `--dir`, then in child processes (each one's
peak resident memory, threads and descendants included, sampled every 0.1 s):

- process: `calib process --json` of a static_bias run of the record (its run.toml sets
  ``memory_limit_mb`` from `--memory-limit-gb`) into a new archive: the streamed route
  (`pipelines.process_streamed`: one pass that hashes, copies and parses the file into the
  samples' Parquet, then the solve, conditions and archive from the Parquet);
- floor: one pass that reads, hashes and copies the file and writes the samples' Parquet
  with the same libraries (pyarrow's CSV parser, the archive's Parquet options), nothing
  else.

With `--formats csv,mcap` (the default) the same for a ROS 2 MCAP log of `--size-gb`
(``sensor_msgs/msg/Imu`` at 1 kHz, CDR payloads serialised with numpy in batches, written
by mcap's Writer in uncompressed 4 MiB chunks):
process is `calib process --json` of a run folder whose run.toml says ``[format] kind =
"mcap"`` (the streamed route through `pipelines.ingest.mcap_reader.stream_mcap`); floor reads,
hashes and copies the file, decodes its messages with the same vectorised CDR decoder and
writes the Parquet, nothing else (no checks, no statistics).

Before the runs, the compiled loops (the Allan sums of `calib_core.second_differences`,
the n-sigma scan of `calib_core.sigma_rule`,
the motion windows of `calib_core.preprocess.motion_windows`; Numba) are compiled into
their cache, as the first use after installing does once; the runs load them from it
(the seconds it took are printed).

And the streamed Allan deviation of a 10-million-sample subset (gyro x of the record)
against allantools' `oadev` (relative error, max over the octave taus both give).

The last stdout line is a JSON object: per format (``"csv"``, ``"mcap"``) size_gb,
samples, peak_rss_gb (the process), floor_peak_rss_gb, process_mb_per_s, floor_mb_per_s,
process_to_floor_ratio and seconds of each part; the CSV figures also at the top level;
allan_rel_err_vs_allantools. Targets (each format): size_gb >= 4,
peak_rss_gb <= 1.5, process_to_floor_ratio <= 1.5, allan_rel_err_vs_allantools <= 1e-9.
The files are deleted at the end (`--keep` keeps them).

    .venv/bin/python benchmarks/longlog.py --size-gb 4 --dir /tmp [--formats mcap]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
import psutil
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from calib_core.preprocess.motion import window_statistics
from calib_core.streamed import StreamedAllan, load_compiled

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from calib_testing.calib_command import CALIB  # noqa: E402
from calib_testing.ros_messages import IMU_MSGDEF, imu_cdr  # noqa: E402

RATE = 1000.0
BLOCK_ROWS = 1_000_000

MANIFEST = """schema_version = 1

[unit]
serial = "LONG-0001"
model = "LongLog"
manufacturer = "Bench"

[run]
started = "2026-11-01T00:00:00+00:00"
operator = "longlog.py"
procedure = "static_bias"
tolerance_profile = "mpu6000"

[run.settings]
up_axis = "+z"
memory_limit_mb = {limit_mb}

{format}
[[segments]]
label = "record"
file = "{data}"
"""

CSV_FORMAT = """[format]
kind = "csv"
time_column = "time"
acc_columns = ["acc_x", "acc_y", "acc_z"]
gyr_columns = ["gyr_x", "gyr_y", "gyr_z"]
"""

MCAP_FORMAT = """[format]
kind = "mcap"
imu_topic = "/imu/data"
"""

FLOOR = """
import hashlib, sys
from pathlib import Path
import pyarrow as pa, pyarrow.csv as pacsv, pyarrow.parquet as pq
from pipelines.ingest.csv_reader import blocks
from pipelines.ingest.streamed_pass import block_bytes
from storage.rawstore import samples_parquet_options
src, work, limit = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
convert = pacsv.ConvertOptions(column_types={c: pa.float64() for c in
    ["time", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]})
names = ["time", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]
read = pacsv.ReadOptions(column_names=names)
schema = pa.schema([(c, pa.float64()) for c in names])
sha = hashlib.sha256()
with src.open("rb") as fh, (work / "raw").open("wb") as copy, pq.ParquetWriter(
        work / "samples.parquet", schema, **samples_parquet_options(schema)) as w:
    sha.update(fh.readline())
    for text in blocks(fh, block_bytes(limit), copy, sha):
        w.write_table(pacsv.read_csv(pa.py_buffer(text), read, convert_options=convert))
print(sha.hexdigest())
"""


def write_record(path: Path, size_bytes: int, seed: int = 0) -> int:
    """A still unit at 1 kHz until the file holds `size_bytes`; returns the samples written."""
    rng = np.random.default_rng(seed)
    rows, walk = 0, np.zeros(3)
    with path.open("wb") as fh:
        fh.write(b"time,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n")
        while fh.tell() < size_bytes:
            t = (rows + np.arange(BLOCK_ROWS)) / RATE
            steps = rng.normal(0.0, 1e-7, (BLOCK_ROWS, 3))
            gyr = rng.normal(0.0, 1e-3, (BLOCK_ROWS, 3)) + walk + np.cumsum(steps, axis=0)
            walk = walk + steps.sum(axis=0)
            acc = rng.normal(0.0, 0.01, (BLOCK_ROWS, 3)) + [0.0, 0.0, 9.80665]
            cols = {"time": pc.round(pa.array(t), 3)}
            for i, a in enumerate("xyz"):
                cols[f"acc_{a}"] = pc.round(pa.array(acc[:, i]), 7)
            for i, a in enumerate("xyz"):
                cols[f"gyr_{a}"] = pc.round(pa.array(gyr[:, i]), 7)
            buf = pa.BufferOutputStream()
            pacsv.write_csv(pa.table(cols), buf, pacsv.WriteOptions(include_header=False))
            fh.write(buf.getvalue().to_pybytes())
            rows += BLOCK_ROWS
    return rows


def count_rows(path: Path) -> int:
    """The data rows of a record `write_record` wrote (its lines but the header)."""
    lines = 0
    with path.open("rb") as fh:
        while block := fh.read(64 << 20):
            lines += block.count(b"\n")
    return lines - 1


def run_child(argv: list[str], env: dict[str, str] | None = None) -> tuple[float, float, str]:
    """(wall s, peak RSS of the child and its descendants in bytes, stdout) of one child.

    The file system's dirty pages are written out first (`os.sync`), so no child pays for
    the write-back of the one before it (the floor writes GBs it never flushes)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DO_NOT_TRACK": "1", **(env or {})}
    os.sync()
    started = time.perf_counter()
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, text=True)
    peak, ps = 0, psutil.Process(proc.pid)
    while proc.poll() is None:
        try:
            tree = [ps, *ps.children(recursive=True)]
            peak = max(peak, sum(p.memory_info().rss for p in tree))
        except psutil.Error:
            pass
        time.sleep(0.1)
    out = proc.stdout.read() if proc.stdout else ""
    if proc.returncode:
        raise SystemExit(f"child failed ({proc.returncode}): {' '.join(argv)[:80]}\n{out}")
    return time.perf_counter() - started, float(peak), out


def calib_process(src: Path, work: Path, limit_gb: float) -> tuple[float, float, str]:
    """`calib process --json` of a static_bias run of the record `src` (CSV, or MCAP by
    its suffix; moved into its run folder) into a new archive under `work`, in a child
    process (`run_child`)."""
    run = work / "run"
    run.mkdir()
    src.rename(run / src.name)
    fmt = MCAP_FORMAT if src.suffix == ".mcap" else CSV_FORMAT
    text = MANIFEST.format(limit_mb=round(limit_gb * 1000), data=src.name, format=fmt)
    (run / "run.toml").write_text(text, encoding="utf-8")
    env = {"CALIB_ARCHIVE": str(work / "archive"), "CALIB_ISSUE_CERTIFICATES": "0"}
    try:
        out = run_child([CALIB, "process", str(run), "--json"], env)
    finally:
        (run / src.name).rename(src)
    (doc,) = json.loads(out[2])["runs"]
    if doc["status"] != "ok":
        raise SystemExit(f"calib process failed: {doc['error']}")
    return out


def report(name: str, out: tuple[float, float, str]) -> None:
    print(f"{name}: {out[0]:.1f} s, peak {out[1] / 2**30:.2f} GB", file=sys.stderr)


def allan_error(parquet: Path, n: int) -> float:
    """Max relative difference of the streamed Allan deviation and allantools' oadev on
    the first `n` gyro-x samples (octave taus both give)."""
    import allantools

    x = pq.read_table(parquet, columns=["gyr_x"]).column(0).to_numpy()[:n]
    s = StreamedAllan(RATE, x.size, 1)
    for i in range(0, x.size, BLOCK_ROWS):
        s.push(x[i : i + BLOCK_ROWS, None])
    got = s.result()
    taus, ref, _, _ = allantools.oadev(x, rate=RATE, data_type="freq", taus="octave")
    k = min(taus.size, got.taus.size)
    return float(np.max(np.abs(got.adev[:k, 0] / ref[:k] - 1.0)))


def csv_part(args: argparse.Namespace) -> dict:
    """The CSV record's figures (and the Allan check on its samples)."""
    work = Path(tempfile.mkdtemp(prefix="longlog-", dir=args.dir))
    try:
        src = work / "static.csv"
        t0 = time.perf_counter()
        if args.record is not None:  # a record written before: linked, not written again
            os.link(args.record, src)
            samples = count_rows(src)
        else:
            samples = write_record(src, int(args.size_gb * 1e9))
        write_s = time.perf_counter() - t0
        size = src.stat().st_size
        print(f"wrote {size / 1e9:.2f} GB, {samples:,} samples in {write_s:.0f} s", file=sys.stderr)
        figures = pass_figures(size, samples, write_s, passes("", FLOOR, src, work, args))
        t0 = time.perf_counter()
        (parquet,) = (work / "archive" / "samples").rglob("*.parquet")
        err = allan_error(parquet, args.allan_samples)
        figures["seconds"]["allan_check"] = round(time.perf_counter() - t0, 1)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    return {
        **figures,
        "allan_rel_err_vs_allantools": err,
        "memory_limit_gb": args.memory_limit_gb,
    }


def passes(name: str, floor: str, src: Path, work: Path, args: argparse.Namespace) -> dict:
    """The floor pass (the script `floor` in a child) and `calib process` of `src`, each
    reported: "floor" and "process" -> (seconds, peak resident bytes, output) of the child."""
    folder = work / "floor"
    folder.mkdir()
    limit = str(int(args.memory_limit_gb * 1e9))
    runs = {
        "floor": run_child(
            [sys.executable, "-c", textwrap.dedent(floor), str(src), str(folder), limit]
        )
    }
    shutil.rmtree(folder)
    report(f"{name}floor", runs["floor"])
    runs["process"] = calib_process(src, work, args.memory_limit_gb)
    report(f"{name}process", runs["process"])
    return runs


def pass_figures(size: int, samples: int, write_s: float, runs: dict) -> dict:
    """The figures of one format's floor and process passes (`runs`, from `passes`)."""
    (floor_s, floor_rss, _), (proc_s, proc_rss, _) = runs["floor"], runs["process"]
    return {
        "size_gb": round(size / 1e9, 3),
        "samples": samples,
        "peak_rss_gb": round(proc_rss / 2**30, 3),
        "floor_peak_rss_gb": round(floor_rss / 2**30, 3),
        "process_mb_per_s": round(size / 1e6 / proc_s, 1),
        "floor_mb_per_s": round(size / 1e6 / floor_s, 1),
        "process_to_floor_ratio": round(proc_s / floor_s, 3),
        "seconds": {
            "write": round(write_s, 1),
            "floor": round(floor_s, 1),
            "process": round(proc_s, 1),
        },
    }


# --- MCAP (ROS 2 sensor_msgs/msg/Imu) ------------------------------------------------

# Reads, hashes and copies every byte, decodes every Imu message of every chunk with the
# same vectorised decoder and writes the Parquet; no checks, no statistics, no solve.
MCAP_FLOOR = """
import hashlib, struct, sys
from pathlib import Path
import numpy as np, pyarrow as pa, pyarrow.parquet as pq
from pipelines.ingest.cdr import IMU_LAYOUT, NS, decode_fixed_cdr, gather
from pipelines.ingest.streamed_pass import ROW_BYTES, block_bytes
from pipelines.ingest.mcap_records import OP_CHUNK, OP_MESSAGE, decompress, record_starts
from storage.rawstore import samples_parquet_options
src, work, limit = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
names = ["t", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]
schema = pa.schema([(c, pa.float64()) for c in names])
rows, parts, sha = block_bytes(limit) // ROW_BYTES, [], hashlib.sha256()

def write(w):
    t = np.concatenate([p["stamp"] for p in parts]) / NS
    acc = np.concatenate([p["acc"] for p in parts])
    gyr = np.concatenate([p["gyr"] for p in parts])
    w.write_table(pa.table([t, *acc.T, *gyr.T], schema=schema))
    parts.clear()

with src.open("rb") as fh, (work / "raw").open("wb") as copy, pq.ParquetWriter(
        work / "samples.parquet", schema, **samples_parquet_options(schema)) as w:
    def take(n):
        data = fh.read(n)
        sha.update(data)
        copy.write(data)
        return data
    take(8)
    pending = 0
    while True:
        head = take(9)
        if len(head) < 9:
            break
        body = take(struct.unpack_from("<Q", head, 1)[0])
        if head[0] != OP_CHUNK:
            continue
        size = struct.unpack_from("<Q", body, 16)[0]
        clen = struct.unpack_from("<I", body, 28)[0]
        start = 40 + clen
        data = decompress(str(src), 0, body[32:start - 8].decode(), body[start:], size)
        arr = np.frombuffer(data, np.uint8)
        starts = record_starts(data, arr)
        msg = starts[arr[starts] == OP_MESSAGE]
        length = gather(arr, msg + 1, "<u8").astype(np.int64)
        parts.append(decode_fixed_cdr(arr, msg + 31, length - 22, IMU_LAYOUT))
        pending += len(msg)
        if pending >= rows:
            write(w)
            pending = 0
    if parts:
        write(w)
print(sha.hexdigest())
"""

IMU_CDR = imu_cdr(b"imu_link")
T0_NS = 1_767_225_600_000_000_000  # 2026-01-01 UTC, ns


def write_mcap_record(path: Path, size_bytes: int, seed: int = 0) -> int:
    """A still unit at 1 kHz as ROS 2 Imu messages until the file holds `size_bytes`;
    returns the messages written. The payloads of a block are one numpy array (the
    Python loop only hands each one's bytes to the Writer)."""
    from mcap.writer import CompressionType, Writer

    rng = np.random.default_rng(seed)
    step = int(1e9 / RATE)
    rows, walk = 0, np.zeros(3)
    block = np.zeros(BLOCK_ROWS, IMU_CDR)
    block["encapsulation"] = [0, 1, 0, 0]
    block["frame_len"], block["frame_id"] = 9, b"imu_link"
    block["orientation"][:, 3] = 1.0
    size = IMU_CDR.itemsize
    with path.open("wb") as fh:
        w = Writer(fh, chunk_size=4 << 20, compression=CompressionType.NONE)
        w.start(profile="ros2", library="benchmarks/longlog.py")
        sid = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", IMU_MSGDEF.encode())
        cid = w.register_channel("/imu/data", "cdr", sid)
        add = w.add_message
        while fh.tell() < size_bytes:
            ns = T0_NS + step * (rows + np.arange(BLOCK_ROWS, dtype=np.int64))
            block["sec"], block["nanosec"] = ns // 1_000_000_000, ns % 1_000_000_000
            steps = rng.normal(0.0, 1e-7, (BLOCK_ROWS, 3))
            block["gyr"] = rng.normal(0.0, 1e-3, (BLOCK_ROWS, 3)) + walk + np.cumsum(steps, 0)
            walk = walk + steps.sum(axis=0)
            block["acc"] = rng.normal(0.0, 0.01, (BLOCK_ROWS, 3)) + [0.0, 0.0, 9.80665]
            data = block.tobytes()
            for i, t in enumerate((ns + 250_000).tolist()):  # logged 0.25 ms after the stamp
                add(cid, t, data[i * size : (i + 1) * size], t, rows + i)
            rows += BLOCK_ROWS
        w.finish()
    return rows


def mcap_part(args: argparse.Namespace, allan: bool) -> dict:
    """The MCAP record's figures (and the Allan check on its samples when `allan`)."""
    work = Path(tempfile.mkdtemp(prefix="longlog-mcap-", dir=args.dir))
    out: dict = {}
    try:
        src = work / "static.mcap"
        t0 = time.perf_counter()
        samples = write_mcap_record(src, int(args.size_gb * 1e9))
        write_s = time.perf_counter() - t0
        size = src.stat().st_size
        print(
            f"mcap: wrote {size / 1e9:.2f} GB, {samples:,} messages in {write_s:.0f} s",
            file=sys.stderr,
        )
        runs = passes("mcap ", MCAP_FLOOR, src, work, args)
        (parquet,) = (work / "archive" / "samples").rglob("*.parquet")
        got = pq.ParquetFile(parquet).metadata.num_rows
        if got != samples:
            raise SystemExit(f"mcap: {got} samples archived, {samples} written")
        if allan:
            t0 = time.perf_counter()
            out["allan_rel_err_vs_allantools"] = allan_error(parquet, args.allan_samples)
            out["allan_check_s"] = round(time.perf_counter() - t0, 1)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    return {**pass_figures(size, samples, write_s, runs), **out}


FIGURES = (
    "size_gb",
    "samples",
    "peak_rss_gb",
    "floor_peak_rss_gb",
    "process_mb_per_s",
    "floor_mb_per_s",
    "process_to_floor_ratio",
    "seconds",
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size-gb", type=float, default=4.0)
    ap.add_argument("--memory-limit-gb", type=float, default=1.0)
    ap.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()))
    ap.add_argument("--allan-samples", type=int, default=10_000_000)
    ap.add_argument("--formats", default="csv,mcap", help="comma-separated: csv, mcap")
    ap.add_argument("--keep", action="store_true")
    ap.add_argument(
        "--record", type=Path, help="CSV only: a record written by an earlier run, not rewritten"
    )
    args = ap.parse_args()
    formats = [f.strip() for f in args.formats.split(",") if f.strip()]
    if not formats or set(formats) - {"csv", "mcap"}:
        ap.error(f"--formats: csv and/or mcap, got {args.formats!r}")
    t0 = time.perf_counter()
    load_compiled()  # compiles the loops into their cache (once)
    window_statistics(np.random.default_rng(0).normal(size=(64, 6)), 16)
    print(f"compiled loops ready in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    result: dict = {}
    if "csv" in formats:
        result = csv_part(args)  # its keys at the top level too, as before
        result["csv"] = {k: result[k] for k in FIGURES if k in result}
    if "mcap" in formats:
        result["mcap"] = mcap_part(args, allan="csv" not in formats)
        if "csv" not in formats:
            result["allan_rel_err_vs_allantools"] = result["mcap"].pop(
                "allan_rel_err_vs_allantools"
            )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
