"""Reader of the MPU-6000 text layout (methods.md section 5), recognised by file name.

One file per position or rotation, named ``<serial>_<x|y|z>_<up|dn|cw|ccw>.txt``.
Each holds 8 whitespace-separated columns per sample::

    time_ms  ax ay az (m/s^2, 4 decimals)  gx gy gz (deg/s, 3 decimals)  temp (deg C, 1 decimal)

then a line of underscores, a line of per-column means and a line of standard
deviations. The summary lines are checked against the data read: a mismatch
beyond the printed precision means the data and its summary disagree (a
truncated or spliced file).
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pandas as pd

from calib_core.recording import Recording
from calib_core.units import DEG
from pipelines.ingest.errors import IngestError
from pipelines.ingest.manifest import SIX_POSITION_LABELS
from storage.naming import check_safe_name

N_COLUMNS = 8
COLUMN_NAMES = ("time_ms", "ax", "ay", "az", "gx", "gy", "gz", "temp")
# Decimals of each column as the layout prints them (time in integer ms).
COLUMN_DECIMALS = (0, 4, 4, 4, 3, 3, 3, 1)

FILE_PATTERN = re.compile(r"^(?P<serial>.+)_(?P<axis>[xyz])_(?P<sense>up|dn|cw|ccw)\.txt$")
_NAMES = " ".join(COLUMN_NAMES)
_UNDERSCORES = re.compile(r"^\s*_{3,}\s*$")


def parse_file_name(name: str) -> tuple[str, str] | None:
    """(serial, label) of an MPU-6000 file name, or None if the name is not of the layout.

    Raises IngestError when the name has the layout but the serial is not a
    safe name (it becomes a folder in the archive).
    """
    m = FILE_PATTERN.match(name)
    if m is None:
        return None
    try:
        serial = check_safe_name(m["serial"], "serial")
    except ValueError as exc:
        raise IngestError(f"serial in the file name: {exc}", file=name) from None
    return serial, f"{m['axis']}_{m['sense']}"


def read_mpu6000_file(path: Path) -> Recording:
    """Read one MPU-6000 text file into a Recording in SI units.

    Parameters
    ----------
    path : ``<serial>_<axis>_<up|dn|cw|ccw>.txt``.

    Returns
    -------
    Recording with t (N,) s, acc (N, 3) m/s^2, gyr (N, 3) rad/s, temp (N,) deg C,
    label from the file name (``"x_up"``, ``"z_ccw"``, ...), source = the path.

    Raises
    ------
    IngestError naming the file (and line) for: an empty or truncated file, a
    wrong number of columns, a non-numeric or non-finite value, time not
    increasing, summary lines that disagree with the data.
    """
    path = Path(path)
    parsed = parse_file_name(path.name)
    label = parsed[1] if parsed else None
    try:
        text = path.read_bytes().decode("ascii")
    except FileNotFoundError:
        raise IngestError("file not found", file=path) from None
    except UnicodeDecodeError as exc:
        raise IngestError(
            f"not ASCII text (byte {exc.start}): not an MPU-6000 file", file=path
        ) from None

    lines = text.splitlines()
    if not any(line.strip() for line in lines):
        raise IngestError("file is empty", file=path)
    end = next((i for i, line in enumerate(lines) if _UNDERSCORES.match(line)), None)
    if end is None:
        raise IngestError(
            "no line of underscores after the data: the file is truncated "
            "(expected data, '____', a line of means and a line of standard deviations)",
            file=path,
        )
    data = _parse_data(lines[:end], path)
    if data.shape[0] == 0:
        raise IngestError("no data lines before the line of underscores", file=path, line=end + 1)

    t_ms = data[:, 0]
    bad = np.flatnonzero(np.diff(t_ms) <= 0)
    if bad.size:
        line = _data_line_numbers(lines[:end])[bad[0] + 1]
        raise IngestError(
            f"time {t_ms[bad[0] + 1]:g} ms is not after the previous sample's "
            f"{t_ms[bad[0]]:g} ms (time must increase)",
            file=path,
            line=line,
        )
    _check_summary(lines, end, data, path)

    return Recording(
        t=t_ms * 1e-3,
        acc=data[:, 1:4].copy(),
        gyr=data[:, 4:7] * DEG,
        temp=data[:, 7].copy(),
        label=label,
        source=str(path),
    )


def _data_line_numbers(lines: list[str]) -> np.ndarray:
    """1-based line numbers of the non-blank lines (the rows pandas returns)."""
    return np.array([i + 1 for i, line in enumerate(lines) if line.strip()], dtype=int)


def _parse_data(lines: list[str], path: Path) -> np.ndarray:
    """The data lines as an (N, 8) float array: one C-parser pass, diagnosis only on failure."""
    try:
        frame = pd.read_csv(
            io.StringIO("\n".join(lines)),
            sep=r"\s+",
            header=None,
            dtype=float,
            engine="c",
        )
        data = frame.to_numpy()
        if data.shape[1] == N_COLUMNS and np.isfinite(data).all():
            return data
    except (ValueError, pd.errors.ParserError):
        pass
    except pd.errors.EmptyDataError:
        return np.empty((0, N_COLUMNS))
    _diagnose(lines, path)
    raise IngestError("could not parse the data lines", file=path)  # _diagnose found nothing


def _diagnose(lines: list[str], path: Path) -> None:
    """Raise IngestError at the first bad data line (slow path, only after a failed parse)."""
    for i, line in enumerate(lines):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != N_COLUMNS:
            raise IngestError(
                f"expected {N_COLUMNS} numeric columns ({_NAMES}), got {len(fields)}",
                file=path,
                line=i + 1,
            )
        for name, value in zip(COLUMN_NAMES, fields, strict=True):
            try:
                number = float(value)
            except ValueError:
                number = None
            if number is None or not np.isfinite(number):
                raise IngestError(
                    f"expected a finite number, got {value!r}", file=path, line=i + 1, field=name
                )


def _decimals(token: str) -> int:
    """Digits after the decimal point as printed (0 for an integer)."""
    mantissa = token.lower().split("e")[0]
    return len(mantissa.split(".")[1]) if "." in mantissa else 0


def _check_summary(lines: list[str], end: int, data: np.ndarray, path: Path) -> None:
    """Compare the printed means and standard deviations with the data read.

    Tolerance per column: half a unit of the summary's last printed digit
    (its own rounding) plus half a unit of the data column's last digit (the
    writer may have averaged unrounded values; rounding moves a mean or a
    std by at most that much). The std is accepted with ddof 0 or 1, since
    writers differ.
    """
    rest = [(i, line) for i, line in enumerate(lines[end + 1 :], start=end + 2) if line.strip()]
    if len(rest) < 2:
        raise IngestError(
            "the lines of means and standard deviations after the underscores are missing: "
            "the file is truncated",
            file=path,
        )
    if len(rest) > 2:
        raise IngestError(
            "unexpected text after the line of standard deviations", file=path, line=rest[2][0]
        )
    data_half_ulp = 0.5 * 10.0 ** -np.array(COLUMN_DECIMALS, dtype=float)
    stats = {
        "means": (data.mean(axis=0),),
        "standard deviations": (
            data.std(axis=0, ddof=0),
            data.std(axis=0, ddof=1 if len(data) > 1 else 0),
        ),
    }
    for (line_no, line), (what, computed) in zip(rest, stats.items(), strict=True):
        tokens = line.split()
        try:
            printed = np.array([float(tok) for tok in tokens])
        except ValueError:
            printed = np.array([])
        if printed.shape != (N_COLUMNS,):
            raise IngestError(
                f"expected the {N_COLUMNS} column {what}, got {line.strip()!r}",
                file=path,
                line=line_no,
            )
        tol = (
            0.5 * 10.0 ** -np.array([_decimals(tok) for tok in tokens], dtype=float) + data_half_ulp
        )
        ok = np.zeros(N_COLUMNS, dtype=bool)
        for values in computed:
            ok |= np.abs(values - printed) <= tol * (1 + 1e-9)
        if not ok.all():
            j = int(np.flatnonzero(~ok)[0])
            raise IngestError(
                f"the printed {what} disagree with the data: column '{COLUMN_NAMES[j]}' prints "
                f"{printed[j]:g}, the {len(data)} data lines give {computed[0][j]:.6g}; "
                "the file is truncated or its parts do not belong together",
                file=path,
                line=line_no,
            )


def find_mpu6000_runs(folder: Path, complete: bool = True) -> dict[str, dict[str, Path]]:
    """MPU-6000 files in `folder` (not recursive), grouped by serial.

    Parameters
    ----------
    folder : a folder holding ``<serial>_<axis>_<sense>.txt`` files.
    complete : if True, every serial must have all 12 files (six positions,
        six rotations); else partial sets are returned as found.

    Returns
    -------
    {serial: {label: path}}, serials and labels sorted.

    Raises
    ------
    IngestError naming the folder, the serial and the missing labels/files.
    """
    folder = Path(folder)
    runs: dict[str, dict[str, Path]] = {}
    for path in sorted(folder.glob("*.txt")):
        try:
            parsed = parse_file_name(path.name)
        except IngestError as exc:
            raise IngestError(exc.problem, file=path) from None
        if parsed is not None and path.is_file():
            serial, label = parsed
            runs.setdefault(serial, {})[label] = path
    if complete:
        for serial, files in runs.items():
            check_complete(folder, serial, files)
    # Canonical segment order: x_up, x_dn, ..., z_cw.
    order = {label: i for i, label in enumerate(SIX_POSITION_LABELS)}
    return {s: dict(sorted(runs[s].items(), key=lambda kv: order[kv[0]])) for s in sorted(runs)}


def check_complete(folder: Path, serial: str, files: dict[str, Path]) -> None:
    """Raise IngestError if `files` lacks any of the 12 six-position + integral segments."""
    missing = [label for label in SIX_POSITION_LABELS if label not in files]
    if missing:
        names = ", ".join(f"{serial}_{label}.txt" for label in missing)
        raise IngestError(
            f"serial '{serial}' has {len(files)} of the 12 MPU-6000 files; missing {names}",
            file=folder,
        )
