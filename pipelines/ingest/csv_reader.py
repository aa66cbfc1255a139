"""Reader of delimited text files (CSV) described by the manifest's ``[format]`` section.

The columns come from the manifest (header names, or 0-based indices without
a header) or, when the manifest names none, are recognised among common names
(`csv_layout.COMMON_NAMES`: ``acc_x``, ``ax``, ``linear_acceleration.x``, ``gyro_x``,
``wx``, ``temp``, ...). Units are converted to SI with calib_core.units; raw
counts with a per-axis scale and offset; time in s/ms/us/ns, MATLAB datenum,
ISO-8601 text, a sample index, or no time column at all (``sample_rate_hz``).

Speed and memory: only the needed columns are parsed, straight to float64,
by pyarrow's multithreaded parser over memory-mapped `SLICE_BYTES` slices of
the file (whitespace-separated text by pandas' C parser in chunks of rows).
The output arrays are allocated once (for an estimate of the row count; their
untouched tail takes no memory), each slice is copied straight into its
place and dropped, so the peak memory is the decoded arrays plus about one
slice, whatever the size of the file (a multi-hour 1 kHz log). Files above
`PROGRESS_THRESHOLD_BYTES` show a progress bar on stderr. Only when a block
holds a problem is the file read again as text, in chunks, to name the first
bad line and column.

`stream_csv` is the same reader on the streamed route (a static record larger than the
run's memory limit): the file's blocks, hashed and copied as they are read, parsed with
the same options, converted and checked block by block, go to the samples' Parquet
(`pipelines.ingest.streamed_pass`) instead of the arrays.

The column plan of a file (which column is which role, header units) is
pipelines.ingest.csv_layout; naming the first bad line, pipelines.ingest.csv_diagnosis.
"""

from __future__ import annotations

import dataclasses
import mmap
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO, Unpack

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from calib_core.recording import Recording
from calib_core.units import acceleration_factor, angular_rate_factor, time_factor
from pipelines.ingest.csv_diagnosis import PANDAS_CHUNK_ROWS, diagnose
from pipelines.ingest.csv_dialect import split_unit
from pipelines.ingest.csv_layout import AXES, CHANNELS, CsvLayout, header_units, layout_of
from pipelines.ingest.data_format import COUNTS, PROGRESS_THRESHOLD_BYTES, FormatSpec
from pipelines.ingest.errors import IngestError
from pipelines.ingest.log_samples import impossible_reading
from pipelines.ingest.time_order import check_time_increases

if TYPE_CHECKING:
    from pipelines.ingest.streamed_pass import Streamed, StreamOptions

# Text per parsed slice: large enough that pyarrow's threads share the parse, small enough
# that a slice and its parse buffers stay well below the decoded arrays (peak 1.7x the
# arrays on an 800k-row file, tests/test_large_csv.py).
SLICE_BYTES = 8 << 20
ESTIMATE_PROBE_BYTES = 64 << 10  # bytes of the first lines that estimate the row count
MATLAB_UNIX_EPOCH_DATENUM = 719529.0  # datenum of 1970-01-01

TEMPERATURE_UNITS = {"degC": (1.0, 0.0), "K": (1.0, -273.15), "degF": (5 / 9, -32 * 5 / 9)}


# --- reading -----------------------------------------------------------------------


def read_csv(path: Path, fmt: FormatSpec, *, progress: bool | None = None) -> Recording:
    """Read a whole delimited text file into a Recording in SI units.

    Parameters
    ----------
    path : the data file.
    fmt : the manifest's format section (kind ``"csv"``): delimiter, header,
        columns (or none: common names recognised), units, sample rate.
    progress : show a progress bar on stderr; None: for files above
        `PROGRESS_THRESHOLD_BYTES`.

    Returns
    -------
    Recording with t (N,) s, acc (N, 3) m/s^2, gyr (N, 3) rad/s, temp (N,)
    deg C if a temperature column is named or recognised, reference channels
    from ``reference_columns``; no label; source = the path.

    Raises
    ------
    IngestError naming the file, and the line and column where it applies: an
    empty file, a named column that is not in the file, a non-numeric,
    missing or non-finite value, time that does not increase.
    """
    return _read(Path(path), fmt, progress, sections=False)[0]


def read_csv_sections(
    path: Path, fmt: FormatSpec, *, progress: bool | None = None
) -> dict[str, Recording]:
    """Read a file whose rows are grouped by a section column into one Recording per section.

    The section column is ``format.section_column``, else the one column named
    ``part``, ``label`` or ``section``; each section's rows must be contiguous.

    Returns
    -------
    {section value: Recording (label = the value)}, in the order of the file.

    Raises
    ------
    IngestError as `read_csv`, and for a section whose rows come in two separate
    blocks (naming the first line of each).
    """
    path = Path(path)
    whole, codes, layout = _read(path, fmt, progress, sections=True)
    starts = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1]])
    ends = np.r_[starts[1:], len(codes)]
    names = {code: value for value, code in layout.sections.items()}
    out: dict[str, Recording] = {}
    first_row: dict[str, int] = {}
    for start, end in zip(starts.tolist(), ends.tolist(), strict=True):
        value = names[int(codes[start])]
        if value in out:
            raise IngestError(
                f"section {value!r} comes in two separate blocks (from line "
                f"{layout.line_of_row(first_row[value])} and from this line); expected each "
                "section's rows together",
                file=path,
                line=layout.line_of_row(start),
                field=layout.fields[layout.roles["section"]],
            )
        first_row[value] = start
        part = whole.select(slice(start, end), label=value)
        out[value] = dataclasses.replace(part, source=f"{path} {layout.roles['section']}={value}")
    return out


def _read(
    path: Path, fmt: FormatSpec, progress: bool | None, sections: bool
) -> tuple[Recording, np.ndarray | None, CsvLayout]:
    """(Recording, section codes per row or None, layout) of a whole file."""
    layout = layout_of(path, fmt, sections=sections)
    fmt = header_units(layout, fmt)
    data = _read_columns(layout, fmt, progress)
    codes = data.pop("section", None)
    t = _time(layout, fmt, data.pop("time", None), len(data["acc"]), codes)
    acc = sensor_si(data.pop("acc"), "acc", fmt)
    gyr = sensor_si(data.pop("gyr"), "gyr", fmt)
    temp = temperature_celsius(layout, data.pop("temp", None))
    reference = {role[4:]: v for role, v in data.items() if role.startswith("ref:")}
    rec = Recording(t=t, acc=acc, gyr=gyr, temp=temp, reference=reference, source=str(path))
    return rec, codes, layout


def temperature_celsius(layout: CsvLayout, temp: np.ndarray | None) -> np.ndarray | None:
    """Temperature in deg C from the header's unit (degC, K or degF; none: degC)."""
    if temp is None:
        return None
    unit = split_unit(layout.roles["temp"])[1] or "degC"
    if unit not in TEMPERATURE_UNITS:
        raise IngestError(
            f"temperature unit {unit!r} in the header; expected one of "
            f"{', '.join(TEMPERATURE_UNITS)}",
            file=layout.path,
            line=layout.data_start - 1,
            field=layout.roles["temp"],
        )
    scale, offset = TEMPERATURE_UNITS[unit]
    return temp * scale + offset if unit != "degC" else temp


def read_csv_pair(
    acc_path: Path, gyr_path: Path, fmt: FormatSpec, *, progress: bool | None = None
) -> Recording:
    """Read an accelerometer file and a gyro file that share one time base.

    Both files have the same layout (``[format]``): the acc file gives time,
    ``acc_columns`` (and temperature, reference channels), the gyro file time
    and ``gyr_columns``. Their time stamps must be the same, row for row.

    Raises
    ------
    IngestError for anything `read_csv` refuses, and for files of different
    lengths or time stamps (naming the gyro file's first differing line).
    """
    acc_layout = layout_of(Path(acc_path), fmt, ("acc",))
    gyr_layout = layout_of(Path(gyr_path), fmt, ("gyr",))
    acc_data = _read_columns(acc_layout, fmt, progress)
    t = _time(acc_layout, fmt, acc_data.pop("time", None), len(acc_data["acc"]))
    gyr_data = _read_columns(gyr_layout, fmt, progress)
    t_gyr = _time(gyr_layout, fmt, gyr_data.pop("time", None), len(gyr_data["gyr"]))
    if len(t_gyr) != len(t):
        raise IngestError(
            f"has {len(t_gyr)} samples but the accelerometer file {acc_layout.path.name} has "
            f"{len(t)}; separate sensor files must share one time base",
            file=gyr_layout.path,
        )
    differ = np.flatnonzero(t_gyr != t)
    if differ.size:
        i = int(differ[0])
        raise IngestError(
            f"time {t_gyr[i]:.9g} s differs from the accelerometer file's {t[i]:.9g} s "
            f"({acc_layout.path.name} line {acc_layout.line_of_row(i)}); separate sensor "
            "files must share one time base",
            file=gyr_layout.path,
            line=gyr_layout.line_of_row(i),
        )
    del t_gyr
    acc = sensor_si(acc_data.pop("acc"), "acc", fmt)
    gyr = sensor_si(gyr_data.pop("gyr"), "gyr", fmt)
    temp = acc_data.pop("temp", None)
    reference = {role[4:]: v for role, v in acc_data.items() if role.startswith("ref:")}
    return Recording(
        t=t, acc=acc, gyr=gyr, temp=temp, reference=reference, source=f"{acc_path} + {gyr_path}"
    )


def estimate_rows(path: Path, data_start: int) -> int:
    """Rows of a text file estimated from the mean length of its first lines (up to 64 KiB)."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(ESTIMATE_PROBE_BYTES).split(b"\n")
    lines = [line for line in head[data_start - 1 : -1] if line.strip()]
    if not lines or len(head) < 2:
        return 1
    return int(size / (sum(map(len, lines)) / len(lines) + 1)) + 1


def _read_columns(
    layout: CsvLayout, fmt: FormatSpec, progress: bool | None
) -> dict[str, np.ndarray]:
    """Parse the file once, filling preallocated output arrays as the blocks come.

    Returns
    -------
    {"time": (N,) raw time values (ISO text already as Unix s), "acc": (N, 3),
    "gyr": (N, 3) raw values, "temp": (N,), "ref:<name>": (N,)}, for the roles
    this file has; every value finite. Each sample is copied once, from the
    parser's block straight into its place. The arrays are allocated for 25 %
    more rows than `estimate_rows` and returned as views of the rows read: the
    pages of unused rows are never touched, so they take no memory (a rare
    file whose later lines are much shorter makes them grow, with one copy).
    """
    iso_column = layout.roles.get("time") if fmt.time_unit == "iso" else None
    capacity = int(estimate_rows(layout.path, layout.data_start) * 1.25) + 1024
    # role -> (output array, column index in it or None)
    out: dict[str, np.ndarray] = {}
    target: dict[str, tuple[str, int | None]] = {}
    for role in layout.roles:
        sensor, _, axis = role.partition("_")
        if sensor in ("acc", "gyr") and axis in AXES:
            out.setdefault(sensor, np.empty((capacity, 3)))
            target[role] = (sensor, AXES.index(axis))
        else:
            out[role] = np.empty(capacity)
            target[role] = (role, None)
    columns = list(dict.fromkeys(layout.roles.values()))
    size = layout.path.stat().st_size
    show = size > PROGRESS_THRESHOLD_BYTES if progress is None else progress
    rows = 0
    with _progress(layout.path, size, show) as advance:
        for batch, consumed in _batches(layout, columns, iso_column):
            n = len(next(iter(batch.values())))
            if rows + n > capacity:
                capacity = 2 * (rows + n)
                for key, array in out.items():
                    grown = np.empty((capacity, *array.shape[1:]))
                    grown[:rows] = array[:rows]
                    out[key] = grown
            for role, name in layout.roles.items():
                values = batch[name]
                # A NaN or an infinity makes the sum non-finite: one pass, no temporary
                # array. A sum overflowing from finite values goes to the exact test.
                with np.errstate(over="ignore"):
                    suspect = not np.isfinite(values.sum())
                bad = np.flatnonzero(~np.isfinite(values)) if suspect else ()
                if len(bad):
                    diagnose(layout, columns, iso_column, rows)
                    raise IngestError(  # not reached unless the diagnosis disagrees
                        f"expected a finite number, got {values[bad[0]]!r}",
                        file=layout.path,
                        line=layout.line_of_row(rows + int(bad[0])),
                        field=layout.fields[name],
                    )
                key, col = target[role]
                if col is None:
                    out[key][rows : rows + n] = values
                else:
                    out[key][rows : rows + n, col] = values
            rows += n
            advance(consumed)
    if rows == 0:
        raise IngestError("no data rows", file=layout.path)
    return {key: array[:rows] for key, array in out.items()}


def _batches(
    layout: CsvLayout, columns: list[str], iso_column: str | None
) -> Iterator[tuple[dict[str, np.ndarray], int]]:
    """Blocks of the file as ({column: float64 array}, bytes read so far).

    An ISO time column comes as Unix seconds.

    Delimited text is parsed slice by slice (`_slices`); whitespace-separated
    text goes through pandas' C parser in chunks of rows.
    """
    if layout.delimiter == "whitespace":
        yield from _pandas_batches(layout, columns, iso_column)
        return
    section = layout.roles.get("section")
    options = arrow_options(layout, columns, (iso_column, section))
    try:
        for text, consumed in _slices(layout.path, layout.data_start):
            table = pacsv.read_csv(pa.BufferReader(text), *options)
            # Record batch by record batch: each column is then one Arrow array, viewed
            # without a copy (a whole-table column would be concatenated first). Nulls
            # (empty cells, "nan") become NaN here and are reported by the caller.
            for batch in table.to_batches():
                yield (
                    {
                        c: iso_seconds(batch.column(c))
                        if c == iso_column
                        else _codes(layout, batch.column(c))
                        if c == section
                        else float_values(batch.column(c))
                        for c in columns
                    },
                    consumed,
                )
            del table
    except pa.ArrowInvalid as exc:
        # Text in a numeric column, a row with too many fields, ...: find it.
        diagnose(layout, columns, iso_column, 0)
        raise IngestError(f"cannot parse the file: {exc}", file=layout.path) from None


def arrow_options(
    layout: CsvLayout, columns: list[str], text: tuple[str | None, ...] = ()
) -> tuple[pacsv.ReadOptions, pacsv.ParseOptions, pacsv.ConvertOptions]:
    """pyarrow's options that parse the data lines of `layout` (no header): `columns` only,
    as float64, the `text` columns (ISO time, section) as strings."""
    types = {c: (pa.string() if c in text else pa.float64()) for c in columns}
    return (
        pacsv.ReadOptions(column_names=layout.names, encoding="utf8"),
        pacsv.ParseOptions(delimiter=layout.delimiter),
        pacsv.ConvertOptions(
            include_columns=columns, column_types=types, decimal_point=layout.decimal
        ),
    )


def _slices(path: Path, data_start: int) -> Iterator[tuple[pa.Buffer, int]]:
    """The data lines of a file as `SLICE_BYTES` slices cut at line ends, with bytes consumed.

    The file is memory-mapped, so a slice is parsed where it lies (no copy), and its pages
    are released (MADV_DONTNEED: clean file pages, re-readable) once parsed: resident
    memory stays bounded by a slice whatever the size of the file. Each slice goes
    through pyarrow's multithreaded whole-buffer parser, which is as fast as its
    whole-file read (its streaming reader parses on one thread only, the slower here).
    """
    size = path.stat().st_size
    if size == 0:
        return
    # Not closed explicitly: the slices handed out hold the mapping until they are freed.
    with path.open("rb") as fh:
        m = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    start = 0
    for _ in range(data_start - 1):  # header and lines before the data
        start = m.find(b"\n", start) + 1
        if start == 0:
            return
    view = memoryview(m)
    while start < size:
        end = min(start + SLICE_BYTES, size)
        if end < size:
            cut = m.rfind(b"\n", start, end)
            end = cut + 1 if cut >= 0 else (m.find(b"\n", end) + 1 or size)
        yield pa.py_buffer(view[start:end]), end
        page_start = start - start % mmap.PAGESIZE
        m.madvise(mmap.MADV_DONTNEED, page_start, end - page_start)
        start = end


def float_values(column: pa.Array) -> np.ndarray:
    """A float64 Arrow column as NumPy, nulls (empty cells, "nan") as NaN.

    Without a null, a view of its buffer: pyarrow's ``to_numpy`` imports pandas
    (a large part of a one-run process) even for a view.
    """
    if column.null_count or column.type != pa.float64():
        return column.to_numpy(zero_copy_only=False)
    width = np.dtype(np.float64).itemsize
    return np.frombuffer(
        column.buffers()[1], dtype=np.float64, count=len(column), offset=column.offset * width
    )


def _codes(layout: CsvLayout, text: pa.Array | np.ndarray) -> np.ndarray:
    """Section names as float codes (`layout.sections` maps each name to its code)."""
    if isinstance(text, pa.Array | pa.ChunkedArray):
        text = text.to_numpy(zero_copy_only=False)
    uniques, inverse = np.unique(np.asarray(text, dtype=str), return_inverse=True)
    codes = np.array([layout.sections.setdefault(str(u), len(layout.sections)) for u in uniques])
    return codes[inverse].astype(float)


def iso_seconds(text: pa.Array | np.ndarray) -> np.ndarray:
    """ISO-8601 text as Unix seconds; a time without a UTC offset is taken as UTC.

    Each value may carry its own offset (``Z``, ``+02:00``) or none. Text that
    is not an ISO-8601 time becomes NaN, which the caller reports.
    """
    import pandas as pd

    if isinstance(text, pa.Array | pa.ChunkedArray):
        text = text.to_numpy(zero_copy_only=False)
    stamps = pd.DatetimeIndex(pd.to_datetime(text, utc=True, format="ISO8601", errors="coerce"))
    seconds = stamps.as_unit("ns").asi8 * 1e-9
    seconds[stamps.isna()] = np.nan
    return seconds


def _pandas_batches(
    layout: CsvLayout, columns: list[str], iso_column: str | None
) -> Iterator[tuple[dict[str, np.ndarray], int]]:
    """Whitespace-separated text through pandas' C parser, in chunks of rows."""
    import pandas as pd

    section = layout.roles.get("section")
    dtypes = {c: ("str" if c in (iso_column, section) else "float64") for c in columns}
    try:
        with layout.path.open("rb") as fh:  # its position tells the progress
            reader = pd.read_csv(
                fh,
                sep=r"\s+",
                header=None,
                names=layout.names,
                usecols=columns,
                dtype=dtypes,
                skiprows=layout.data_start - 1,
                engine="c",
                encoding="utf-8-sig",
                decimal=layout.decimal,
                chunksize=PANDAS_CHUNK_ROWS,
            )
            with reader:
                for frame in reader:
                    batch = {
                        c: iso_seconds(frame[c].to_numpy())
                        if c == iso_column
                        else _codes(layout, frame[c].to_numpy())
                        if c == section
                        else frame[c].to_numpy(dtype=np.float64)
                        for c in columns
                    }
                    yield batch, fh.tell()
    except (ValueError, pd.errors.ParserError) as exc:
        diagnose(layout, columns, iso_column, 0)
        raise IngestError(f"cannot parse the file: {exc}", file=layout.path) from None


@contextmanager
def _progress(path: Path, size: int, show: bool) -> Iterator[Callable[[int], None]]:
    """Yield `advance(bytes_read)`, which moves a rich bar on stderr (when `show`)."""
    if not show:
        yield lambda done: None
        return
    from rich.console import Console
    from rich.progress import BarColumn, DownloadColumn, Progress, TimeRemainingColumn

    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        DownloadColumn(),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        transient=True,
    ) as bar:
        task = bar.add_task(f"reading {path.name}", total=size)
        yield lambda done: bar.update(task, completed=min(done, size))
        bar.update(task, completed=size)


# --- the streamed route ----------------------------------------------------------------


def blocks(fh: BinaryIO, size: int, copy: BinaryIO | None, sha: Any) -> Iterator[memoryview]:
    """The file's bytes in blocks cut after a line end; every byte hashed and copied once.

    Read into two buffers in turn: a thread hashes and copies one buffer's new bytes
    while the caller parses the block before it is handed out (hashing overlaps
    parsing); a buffer is read into again only once its bytes are hashed and copied.
    Each block is a view, valid until the next one is asked for (the parser copies what
    it keeps); the unfinished last line moves to the front of the other buffer. All is
    hashed and copied when the iteration ends.
    """
    bufs = [bytearray(2 * size), bytearray(2 * size)]
    jobs: list[Future | None] = [None, None]
    io = ThreadPoolExecutor(max_workers=1, thread_name_prefix="calib-hash")

    def consume(view: memoryview) -> None:
        sha.update(view)
        if copy is not None:
            copy.write(view)

    cur, carry = 0, 0
    prev = memoryview(bufs[0])[:0]
    try:
        while True:
            if jobs[cur] is not None:
                jobs[cur].result()  # its last bytes are hashed: it may be filled again
            if len(bufs[cur]) - carry < size:  # a line longer than a block: grow
                bufs[cur] = bytearray(carry + 2 * size)
            view = memoryview(bufs[cur])
            view[:carry] = prev[len(prev) - carry :] if carry else b""
            got = fh.readinto(view[carry : carry + size])
            if not got:
                if carry:
                    yield view[:carry]
                return
            jobs[cur] = io.submit(consume, view[carry : carry + got])
            end = carry + got
            cut = bufs[cur].rfind(b"\n", 0, end) + 1
            prev, carry = view[:end], end - cut
            if cut:
                yield view[:cut]
                cur = 1 - cur
            # else: no line end yet; read on into the same buffer after the carry
            else:
                jobs[cur].result()
                prev = memoryview(bytes(view[:end]))
    finally:
        io.shutdown(wait=True)
        for job in jobs:
            if job is not None:
                job.result()  # raise a failed write (a full disk)


def stream_csv(
    path: Path,
    fmt: FormatSpec,
    samples: Path,
    **options: Unpack[StreamOptions],
) -> Streamed:
    """The streamed route: one pass over a delimited text file, hashed and copied (the raw
    copy) block by block, each block's samples (this reader's column plan, units and
    checks) to the samples' Parquet and the first-pass statistics (`streamed_pass`).

    Parameters
    ----------
    path : the data file (delimited text with a time column or a sample rate; one record).
    fmt : the manifest's format section (as `read_csv`).
    samples : the Parquet file to write (columns segment, t, acc_*, gyr_*, temp; SI).
    options : `streamed_pass.StreamOptions` (raw copy, label, memory limit: the block
        size, progress, time window).

    Raises
    ------
    IngestError naming the file and the line where time stops increasing or a value is
    not a finite number.
    """
    from pipelines.ingest.streamed_pass import block_bytes, streamed_pass

    path = Path(path)
    layout = layout_of(path, fmt, sections=False)
    if layout.delimiter == "whitespace" or "section" in layout.roles:
        raise IngestError("the streamed route reads delimited text of one record only", file=path)
    fmt = header_units(layout, fmt)
    iso = layout.roles.get("time") if fmt.time_unit == "iso" else None
    columns = list(dict.fromkeys(layout.roles.values()))
    parsing = arrow_options(layout, columns, (iso,))
    last_t = None
    with streamed_pass(path, samples, **options) as run:
        fh, sink = run.fh, run.sink
        head = b"".join(fh.readline() for _ in range(layout.data_start - 1))
        run.sha.update(head)
        if run.copy is not None:
            run.copy.write(head)
        done = len(head)
        for text in blocks(fh, block_bytes(run.memory_limit), run.copy, run.sha):
            done += len(text)
            try:
                table = pacsv.read_csv(pa.py_buffer(text), *parsing)
            except pa.ArrowInvalid as exc:
                diagnose(layout, columns, iso, sink.done)  # the line and field, as in memory
                raise IngestError(f"cannot parse the file: {exc}", file=path) from None
            if table.num_rows == 0:  # blank lines only
                continue
            chunk = csv_chunk(table, layout, fmt, iso, sink.done, path, last_t)
            last_t = float(chunk["t"][-1])
            sink.write(chunk)
            run.bar.update(done, sink.done)
        sink.finish()  # the last chunk's motion windows (computed beside the reading)
    if sink.done == 0:
        raise IngestError("no data rows", file=path)
    return run.result()


def csv_chunk(
    table: pa.Table, layout, fmt: FormatSpec, iso, rows: int, path: Path, last_t: float | None
) -> dict[str, np.ndarray]:
    """One block's samples in SI: t (n,), acc and gyr (n, 3), temp (n,) (NaN if none)."""
    n = table.num_rows
    # [gyr | acc]: the first pass takes it without a copy; column by column in memory, so
    # each column is filled, reduced and handed to Arrow without a strided copy. The
    # parser's chunks are copied straight into it (one copy, no combined Arrow column).
    both = np.empty((n, 6), order="F")
    values: dict[str, np.ndarray] = {}
    for role, name in layout.roles.items():
        col = table.column(name)
        if name == iso:
            v = iso_seconds(col.combine_chunks())
        else:
            v = both[:, CHANNELS.index(role)] if role in CHANNELS else np.empty(n)
            _copy_values(col, v)
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise IngestError(
                "expected a finite number",
                file=path,
                line=layout.line_of_row(rows + int(bad[0])),
                field=layout.fields[name],
            )
        values[role] = v
    gyr = sensor_si(both[:, :3], "gyr", fmt)
    acc = sensor_si(both[:, 3:], "acc", fmt)
    found = impossible_reading({"acc": acc, "gyr": gyr})
    if found is not None:  # the in-memory route's check (run_loader: check_readings)
        name, i, text = found
        raise IngestError(text, file=path, line=layout.line_of_row(rows + i), field=name)
    if "time" in values:
        t = values["time"]
        if fmt.time_unit == "samples":
            t = t / fmt.sample_rate_hz
        elif fmt.time_unit != "iso":
            t = seconds(t, fmt.time_unit)
    else:
        t = (rows + np.arange(n)) / fmt.sample_rate_hz
    steps = np.diff(t, prepend=-np.inf if last_t is None else last_t)
    if (steps <= 0).any():
        row = rows + int(np.flatnonzero(steps <= 0)[0])
        field = layout.fields.get(layout.roles.get("time", ""), "time")
        raise IngestError(
            "time must increase", file=path, line=layout.line_of_row(row), field=field
        )
    temp = temperature_celsius(layout, values.get("temp"))
    return {"t": t, "acc": acc, "gyr": gyr, "temp": np.full(n, np.nan) if temp is None else temp}


def _copy_values(column: pa.ChunkedArray, out: np.ndarray) -> None:
    """A float64 column's values into out (n,), chunk by chunk (nulls as NaN)."""
    start = 0
    for chunk in column.chunks:
        out[start : start + len(chunk)] = float_values(chunk)
        start += len(chunk)


# --- conversion to SI ----------------------------------------------------------------


def seconds(values: np.ndarray, unit: str) -> np.ndarray:
    """Time values in `unit` (s, ms, us, ns, or MATLAB ``datenum`` days) as seconds.

    datenum becomes Unix seconds: (dn - 719529) * 86400.
    """
    if unit == "datenum":
        return (values - MATLAB_UNIX_EPOCH_DATENUM) * 86400.0
    return values * time_factor(unit)


def _time(
    layout: CsvLayout,
    fmt: FormatSpec,
    raw: np.ndarray | None,
    n: int,
    sections: np.ndarray | None = None,
) -> np.ndarray:
    """Time in s from the raw time column, converted in place, or from the sample rate.

    `sections` (one code per row) makes each section a time base of its own: a sample
    counter may restart in every section, time is checked within each.

    Raises IngestError at the first row whose time is not after the previous one (of
    its section).
    """
    if raw is None:  # no time column: the sample index at the manifest's rate
        return np.arange(n) / fmt.sample_rate_hz
    t = raw
    if fmt.time_unit == "samples":
        t /= fmt.sample_rate_hz
    elif fmt.time_unit == "datenum":
        t -= MATLAB_UNIX_EPOCH_DATENUM
        t *= 86400.0
    elif fmt.time_unit != "iso" and fmt.time_unit != "s":
        t *= time_factor(fmt.time_unit)
    check_time_increases(
        t,
        file=layout.path,
        sample="row",
        line_of=layout.line_of_row,
        field=layout.fields[layout.roles["time"]],
        restarts=None if sections is None else np.r_[True, sections[1:] != sections[:-1]],
    )
    return t


def sensor_si(values: np.ndarray, sensor: str, fmt: FormatSpec) -> np.ndarray:
    """Convert an (N, 3) triad to SI in place and return it.

    Raw counts: value = (raw - offset) / scale * factor(scale_unit), per axis.
    """
    unit = getattr(fmt, f"{sensor}_unit")
    convert = acceleration_factor if sensor == "acc" else angular_rate_factor
    if unit == COUNTS:
        offset = getattr(fmt, f"{sensor}_offset")
        if offset is not None:
            values -= np.asarray(offset, dtype=float)
        values *= convert(getattr(fmt, f"{sensor}_scale_unit")) / np.asarray(
            getattr(fmt, f"{sensor}_scale"), dtype=float
        )
    elif (factor := convert(unit)) != 1.0:
        values *= factor
    return values
