"""Write-call size benchmark: one file's bytes written into new files in calls of each size.

The archive writes every raw file and every run's Parquet samples into new files
(storage.rawstore). On Linux 6.18 with ext4 a large write() into new page-cache
pages has cost ten times a write of 256 KiB, and at other times the same (the
state of the machine's memory seems to decide, not looked into): this script
measures it, so `storage.rawstore.IO_CHUNK` rests on figures.

For each call size (64 KiB to the whole file at once), in turns, `--rounds` times:
write the bytes of a 16 MB buffer (a 1 kHz run's CSV is 15.6 MB) into a new file
in a temporary folder beside the archive's default location (the current directory
unless --dir), then fsync it. The files are kept until the end, as an archive keeps
its files: deleting each one would hand its freshly freed pages to the next write.

Progress goes to stderr; the last stdout line is one JSON object:
write_ms (median write time by call size in KiB), write_fsync_ms (write + fsync),
ratio_1mib_to_256kib (median write time in 1 MiB calls / in 256 KiB calls),
bytes, rounds.

Run: ``.venv/bin/python benchmarks/write_chunks.py`` (~10 s).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from storage.rawstore import write_all  # noqa: E402 - after the path is set

SIZES_KIB = (64, 256, 512, 1024, 4096)
NBYTES = 16 << 20


def write_file(path: Path, data: memoryview, call: int) -> tuple[float, float]:
    """(seconds to write `data` in calls of `call` bytes, seconds to write and fsync)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        started = time.perf_counter()
        write_all(fd, data, call)
        written = time.perf_counter() - started
        os.fsync(fd)
        return written, time.perf_counter() - started
    finally:
        os.close(fd)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--dir", type=Path, default=Path.cwd(), help="file system to test")
    args = parser.parse_args()
    # Random bytes: nothing a file system could compress or deduplicate.
    data = memoryview(os.urandom(NBYTES))
    calls = {kib: kib << 10 for kib in SIZES_KIB} | {NBYTES >> 10: NBYTES}
    times: dict[int, list[tuple[float, float]]] = {kib: [] for kib in calls}
    with tempfile.TemporaryDirectory(prefix="calib-write-chunks-", dir=args.dir) as tmp:
        for r in range(args.rounds):
            for kib, call in calls.items():
                times[kib].append(write_file(Path(tmp) / f"{kib}-{r}", data, call))
            print(f"  round {r + 1}/{args.rounds}", file=sys.stderr, flush=True)
    write_ms = {kib: round(1e3 * statistics.median(w for w, _ in v), 2) for kib, v in times.items()}
    fsync_ms = {kib: round(1e3 * statistics.median(f for _, f in v), 2) for kib, v in times.items()}
    for kib in calls:
        print(
            f"calls of {kib:6d} KiB: write {write_ms[kib]:7.1f} ms, "
            f"with fsync {fsync_ms[kib]:7.1f} ms",
            file=sys.stderr,
        )
    print(
        json.dumps(
            {
                "write_ms": write_ms,
                "write_fsync_ms": fsync_ms,
                "ratio_1mib_to_256kib": round(write_ms[1024] / write_ms[256], 2),
                "bytes": NBYTES,
                "rounds": args.rounds,
            }
        )
    )


if __name__ == "__main__":
    main()
