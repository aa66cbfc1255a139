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

And the streamed Allan deviation of a 10-million-sample subset (gyro x of the record)
against allantools' `oadev` (relative error, max over the octave taus both give).

The last stdout line is a JSON object: size_gb, samples, peak_rss_gb (the process),
floor_peak_rss_gb, process_mb_per_s, floor_mb_per_s, process_to_floor_ratio,
allan_rel_err_vs_allantools, seconds of each part. Targets: size_gb >= 4,
peak_rss_gb <= 1.5, process_to_floor_ratio <= 1.5, allan_rel_err_vs_allantools <= 1e-9.
The files are deleted at the end (`--keep` keeps them).

    .venv/bin/python benchmarks/longlog.py --size-gb 4 --dir /tmp
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

ROOT = Path(__file__).resolve().parent.parent
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

[format]
kind = "csv"
time_column = "time"
acc_columns = ["acc_x", "acc_y", "acc_z"]
gyr_columns = ["gyr_x", "gyr_y", "gyr_z"]

[[segments]]
label = "record"
file = "{data}"
"""

FLOOR = """
import hashlib, sys
from pathlib import Path
import pyarrow as pa, pyarrow.csv as pacsv, pyarrow.parquet as pq
from pipelines.ingest.csv_stream import block_bytes, _blocks
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
    for text in _blocks(fh, block_bytes(limit), copy, sha):
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


def run_child(argv: list[str], env: dict[str, str] | None = None) -> tuple[float, float, str]:
    """(wall s, peak RSS of the child and its descendants in bytes, stdout) of one child."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DO_NOT_TRACK": "1", **(env or {})}
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
    """`calib process --json` of a static_bias run of the record `src` (moved into its run
    folder) into a new archive under `work`, in a child process (`run_child`)."""
    run = work / "run"
    run.mkdir()
    src.rename(run / src.name)
    text = MANIFEST.format(limit_mb=round(limit_gb * 1000), data=src.name)
    (run / "run.toml").write_text(text, encoding="utf-8")
    calib = shutil.which("calib", path=str(Path(sys.executable).parent)) or "calib"
    env = {"CALIB_ARCHIVE": str(work / "archive"), "CALIB_ISSUE_CERTIFICATES": "0"}
    try:
        out = run_child([calib, "process", str(run), "--json"], env)
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
    import pyarrow.parquet as pq

    from calib_core.streamed import StreamedAllan

    x = pq.read_table(parquet, columns=["gyr_x"]).column(0).to_numpy()[:n]
    s = StreamedAllan(RATE, x.size, 1)
    for i in range(0, x.size, BLOCK_ROWS):
        s.push(x[i : i + BLOCK_ROWS, None])
    got = s.result()
    taus, ref, _, _ = allantools.oadev(x, rate=RATE, data_type="freq", taus="octave")
    k = min(taus.size, got.taus.size)
    return float(np.max(np.abs(got.adev[:k, 0] / ref[:k] - 1.0)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size-gb", type=float, default=4.0)
    ap.add_argument("--memory-limit-gb", type=float, default=1.0)
    ap.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()))
    ap.add_argument("--allan-samples", type=int, default=10_000_000)
    ap.add_argument("--keep", action="store_true")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="longlog-", dir=args.dir))
    limit = str(int(args.memory_limit_gb * 1e9))
    try:
        src = work / "static.csv"
        t0 = time.perf_counter()
        samples = write_record(src, int(args.size_gb * 1e9))
        write_s = time.perf_counter() - t0
        size = src.stat().st_size
        print(f"wrote {size / 1e9:.2f} GB, {samples:,} samples in {write_s:.0f} s", file=sys.stderr)
        outs = {}
        folder = work / "floor"
        folder.mkdir()
        floor = [sys.executable, "-c", textwrap.dedent(FLOOR), str(src), str(folder), limit]
        outs["floor"] = run_child(floor)
        shutil.rmtree(folder)
        report("floor", outs["floor"])
        outs["process"] = calib_process(src, work, args.memory_limit_gb)
        report("process", outs["process"])
        t0 = time.perf_counter()
        (parquet,) = (work / "archive" / "samples").rglob("*.parquet")
        err = allan_error(parquet, args.allan_samples)
        allan_s = time.perf_counter() - t0
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    (floor_s, floor_rss, _), (proc_s, proc_rss, _) = outs["floor"], outs["process"]
    print(
        json.dumps(
            {
                "size_gb": round(size / 1e9, 3),
                "samples": samples,
                "peak_rss_gb": round(proc_rss / 2**30, 3),
                "floor_peak_rss_gb": round(floor_rss / 2**30, 3),
                "process_mb_per_s": round(size / 1e6 / proc_s, 1),
                "floor_mb_per_s": round(size / 1e6 / floor_s, 1),
                "process_to_floor_ratio": round(proc_s / floor_s, 3),
                "allan_rel_err_vs_allantools": err,
                "seconds": {
                    "write": round(write_s, 1),
                    "floor": round(floor_s, 1),
                    "process": round(proc_s, 1),
                    "allan_check": round(allan_s, 1),
                },
                "memory_limit_gb": args.memory_limit_gb,
            }
        )
    )


if __name__ == "__main__":
    main()
