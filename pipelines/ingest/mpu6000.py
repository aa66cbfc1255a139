"""Reader of the MPU-6000 text layout (docs/methods.md section 5), recognised by file name.

One file per position or rotation, named ``<serial>_<x|y|z>_<up|dn|cw|ccw>.txt``
(any case, ``-`` or ``_`` between the parts, ``down`` for ``dn``). Each holds 8
columns per sample::

    time_ms  ax ay az (m/s^2, 4 decimals)  gx gy gz (deg/s, 3 decimals)  temp (deg C, 1 decimal)

then a line of underscores, a line of means and a line of standard deviations.
The manual leaves the details open and real files differ, so the reader accepts:

- summary lines with or without a label (``mean``/``std``, any case, followed by
  nothing, ``=`` or ``:``) holding 8 numbers (every column), 6 (ax..gz) or 7
  (ax..gz + temp, or time + ax..gz: the one the data agree with);
- point or comma decimal marks; space, tab or semicolon separators;
- LF, CRLF or CR line ends; UTF-8 with or without BOM, or cp1251 (a Windows
  program's Cyrillic header); header lines before the data, comment lines
  (``#``, ``%``, ``//``) and blank lines anywhere.

The summary lines are checked against the data read: a mismatch beyond the
printed precision means the data and its summary disagree (a truncated or
spliced file) and is an error naming the line and column. What was found is
returned as a :class:`TextVariant` (``calib inspect`` shows it).
"""

from __future__ import annotations

import codecs
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib_core.recording import Recording
from calib_core.units import DEG
from pipelines.ingest.csv_dialect import is_number
from pipelines.ingest.errors import IngestError
from pipelines.ingest.manifest import ROTATION_LABELS, SIX_POSITION_LABELS, STATIC_LABELS
from pipelines.ingest.time_order import check_time_increases
from storage.naming import check_safe_name

N_COLUMNS = 8
COLUMN_NAMES = ("time_ms", "ax", "ay", "az", "gx", "gy", "gz", "temp")
# Decimals of each column as the layout prints them (time in integer ms).
COLUMN_DECIMALS = (0, 4, 4, 4, 3, 3, 3, 1)
# Which columns a summary line of n numbers may hold, in order of preference.
SUMMARY_COLUMNS = {
    8: ((0, 1, 2, 3, 4, 5, 6, 7),),
    7: ((1, 2, 3, 4, 5, 6, 7), (0, 1, 2, 3, 4, 5, 6)),
    6: ((1, 2, 3, 4, 5, 6),),
}

FILE_PATTERN = re.compile(
    r"^(?P<serial>.+)[-_](?P<axis>[xyz])[-_](?P<sense>up|dn|down|cw|ccw)\.txt$", re.IGNORECASE
)
_NAMES = " ".join(COLUMN_NAMES)
_UNDERLINE = re.compile(r"^\s*(_{3,}|-{3,}|={3,})\s*$")
_COMMENT = ("#", "%", "//")
_DECIMAL = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")
_SUMMARY = re.compile(r"^\s*(?:(?P<label>[A-Za-z]+)\s*[=:]?)?\s*(?P<numbers>[-+0-9.,;\s eE]*)$")
_LABELS = {"mean": "means", "std": "standard deviations"}
# What a data line may hold after _normalise. With no other character, Python's float()
# takes exactly the numbers _DECIMAL matches (no "1_000", "nan", "inf").
_DATA_CHARS = frozenset("0123456789+-.eE \t\r\n\f\v")


@dataclass
class TextVariant:
    """How an MPU-6000 text file is written (what the reader found)."""

    encoding: str = "ascii"
    line_end: str = "LF"
    separator: str = "space"
    decimal: str = "."
    header_lines: int = 0
    comment_lines: int = 0
    summary: list[str] = field(default_factory=list)

    def describe(self) -> str:
        """One line for people, e.g. ``cp1251, CRLF, tab-separated, decimal ','``."""
        parts = [
            self.encoding,
            self.line_end,
            f"{self.separator}-separated",
            f"decimal '{self.decimal}'",
        ]
        if self.header_lines:
            parts.append(f"{self.header_lines} header line(s)")
        if self.comment_lines:
            parts.append(f"{self.comment_lines} comment line(s)")
        parts += self.summary
        return ", ".join(parts)


def parse_file_name(name: str) -> tuple[str, str] | None:
    """(serial, label) of an MPU-6000 file name, or None if the name is not of the layout.

    The label is canonical (``"x_dn"`` for ``X-DOWN``). Raises IngestError when
    the name has the layout but the serial is not a safe name (it becomes a
    folder in the archive).
    """
    m = FILE_PATTERN.match(name)
    if m is None:
        return None
    try:
        serial = check_safe_name(m["serial"], "serial")
    except ValueError as exc:
        raise IngestError(f"serial in the file name: {exc}", file=name) from None
    sense = m["sense"].lower().replace("down", "dn")
    return serial, f"{m['axis'].lower()}_{sense}"


def read_mpu6000_file(path: Path) -> Recording:
    """Read one MPU-6000 text file into a Recording in SI units.

    Parameters
    ----------
    path : ``<serial>_<axis>_<up|dn|cw|ccw>.txt`` (or a variant of the name).

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
    return read_mpu6000_text(path)[0]


def read_mpu6000_text(path: Path) -> tuple[Recording, TextVariant]:
    """Like :func:`read_mpu6000_file`, also returning the variant of the layout found."""
    path = Path(path)
    parsed = parse_file_name(path.name)
    label = parsed[1] if parsed else None
    variant = TextVariant()
    lines = _decode_lines(path, variant)
    data_lines, summary_lines = _split_parts(lines, path, variant)
    _detect_marks(data_lines[0][1], variant)
    data = _parse_data(data_lines, path, variant)

    t_ms = data[:, 0]
    check_time_increases(t_ms, file=path, unit="ms", line_of=lambda i: data_lines[i][0])
    _check_summary(summary_lines, data, path, variant)
    rec = Recording(
        t=t_ms * 1e-3,
        acc=data[:, 1:4].copy(),
        gyr=data[:, 4:7] * DEG,
        temp=data[:, 7].copy(),
        label=label,
        source=str(path),
    )
    return rec, variant


def _decode_lines(path: Path, variant: TextVariant) -> list[str]:
    """The file's lines (any line end), decoded as UTF-8 (BOM or not) or cp1251."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise IngestError("file not found", file=path) from None
    except OSError as exc:
        raise IngestError(f"cannot read file: {exc.strerror or exc}", file=path) from None
    if b"\x00" in raw:
        offset = raw.index(b"\x00")
        raise IngestError(
            f"NUL byte at offset {offset}: binary, not an MPU-6000 text file", file=path
        )
    if raw.startswith(codecs.BOM_UTF8):
        variant.encoding, raw = "utf-8 with BOM", raw[len(codecs.BOM_UTF8) :]
    try:
        text = raw.decode("utf-8")
        if variant.encoding == "ascii" and not raw.isascii():
            variant.encoding = "utf-8"
    except UnicodeDecodeError:
        try:
            text = raw.decode("cp1251")
        except UnicodeDecodeError as exc:
            raise IngestError(
                f"byte {exc.start} is neither UTF-8 nor cp1251 text", file=path
            ) from None
        variant.encoding = "cp1251"
    crlf, cr = text.count("\r\n"), text.count("\r")
    lf = text.count("\n") - crlf
    ends = [name for name, n in (("CRLF", crlf), ("CR", cr - crlf), ("LF", lf)) if n]
    variant.line_end = "+".join(ends) if ends else "none"
    # Only CR, LF and CRLF end a line (str.splitlines also splits on \x0b, \x1c, ...).
    return re.split(r"\r\n|\r|\n", text)


def _split_parts(
    lines: list[str], path: Path, variant: TextVariant
) -> tuple[list[tuple[int, str]], list[tuple[int, str]]]:
    """(line number, text) of the data lines and of the summary lines after the underline."""
    data: list[tuple[int, str]] = []
    summary: list[tuple[int, str]] = []
    underline = None
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith(_COMMENT):
            variant.comment_lines += 1
        elif underline is not None:
            summary.append((number, line))
        elif _UNDERLINE.match(line):
            underline = number
        elif not data and not is_number(re.split(r"[;\s]+", stripped)[0]):
            variant.header_lines += 1  # text before the first data line
        else:
            data.append((number, line))
    if not data and underline is None:
        what = "no data lines" if variant.header_lines else "file is empty"
        raise IngestError(f"{what}: expected {N_COLUMNS} numeric columns ({_NAMES})", file=path)
    if underline is None:
        raise IngestError(
            "no line of underscores after the data: the file is truncated "
            "(expected data, '____', a line of means and a line of standard deviations)",
            file=path,
        )
    if not data:
        raise IngestError("no data lines before the line of underscores", file=path, line=underline)
    return data, summary


def _detect_marks(first: str, variant: TextVariant) -> None:
    """Separator and decimal mark from the first data line."""
    if ";" in first:
        variant.separator = "semicolon"
    elif "\t" in first:
        variant.separator = "tab"
    if "," in first and "." not in first:
        variant.decimal = ","


def _normalise(text: str, variant: TextVariant) -> str:
    """Text with point decimals and whitespace between the fields."""
    if variant.decimal == ",":
        text = text.replace(",", ".")
    return text.replace(";", " ") if variant.separator == "semicolon" else text


def _parse_data(lines: list[tuple[int, str]], path: Path, variant: TextVariant) -> np.ndarray:
    """The data lines as an (N, 8) float array; diagnosis only on failure.

    Each field through Python's float() (correctly rounded, as pandas' C parser gives
    them: checked equal on 200 000 numbers of 1-19 digits), since importing pandas
    alone takes longer than reading a run's twelve files.
    """
    text = _normalise("\n".join(line for _, line in lines), variant)
    if set(text) <= _DATA_CHARS:
        rows = [line.split() for line in text.split("\n")]
        if len(rows) == len(lines) and all(len(row) == N_COLUMNS for row in rows):
            try:
                values = [float(v) for row in rows for v in row]
            except ValueError:  # a sign or point out of place ("1-2", "1.2.3")
                values = []
            data = np.array(values, dtype=float).reshape(-1, N_COLUMNS)
            if data.shape == (len(lines), N_COLUMNS) and np.isfinite(data).all():
                # Column-major, as pandas gave it: a column's sums (means, variances)
                # then run over contiguous memory and round exactly as before.
                return np.asfortranarray(data)
    _diagnose(lines, path, variant)
    raise IngestError("could not parse the data lines", file=path)  # _diagnose found nothing


def _diagnose(lines: list[tuple[int, str]], path: Path, variant: TextVariant) -> None:
    """Raise IngestError at the first bad data line (slow path, only after a failed parse)."""
    for number, line in lines:
        fields = _normalise(line, variant).split()
        if len(fields) != N_COLUMNS:
            raise IngestError(
                f"expected {N_COLUMNS} numeric columns ({_NAMES}), got {len(fields)}",
                file=path,
                line=number,
            )
        for name, value in zip(COLUMN_NAMES, fields, strict=True):
            # Python's float() takes "1_000" and " nan"; the data parser does not.
            number_ = float(value) if _DECIMAL.fullmatch(value) else None
            if number_ is None or not np.isfinite(number_):
                raise IngestError(
                    f"expected a finite number, got {value!r}", file=path, line=number, field=name
                )


def _decimals(token: str) -> int:
    """Digits after the decimal point as printed (0 for an integer)."""
    mantissa = token.lower().split("e")[0]
    return len(mantissa.split(".")[1]) if "." in mantissa else 0


def _summary_values(
    summary: list[tuple[int, str]], path: Path, variant: TextVariant
) -> dict[str, tuple[int, list[str]]]:
    """{"means"|"standard deviations": (line, number tokens)}, by label or by order."""
    if len(summary) < 2:
        raise IngestError(
            "the lines of means and standard deviations after the underscores are missing: "
            "the file is truncated",
            file=path,
        )
    if len(summary) > 2:
        raise IngestError(
            "unexpected text after the line of standard deviations", file=path, line=summary[2][0]
        )
    out: dict[str, tuple[int, list[str]]] = {}
    for (number, line), default in zip(summary, _LABELS.values(), strict=True):
        m = _SUMMARY.match(_normalise(line, variant))
        label = m["label"].lower() if m and m["label"] else None
        if m is None or (label is not None and label not in _LABELS):
            raise IngestError(
                f"expected the {default}: an optional label 'mean' or 'std' and 6, 7 or 8 "
                f"numbers, got {line.strip()[:80]!r}",
                file=path,
                line=number,
            )
        what = _LABELS[label] if label else default
        if what in out:
            raise IngestError(f"second line of {what}", file=path, line=number)
        out[what] = (number, m["numbers"].split())
        variant.summary.append(
            f"{what} {'labelled ' + repr(label) if label else 'unlabelled'}, "
            f"{len(out[what][1])} numbers"
        )
    return out


def _check_summary(
    summary: list[tuple[int, str]], data: np.ndarray, path: Path, variant: TextVariant
) -> None:
    """Compare the printed means and standard deviations with the data read.

    Tolerance per column: half a unit of the summary's last printed digit
    (its own rounding) plus half a unit of the data column's last digit (the
    writer may have averaged unrounded values; rounding moves a mean or a
    std by at most that much). The std is accepted with ddof 0 or 1, since
    writers differ. A 7-number line is matched against (ax..gz, temp) and
    (time, ax..gz); the means decide which, the stds must then agree too.
    """
    values = _summary_values(summary, path, variant)
    data_half_ulp = 0.5 * 10.0 ** -np.array(COLUMN_DECIMALS, dtype=float)
    stats = {
        "means": (data.mean(axis=0),),
        "standard deviations": (
            data.std(axis=0, ddof=0),
            data.std(axis=0, ddof=1 if len(data) > 1 else 0),
        ),
    }
    columns = None
    for what in ("means", "standard deviations"):
        line_no, tokens = values[what]
        try:
            printed = np.array([float(tok) for tok in tokens])
        except ValueError:
            printed = np.array([])
        candidates = SUMMARY_COLUMNS.get(printed.size, ())
        if columns is not None and columns not in candidates:
            candidates = ()
        if not candidates or not np.isfinite(printed).all():
            raise IngestError(
                f"expected the column {what} (6, 7 or 8 numbers"
                + (f", as many as the {len(columns)} means" if columns else "")
                + f"), got {' '.join(tokens)[:80]!r}",
                file=path,
                line=line_no,
            )
        tol_printed = 0.5 * 10.0 ** -np.array([_decimals(tok) for tok in tokens], dtype=float)
        mismatch = None
        for cols in [columns] if columns else candidates:
            idx = np.array(cols)
            tol = (tol_printed + data_half_ulp[idx]) * (1 + 1e-9)
            ok = np.zeros(idx.size, dtype=bool)
            for computed in stats[what]:
                ok |= np.abs(computed[idx] - printed) <= tol
            if ok.all():
                columns = cols
                break
            if mismatch is None or (~ok).sum() < mismatch[2]:  # report the closer reading
                mismatch = (idx, int(np.flatnonzero(~ok)[0]), int((~ok).sum()))
        else:
            idx, j, _ = mismatch
            raise IngestError(
                f"the printed {what} disagree with the data: column '{COLUMN_NAMES[idx[j]]}' "
                f"prints {printed[j]:g}, the {len(data)} data lines give "
                f"{stats[what][0][idx[j]]:.6g}; the file is truncated or its parts do not "
                "belong together",
                file=path,
                line=line_no,
            )
    variant.summary.append("columns " + " ".join(COLUMN_NAMES[c] for c in columns))


def find_mpu6000_runs(folder: Path, complete: bool = True) -> dict[str, dict[str, Path]]:
    """MPU-6000 files in `folder` (not recursive), grouped by serial.

    Parameters
    ----------
    folder : a folder holding ``<serial>_<axis>_<sense>.txt`` files (any of the
        name variants :func:`parse_file_name` accepts).
    complete : if True, every serial must have all 12 files (six positions,
        six rotations); else partial sets are returned as found.

    Returns
    -------
    {serial: {label: path}}, serials and labels sorted.

    Raises
    ------
    IngestError naming the folder, the serial and the missing labels/files, or
    the two files that name the same segment (``x_dn`` and ``x_down``).
    """
    folder = Path(folder)
    runs: dict[str, dict[str, Path]] = {}
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() != ".txt":
            continue
        try:
            parsed = parse_file_name(path.name)
        except IngestError as exc:
            raise IngestError(exc.problem, file=path) from None
        if parsed is not None and path.is_file():
            serial, label = parsed
            other = runs.setdefault(serial, {}).setdefault(label, path)
            if other != path:
                raise IngestError(
                    f"two files of serial '{serial}' segment '{label}': {other.name} and "
                    f"{path.name}; keep one",
                    file=folder,
                )
    if complete:
        for serial, files in runs.items():
            check_complete(folder, serial, files)
    # Canonical segment order: x_up, x_dn, ..., z_cw.
    order = {label: i for i, label in enumerate(SIX_POSITION_LABELS)}
    return {s: dict(sorted(runs[s].items(), key=lambda kv: order[kv[0]])) for s in sorted(runs)}


# The MPU-6000 program's stages: stage 1 the six orientations, stage 2 the six rotations;
# a folder with one stage only is a valid run of that stage's procedure.
STAGE_PROCEDURES = (
    (SIX_POSITION_LABELS, "six_position_integral"),
    (STATIC_LABELS, "six_position"),
    (ROTATION_LABELS, "integral"),
)


def check_complete(folder: Path, serial: str, files: dict[str, Path]) -> str:
    """The procedure of a serial's files: all 12 (six_position_integral), the six
    orientations only (stage 1, six_position) or the six rotations only (stage 2, integral).

    Raises IngestError naming the missing files of the nearest complete set otherwise.
    """
    have = set(files)
    for labels, procedure in STAGE_PROCEDURES:
        if have == set(labels):
            return procedure
    # The nearest complete set: a stage whose labels hold all files, else both stages.
    labels, what = next(
        ((labels, name) for labels, name in _STAGE_NAMES if have <= set(labels)),
        (SIX_POSITION_LABELS, "stages 1 and 2"),
    )
    missing = [label for label in labels if label not in files]
    names = ", ".join(f"{serial}_{label}.txt" for label in missing)
    raise IngestError(
        f"serial '{serial}' has {len(files)} of the {len(labels)} MPU-6000 files of {what}; "
        f"missing {names}",
        file=folder,
    )


_STAGE_NAMES = ((STATIC_LABELS, "stage 1 (orientations)"), (ROTATION_LABELS, "stage 2 (rotations)"))
