"""Reader of delimited text files (CSV) described by the manifest's ``[format]`` section.

The columns come from the manifest (header names, or 0-based indices without
a header) or, when the manifest names none, are recognised among common names
(`csv_layout.COMMON_NAMES`: ``acc_x``, ``ax``, ``linear_acceleration.x``, ``gyro_x``,
``wx``, ``temp``, ...). Units are converted to SI with calib_core.units; raw
counts with a per-axis scale and offset; time in s/ms/us/ns, MATLAB datenum,
ISO-8601 text, a sample index, or no time column at all (``sample_rate_hz``).

One chunk loop (`csv_chunks`) serves both routes: each block of the data lines is parsed
(only the needed columns, straight to float64, by pyarrow's multithreaded parser;
whitespace-separated text by pandas' C parser in chunks of rows), checked and converted
to SI in the rows its caller gives, and dropped before the next block is parsed. Read
into memory (`read_csv`), those rows are slices of output arrays allocated once (for an
estimate of the row count; their untouched tail takes no memory) and the blocks are
memory-mapped `SLICE_BYTES` slices of the file: the peak memory is the decoded arrays
plus about one slice, whatever the size of the file (a multi-hour 1 kHz log). Streamed
(`stream_csv`: a static record larger than the run's memory limit), the blocks are read,
hashed and copied as they come (`blocks`) and each chunk goes to the samples' Parquet
(`pipelines.ingest.streamed_pass`). Files above `PROGRESS_THRESHOLD_BYTES` show progress
on stderr. Only when a block holds a problem is the file read again as text, in chunks,
to name the first bad line and column.

The column plan of a file (which column is which role, header units) is
pipelines.ingest.csv_layout; naming the first bad line, pipelines.ingest.csv_diagnosis.
"""

from __future__ import annotations

import dataclasses
import mmap
from collections.abc import Callable, Iterable, Iterator
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
from pipelines.ingest.csv_layout import AXES, CsvLayout, header_units, layout_of
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
    data = _joined(layout, fmt, progress)
    codes = data.pop("section", None)
    t, acc, gyr, temp = data.pop("t"), data.pop("acc"), data.pop("gyr"), data.pop("temp", None)
    reference = {role[4:]: v for role, v in data.items() if role.startswith("ref:")}
    rec = Recording(t=t, acc=acc, gyr=gyr, temp=temp, reference=reference, source=str(path))
    return rec, codes, layout


def temperature_celsius(layout: CsvLayout, temp: np.ndarray | None) -> np.ndarray | None:
    """Temperature in deg C from the header's unit (degC, K or degF; none: degC), in place."""
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
    if unit != "degC":
        scale, offset = TEMPERATURE_UNITS[unit]
        temp *= scale
        temp += offset
    return temp


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
    acc_data = _joined(acc_layout, fmt, progress)
    t = acc_data.pop("t")
    gyr_data = _joined(gyr_layout, fmt, progress)
    t_gyr = gyr_data.pop("t")
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
    acc, gyr, temp = acc_data.pop("acc"), gyr_data.pop("gyr"), acc_data.pop("temp", None)
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


def _joined(layout: CsvLayout, fmt: FormatSpec, progress: bool | None) -> dict[str, np.ndarray]:
    """The file's chunks (`csv_chunks`) joined in place in preallocated arrays.

    Returns
    -------
    {"t": (N,) s, "acc": (N, 3) m/s^2, "gyr": (N, 3) rad/s, "temp": (N,) deg C,
    "ref:<name>": (N,), "section": (N,) codes}, for the roles this file has; checked.
    Each sample is copied once, from the parser's block straight into its place. The
    arrays are allocated for 25 % more rows than `estimate_rows` and returned as views of
    the rows read: the pages of unused rows are never touched, so they take no memory (a
    rare file whose later lines are much shorter makes them grow, with one copy).
    """
    capacity = int(estimate_rows(layout.path, layout.data_start) * 1.25) + 1024
    out = {
        key: np.empty((capacity, 3) if key in ("acc", "gyr") else capacity) for key in _keys(layout)
    }
    rows = 0

    def rows_of(start: int, n: int) -> dict[str, np.ndarray]:
        nonlocal capacity, rows
        if start + n > capacity:
            capacity = 2 * (start + n)
            for key, array in out.items():
                out[key] = np.empty((capacity, *array.shape[1:]))
                out[key][:start] = array[:start]
        rows = start + n
        return {key: array[start:rows] for key, array in out.items()}

    size = layout.path.stat().st_size
    show = size > PROGRESS_THRESHOLD_BYTES if progress is None else progress
    with _progress(layout.path, size, show) as advance:
        texts = _slices(layout.path, layout.data_start)
        for _, consumed in csv_chunks(layout, fmt, texts, rows_of):
            advance(consumed)
    if rows == 0:
        raise IngestError("no data rows", file=layout.path)
    return {key: array[:rows] for key, array in out.items()}


def _keys(layout: CsvLayout) -> list[str]:
    """The arrays a chunk of this file fills: t, and acc, gyr, temp, ref:<name>, section
    for the roles it has."""
    keys = ["t"]
    for role in layout.roles:
        sensor, _, axis = role.partition("_")
        key = sensor if sensor in ("acc", "gyr") and axis in AXES else role
        if key != "time" and key not in keys:
            keys.append(key)
    return keys


def csv_chunks(
    layout: CsvLayout,
    fmt: FormatSpec,
    texts: Iterable[tuple[Any, int]],
    rows_of: Callable[[int, int], dict[str, np.ndarray]],
    *,
    readings: bool = False,
) -> Iterator[tuple[dict[str, np.ndarray], int]]:
    """The one chunk loop of both routes: each block of the data lines parsed, checked and
    converted to SI in ``rows_of(its first row, its rows)`` (`_keys`' arrays); yields
    those arrays and the bytes read so far.

    Parameters
    ----------
    layout, fmt : the file's column plan and the manifest's format section.
    texts : (block of whole data lines, bytes read so far); whitespace-separated text is
        read from the file by pandas instead.
    rows_of : the arrays to fill for rows [start, start + n) of the file.
    readings : also refuse an acc or gyr reading beyond what any IMU measures (in memory,
        run_loader's check_readings does it for every format).

    Raises
    ------
    IngestError naming the file, line and column: text that does not parse, a value that
    is not a finite number, a reading no IMU makes, time that does not increase (within
    each section; across blocks too).
    """
    iso = layout.roles.get("time") if fmt.time_unit == "iso" else None
    columns = list(dict.fromkeys(layout.roles.values()))
    rows, last = 0, None
    for table, consumed in _tables(layout, columns, iso, texts):
        chunk = rows_of(rows, len(table))
        _fill(table, layout, chunk, rows, columns, iso)
        del table  # freed before the next block is parsed: one block's buffers at a time
        for sensor in ("acc", "gyr"):
            if sensor in chunk:
                sensor_si(chunk[sensor], sensor, fmt)
        temperature_celsius(layout, chunk.get("temp") if "temp" in layout.roles else None)
        if readings:
            _check_readings(layout, chunk, rows)
        _time(layout, fmt, chunk, rows, last)
        last = chunk["t"][-1], chunk["section"][-1] if "section" in chunk else None
        rows += len(chunk["t"])
        yield chunk, consumed


def _tables(
    layout: CsvLayout, columns: list[str], iso: str | None, texts: Iterable[tuple[Any, int]]
) -> Iterator[tuple[Any, int]]:
    """Each non-empty block of the data lines parsed (`columns` only, as float64; the ISO
    time and section columns as text), with the bytes read so far: delimited text from
    `texts` by pyarrow's multithreaded parser (a Table), whitespace-separated text by
    pandas' C parser in chunks of rows (a DataFrame)."""
    section = layout.roles.get("section")
    if layout.delimiter == "whitespace":
        yield from _pandas_frames(layout, columns, (iso, section))
        return
    options = arrow_options(layout, columns, (iso, section))
    rows = 0
    for text, consumed in texts:
        try:
            table = pacsv.read_csv(pa.py_buffer(text), *options)
        except pa.ArrowInvalid as exc:
            # Text in a numeric column, a row with too many fields, ...: find it.
            diagnose(layout, columns, iso, rows)
            raise IngestError(f"cannot parse the file: {exc}", file=layout.path) from None
        rows += table.num_rows
        if table.num_rows:  # not blank lines only
            yield table, consumed
        del table  # not held while the next block is parsed


def _fill(
    table: Any,
    layout: CsvLayout,
    chunk: dict[str, np.ndarray],
    rows: int,
    columns: list[str],
    iso: str | None,
) -> None:
    """A parsed block's columns (a pyarrow Table or a pandas DataFrame) copied into their
    places in `chunk`, an ISO time as Unix s, section names as codes; `rows`: its first
    row in the file. Raises IngestError at the first value that is not a finite number."""
    for role, name in layout.roles.items():
        sensor, _, axis = role.partition("_")
        if sensor in ("acc", "gyr") and axis in AXES:
            out = chunk[sensor][:, AXES.index(axis)]
        else:
            out = chunk["t" if role == "time" else role]
        column = table.column(name) if isinstance(table, pa.Table) else table[name].to_numpy()
        if name == iso:
            parts = [iso_seconds(column)]
        elif role == "section":
            parts = [_codes(layout, column)]
        elif isinstance(column, pa.ChunkedArray):  # no combined Arrow column: one copy
            parts = [float_values(part) for part in column.chunks]
        else:
            parts = [column]
        start = 0
        for values in parts:
            # A NaN or an infinity makes the sum non-finite: one pass, no temporary array.
            # A sum overflowing from finite values goes to the exact test.
            with np.errstate(over="ignore"):
                suspect = not np.isfinite(values.sum())
            bad = np.flatnonzero(~np.isfinite(values)) if suspect else ()
            if len(bad):
                diagnose(layout, columns, iso, rows)
                raise IngestError(  # not reached unless the diagnosis disagrees
                    f"expected a finite number, got {values[bad[0]]!r}",
                    file=layout.path,
                    line=layout.line_of_row(rows + start + int(bad[0])),
                    field=layout.fields[name],
                )
            out[start : start + len(values)] = values
            start += len(values)


def _check_readings(layout: CsvLayout, chunk: dict[str, np.ndarray], rows: int) -> None:
    """IngestError at the first acc or gyr reading of a chunk beyond what any IMU measures,
    naming its line and column."""
    empty = np.empty((0, 3))
    found = impossible_reading({key: chunk.get(key, empty) for key in ("acc", "gyr")})
    if found is not None:
        sensor, i, text = found
        axis = AXES[int(np.argmax(np.abs(chunk[sensor][i])))]
        field = layout.fields[layout.roles[f"{sensor}_{axis}"]]
        raise IngestError(text, file=layout.path, line=layout.line_of_row(rows + i), field=field)


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


def _slices(path: Path, data_start: int) -> Iterator[tuple[memoryview, int]]:
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
        yield view[start:end], end
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


def _pandas_frames(
    layout: CsvLayout, columns: list[str], text: tuple[str | None, ...]
) -> Iterator[tuple[Any, int]]:
    """Whitespace-separated text through pandas' C parser, in chunks of rows (the `text`
    columns as strings), with the bytes read so far."""
    import pandas as pd

    dtypes = {c: ("str" if c in text else "float64") for c in columns}
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
                    yield frame, fh.tell()
                    del frame  # not held while the next chunk is parsed
    except (ValueError, pd.errors.ParserError) as exc:
        diagnose(layout, columns, text[0], 0)
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

    def rows_of(start: int, n: int) -> dict[str, np.ndarray]:
        # [gyr | acc]: the first pass takes it without a copy; column by column in memory,
        # so each column is filled, reduced and handed to Arrow without a strided copy
        both = np.empty((n, 6), order="F")
        chunk = {key: np.empty(n) for key in _keys(layout) if key not in ("acc", "gyr")}
        return {"temp": np.full(n, np.nan), **chunk, "gyr": both[:, :3], "acc": both[:, 3:]}

    with streamed_pass(path, samples, **options) as run:
        fh, sink = run.fh, run.sink
        head = b"".join(fh.readline() for _ in range(layout.data_start - 1))
        run.sha.update(head)
        if run.copy is not None:
            run.copy.write(head)
        texts = blocks(fh, block_bytes(run.memory_limit), run.copy, run.sha)
        done = len(head)
        texts = ((text, done := done + len(text)) for text in texts)
        for chunk, _ in csv_chunks(layout, fmt, texts, rows_of, readings=True):
            sink.write(chunk)
            run.bar.update(done, sink.done)
        sink.finish()  # the last chunk's motion windows (computed beside the reading)
    if sink.done == 0:
        raise IngestError("no data rows", file=path)
    return run.result()


# --- conversion to SI ----------------------------------------------------------------


def _time(
    layout: CsvLayout,
    fmt: FormatSpec,
    chunk: dict[str, np.ndarray],
    rows: int,
    last: tuple[float, float | None] | None,
) -> None:
    """A chunk's time in s, converted in place (MATLAB datenum to Unix s: (dn - 719529) *
    86400), or from the sample rate; `rows`: its first row in the file, `last`: the
    previous chunk's last time and section code. A section (``chunk["section"]``, one
    code per row) is a time base of its own: a sample counter may restart in every
    section, time is checked within each.

    Raises IngestError at the first row whose time is not after the previous one (of
    its section), this chunk's first row after the previous chunk's last one.
    """
    t = chunk["t"]
    if "time" not in layout.roles:  # no time column: the sample index at the manifest's rate
        t[:] = np.arange(rows, rows + len(t))
        t /= fmt.sample_rate_hz
        return
    if fmt.time_unit == "samples":
        t /= fmt.sample_rate_hz
    elif fmt.time_unit == "datenum":
        t -= MATLAB_UNIX_EPOCH_DATENUM
        t *= 86400.0
    elif fmt.time_unit != "iso" and fmt.time_unit != "s":
        t *= time_factor(fmt.time_unit)
    codes = chunk.get("section")
    field = layout.fields[layout.roles["time"]]
    where = {"file": layout.path, "sample": "row", "line_of": layout.line_of_row, "field": field}
    if last is not None and (codes is None or codes[0] == last[1]):
        check_time_increases(np.array([last[0], t[0]]), offset=rows - 1, **where)
    restarts = None if codes is None else np.r_[True, codes[1:] != codes[:-1]]
    check_time_increases(t, restarts=restarts, offset=rows, **where)


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
