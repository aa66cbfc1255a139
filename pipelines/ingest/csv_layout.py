"""CSV reader, the column plan: which column of a delimited text file holds which role.

`layout_of` resolves the manifest's ``[format]`` columns (header names, or 0-based
indices without a header) against the file's first line, or recognises common
names (`COMMON_NAMES`) when the manifest names none; `header_units` takes the
units a header gives (``acc_x [g]``). The reader (pipelines.ingest.csv_reader)
and its diagnosis of bad lines (pipelines.ingest.csv_diagnosis) read by this plan.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from calib_core.settings import SettingError
from pipelines.ingest.csv_dialect import is_number, sniff, split_unit
from pipelines.ingest.data_format import Column, FormatSpec
from pipelines.ingest.errors import IngestError

AXES = "xyz"
CHANNELS = (*(f"gyr_{a}" for a in AXES), *(f"acc_{a}" for a in AXES))  # [gyr | acc]
# Recognised column names (case-insensitive) when the manifest names no columns.
# "{a}" is the axis letter. A name matching two roles, or a role matched by two
# columns, is an error that lists the candidates.
_PATTERNS = {
    "acc": (
        "acc_{a}", "acc{a}", "acc.{a}", "a{a}", "a_{a}", "accel_{a}", "accel{a}", "accel.{a}",
        "accelerometer_{a}", "accelerometer.{a}", "linear_acceleration.{a}",
        "linear_acceleration_{a}",
    ),
    "gyr": (
        "gyr_{a}", "gyr{a}", "gyr.{a}", "gyro_{a}", "gyro{a}", "gyro.{a}", "g{a}", "g_{a}",
        "w{a}", "w_{a}", "omega_{a}", "gyroscope_{a}", "gyroscope.{a}",
        "angular_velocity.{a}", "angular_velocity_{a}",
    ),
}  # fmt: skip
COMMON_NAMES: dict[str, tuple[str, ...]] = {
    "time": ("t", "time", "time_s", "timestamp", "stamp", "header.stamp", "ts"),
    **{
        f"{sensor}_{a}": tuple(p.format(a=a) for p in patterns)
        for sensor, patterns in _PATTERNS.items()
        for a in AXES
    },
    "temp": ("temp", "temperature", "temp_c", "temperature_c", "temperature.temperature"),
}
SECTION_NAMES = ("part", "label", "section")  # a column naming each row's segment
_NO_HEADER_HINT = (
    "; that line holds only numbers: a file without a header (as imu_tk writes) needs "
    "header = false and the columns by index in [format] (time_column = 0, acc_columns = [1, 2, 3])"
)


@dataclass
class CsvLayout:
    """Where the data of one file is: delimiter, column names and the columns of each role."""

    path: Path
    delimiter: str
    names: list[str]  # every column of the file (header names, or "c0", "c1", ...)
    data_start: int  # 1-based line of the first line after the header (or of the file)
    roles: dict[str, str]  # role ("time", "acc_x", ..., "temp", "ref:<name>") -> column name
    fields: dict[str, str]  # column name -> manifest field or column name, for messages
    decimal: str = "."
    metadata: tuple[str, ...] = ()  # lines before the header
    sections: dict[str, int] = dataclasses.field(default_factory=dict)  # value -> code

    def line_of_row(self, row: int) -> int:
        """1-based line number of 0-based data row `row` (blank lines are not rows)."""
        seen = -1
        with self.path.open("r", encoding="utf-8-sig", errors="replace") as fh:
            for number, line in enumerate(fh, start=1):
                if number >= self.data_start and line.strip():
                    seen += 1
                    if seen == row:
                        return number
        return self.data_start + row


def layout_of(
    path: Path,
    fmt: FormatSpec,
    sensors: tuple[str, ...] = ("acc", "gyr"),
    sections: bool = False,
) -> CsvLayout:
    """Resolve the manifest's columns (or recognise common names) against the file's first line.

    Parameters
    ----------
    path : the data file.
    fmt : the ``[format]`` section.
    sensors : the triads this file must hold (``("acc",)`` for a separate acc file).
    sections : find the section column (``format.section_column`` or a ``part``,
        ``label`` or ``section`` column) as role ``"section"``.

    Raises
    ------
    IngestError naming the file, the line and the manifest field of a column
    that is not in the file, or listing the candidates of an ambiguous or
    unrecognised column.
    """
    path = Path(path)
    dialect = sniff(path, fmt)
    delimiter = dialect.delimiter
    present = names = dialect.names
    first_no = dialect.header_line or dialect.data_start
    if fmt.header and len(set(names)) != len(names):
        repeated = sorted({n for n in names if names.count(n) > 1})
        raise IngestError(f"the header repeats column names {repeated}", file=path, line=first_no)
    roles: dict[Column, str] = {}
    if fmt.acc_columns is None and fmt.gyr_columns is None:
        wanted = _recognise(path, present, first_no, sensors, fmt)
    else:
        wanted = {}
        if fmt.time_column is not None:
            wanted["time"] = (fmt.time_column, "format.time_column")
        for sensor in sensors:
            for a, col in zip(AXES, getattr(fmt, f"{sensor}_columns") or [], strict=True):
                wanted[f"{sensor}_{a}"] = (col, f"format.{sensor}_columns")
        if fmt.temp_column is not None and "acc" in sensors:
            wanted["temp"] = (fmt.temp_column, "format.temp_column")
    if "acc" in sensors:
        for name, col in fmt.reference_columns.items():
            wanted[f"ref:{name}"] = (col, f"format.reference_columns.{name}")
    if sections:
        wanted["section"] = _section_column(path, present, first_no, fmt)
    fields: dict[str, str] = {}
    bases = {split_unit(name)[0]: name for name in present}
    for role, (col, field) in wanted.items():
        if fmt.header:
            col = bases.get(col, col) if col not in present else col  # "acc_x" for "acc_x [g]"
            if col not in present:
                raise IngestError(
                    f"column {col!r} named in the manifest is not in the header; "
                    f"the header has: {', '.join(present)}",
                    file=path,
                    line=first_no,
                    field=field,
                )
            name = str(col)
        else:
            if not (isinstance(col, int) and 0 <= col < len(present)):
                raise IngestError(
                    f"column {col!r}: without a header, columns are 0-based indices "
                    f"below {len(present)} (the first line has {len(present)} columns)",
                    file=path,
                    line=first_no,
                    field=field,
                )
            name = names[col]
        roles[role] = name
        fields[name] = str(col)
    return CsvLayout(
        path=path,
        delimiter=delimiter,
        names=names,
        data_start=dialect.data_start,
        roles=roles,
        fields=fields,
        decimal=dialect.decimal,
        metadata=tuple(dialect.metadata),
    )


def _section_column(
    path: Path, header: list[str], line: int, fmt: FormatSpec
) -> tuple[Column, str]:
    """The section column: the manifest's, else the one 'part', 'label' or 'section' column."""
    if fmt.section_column is not None:
        return fmt.section_column, "format.section_column"
    hits = [h for h in header if split_unit(h)[0].lower() in SECTION_NAMES]
    if len(hits) != 1:
        raise IngestError(
            f"segments give 'section' but the file has {'no' if not hits else 'several'} "
            f"section column ({', '.join(hits) or 'header: ' + ', '.join(header)}); expected one "
            f"of {', '.join(SECTION_NAMES)} or format.section_column",
            file=path,
            line=line,
            field="format.section_column",
        )
    return hits[0], "format.section_column"


def _recognise(
    path: Path, header: list[str], line: int, sensors: tuple[str, ...], fmt: FormatSpec
) -> dict[str, tuple[str, str]]:
    """Map roles to header columns by `COMMON_NAMES`; errors list the candidates."""
    wanted_roles = [f"{s}_{a}" for s in sensors for a in AXES]
    if fmt.time_column is None and fmt.sample_rate_hz is None:
        wanted_roles.insert(0, "time")
    if "acc" in sensors and fmt.temp_column is None:
        wanted_roles.append("temp")
    out: dict[str, tuple[str, str]] = {}
    if fmt.time_column is not None:
        out["time"] = (fmt.time_column, "format.time_column")
    for role in wanted_roles:
        hits = [h for h in header if split_unit(h)[0].lower() in COMMON_NAMES[role]]
        if len(hits) > 1:
            raise IngestError(
                f"ambiguous {role} column: {', '.join(hits)} all look like {role}; "
                "name the columns in [format] (time_column, acc_columns, gyr_columns)",
                file=path,
                line=line,
                field="format",
            )
        if hits:
            out[role] = (hits[0], "format")
        elif role != "temp":  # temperature is optional
            raise IngestError(
                f"no {role} column recognised in the header; found: {', '.join(header)}; "
                f"expected one of {', '.join(COMMON_NAMES[role][:6])}, ... (any case, "
                "optionally with a unit as 'acc_x [g]'), or name the columns in [format]"
                + (" or give sample_rate_hz" if role == "time" else "")
                + (_NO_HEADER_HINT if all(is_number(h) for h in header) else ""),
                file=path,
                line=line,
                field="format",
            )
    if fmt.temp_column is not None and "acc" in sensors:
        out["temp"] = (fmt.temp_column, "format.temp_column")
    return out


def header_units(layout: CsvLayout, fmt: FormatSpec) -> FormatSpec:
    """`fmt` with the units the header names give (``acc_x [g]``), unless the manifest sets them.

    Raises IngestError naming the column when the three axes of a triad carry
    different units or a unit is unknown.
    """
    update: dict[str, str] = {}
    for key, roles in (
        ("time_unit", ("time",)),
        ("acc_unit", tuple(f"acc_{a}" for a in AXES)),
        ("gyr_unit", tuple(f"gyr_{a}" for a in AXES)),
    ):
        units = {split_unit(layout.roles[r])[1] for r in roles if r in layout.roles}
        units.discard(None)
        if not units or key in fmt.given:
            continue
        if len(units) > 1:
            names = ", ".join(layout.roles[r] for r in roles if r in layout.roles)
            raise IngestError(
                f"the columns {names} carry different units; expected one unit per triad "
                f"(or set format.{key})",
                file=layout.path,
                line=layout.data_start - 1,
                field=f"format.{key}",
            )
        update[key] = units.pop()
    if not update:
        return fmt
    try:
        return dataclasses.replace(fmt, **update, given=fmt.given | set(update))
    except SettingError as exc:
        key = next(iter(update))
        raise IngestError(
            f"unit in the header not understood: {exc.problem}; set format.{key} to override",
            file=layout.path,
            line=layout.data_start - 1,
            field=f"format.{key}",
        ) from None
