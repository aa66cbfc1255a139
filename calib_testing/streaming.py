"""How much resident memory a streamed read and solve adds, measured in a fresh process.

The memory tests of the streamed readers (CSV, MCAP, ROS 1 bag) run the same measurement:
after a warm-up on a smaller file of the same kind (the lazily imported modules, worker
threads and codecs: fixed costs), the growth of the peak resident set while the big file
is read, hashed, copied, written and solved. `assert_same_samples` and `assert_same_solve`
are their comparisons of the streamed route with the in-memory one.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np

GRAVITY = 9.80665  # m/s^2


def streamed_memory_growth(
    streamer: str, kind: str, big: Path, small: Path, out: Path, limit: int, settings: dict
) -> int:
    """Bytes the peak resident set grows by while `big` is streamed and solved.

    streamer : ``module:function`` of the streamed reader (`pipelines.ingest.streaming`).
    kind : the [format] section given to it: a kind (``"mcap"``), or a `FormatSpec`'s
        JSON (columns and units of a CSV file).
    small : a file of the same kind read first (the warm-up).
    out : the samples' Parquet to write (the warm-up's beside it).
    limit : the memory limit, bytes.
    settings : the static-bias settings of the solve.
    """
    module, function = streamer.split(":")
    if kind.startswith("{"):
        fmt = f"format_spec(json.loads({kind!r}))"
    else:
        fmt = f"format_spec({{'kind': {kind!r}}})"
    script = textwrap.dedent(f"""
        import json, sys
        from pathlib import Path
        from pipelines.streamed_solve import solve_streamed
        from pipelines.ingest.data_format import format_spec
        from {module} import {function} as stream

        def status(key):
            for line in open("/proc/self/status"):
                if line.startswith(key):
                    return int(line.split()[1]) * 1024

        def run(src, out):
            s = stream(src, fmt, out, copy_to=out.with_suffix(".raw"),
                       memory_limit={limit}, progress=False)
            solve_streamed(s, {settings!r}, gravity={GRAVITY}, memory_limit={limit})

        fmt = {fmt}
        big, small, out = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
        run(small, out.with_name("small.parquet"))
        base = status("VmRSS:")
        open("/proc/self/clear_refs", "w").write("5")  # peak := current
        run(big, out)
        print(json.dumps({{"grown": status("VmHWM:") - base}}))
    """)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    done = subprocess.run(
        [sys.executable, "-c", script, str(big), str(small), str(out)],
        capture_output=True,
        text=True,
        env=env,
    )
    if done.returncode != 0:
        raise RuntimeError(done.stderr[-2000:])
    return int(json.loads(done.stdout.strip().splitlines()[-1])["grown"])


def same_error(read: Any, stream: Any, path: Path, tmp_path: Path, **keys: Any) -> str:
    """The streamed route's error (``stream(path, tmp_path, **keys)``) is the in-memory
    reader's (``read(path, **keys)``), word for word, naming the file; its text."""
    from pipelines.ingest.errors import IngestError

    errors = []
    for call in (lambda: read(path, **keys), lambda: stream(path, tmp_path, **keys)):
        try:
            call()
        except IngestError as exc:
            errors.append(str(exc))
        else:
            raise AssertionError(f"{path} was not refused")
    assert errors[1] == errors[0]
    assert str(path) in errors[1]
    return errors[1]


def assert_same_samples(table: Any, rec: Any) -> None:
    """The streamed samples' Parquet `table` (pyarrow) holds the in-memory `Recording` `rec`
    bit for bit: the same time base and values, no temperature on either."""
    assert np.array_equal(table.column("t").to_numpy(), rec.t)
    for i, a in enumerate("xyz"):
        assert np.array_equal(table.column(f"acc_{a}").to_numpy(), rec.acc[:, i])
        assert np.array_equal(table.column(f"gyr_{a}").to_numpy(), rec.gyr[:, i])
    assert np.isnan(table.column("temp").to_numpy()).all() and rec.temp is None


def assert_same_solve(got: Any, ref: Any) -> None:
    """The streamed solve `got` is the in-memory solve `ref` (`Calibration`s) to rounding.

    Chunked sums differ from one pass by rounding (a few ulp, amplified by the Allan
    deviation's second differences): far below any noise. The same parameters, values
    within 1e-9 and standard uncertainties within 1e-6 relative, the same outlier counts.
    """
    assert set(got.parameters) == set(ref.parameters)
    for name, p in ref.parameters.items():
        q = got.parameters[name]
        assert math.isclose(q.value, p.value, rel_tol=1e-9), name
        if p.std is not None:
            assert math.isclose(q.std, p.std, rel_tol=1e-6), name
    assert got.info["outliers"] == ref.info["outliers"]
