"""The ``[format]`` section of a run manifest: the layout and units of a run's data files.

``kind`` picks the reader (pipelines.ingest.readers); the other fields describe a
delimited text file (CSV and its variants, docs/manifest.md). Readers of other
formats (MAT, MCAP) keep their own keys there and read ``FormatSpec.extra``.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from calib_core.settings import Setting, SettingError, Settings, typed
from calib_core.units import acceleration_factor, angular_rate_factor, time_factor
from pipelines.ingest.errors import IngestError

# Formats a reader exists for; readers register in pipelines.ingest.readers.
# Extend this tuple when adding a format.
FORMAT_KINDS = ("csv", "mpu6000", "mat", "mcap", "ulog", "dataflash", "rosbag", "imutk")
DELIMITERS = {",": ",", ";": ";", "\t": "\t", "tab": "\t", "whitespace": "whitespace"}

Column = str | int  # a column name, or a 0-based index when the file has no header
PROGRESS_THRESHOLD_BYTES = 64 * 2**20  # a data file above: its reading shows progress on stderr
COUNTS = "counts"  # acc_unit / gyr_unit of raw sensor counts, with *_scale and *_offset


@dataclass(frozen=True)
class FormatRules:
    """Layout of the data files (`FormatSpec`, declared by `FORMAT`).

    ``kind`` picks the reader. The CSV fields describe a delimited text file; readers of
    other kinds find their own keys in ``extra``. ``given``: the keys the manifest gives and
    those that differ from their default; a header's units apply to the others.

    Columns are header names, or 0-based indices when ``header = false``.
    Units are names from calib_core.units (``m/s^2``, ``g``, ``mg``, ``deg/s``,
    ``rad/s``, ``deg/h``, ... ; time ``s``, ``ms``, ``us``, ``ns`` or ``datenum``).
    ``reference_columns`` maps reference channel names (``table_angle``,
    ``table_rate``) to columns already in SI units (rad, rad/s).
    """

    extra: dict[str, Any] = field(default_factory=dict)
    given: frozenset[str] = frozenset()

    def __post_init__(self) -> None:
        """SettingError naming ``format.key``, or ``format`` for a problem of the whole."""
        values = {s.name: getattr(self, s.name) for s in FORMAT}
        FORMAT.validate(values, "", "format")
        defaults = FORMAT.defaults()
        given = self.given | {k for k, v in values.items() if v != defaults[k]}
        object.__setattr__(self, "given", frozenset(given))
        if self.kind is None:
            raise SettingError("kind", "required field is missing", "format")
        if self.kind not in FORMAT_KINDS:
            known = ", ".join(FORMAT_KINDS)
            problem = f"unknown format kind {self.kind!r}; expected one of: {known}"
            raise SettingError("kind", problem, "format")
        if self.delimiter is not None and self.delimiter not in DELIMITERS:
            raise SettingError("delimiter", f"unknown delimiter {self.delimiter!r}; expected "
                               "one of ',', ';', 'tab', 'whitespace' (or leave it out to "
                               "detect it)", "format")  # fmt: skip
        object.__setattr__(self, "delimiter", DELIMITERS.get(self.delimiter))
        for key in ("acc_unit", "acc_scale_unit", "gyr_unit", "gyr_scale_unit", "time_unit"):
            try:
                _check_unit(key, getattr(self, key))
            except ValueError as exc:
                raise SettingError(key, str(exc), "format") from None
        for key in ("acc_scale", "acc_offset", "gyr_scale", "gyr_offset"):
            value = getattr(self, key)  # 3 finite numbers (FORMAT), as floats
            object.__setattr__(self, key, None if value is None else [float(v) for v in value])
        for key in ("acc_columns", "gyr_columns"):
            value = getattr(self, key)
            if value is not None and len(value) != 3:
                problem = f"expected 3 columns (x, y, z), got {len(value)}"
                raise SettingError(key, problem, "format")
            if value is not None and not all(isinstance(c, str | int) for c in value):
                problem = f"expected column names or 0-based indices, got {value!r}"
                raise SettingError(key, problem, "format")
        try:
            self._complete()
        except ValueError as exc:
            raise SettingError("format", str(exc), "") from None

    def _complete(self) -> None:
        if self.kind == "csv":
            needed = ["acc_columns", "gyr_columns"]
            if self.sample_rate_hz is None or self.time_unit == "samples":
                needed.insert(0, "time_column")
            missing = [name for name in needed if getattr(self, name) is None]
            # All three left out: the reader recognises common names in the header.
            recognise = self.header and self.acc_columns is None and self.gyr_columns is None
            if missing and not (recognise and self.time_column is None):
                raise ValueError(
                    f"format kind 'csv' needs {', '.join(missing)} (or, with a header, leave "
                    "out time_column, acc_columns and gyr_columns to recognise common names)"
                )
        for sensor in ("acc", "gyr"):
            counts = getattr(self, f"{sensor}_unit") == COUNTS
            if counts and getattr(self, f"{sensor}_scale") is None:
                raise ValueError(
                    f"{sensor}_unit = 'counts' needs {sensor}_scale (counts per "
                    f"{sensor}_scale_unit, per axis) and optionally {sensor}_offset (counts)"
                )
            given = [f for f in ("scale", "offset") if getattr(self, f"{sensor}_{f}") is not None]
            if given and not counts:
                raise ValueError(
                    f"{sensor}_{given[0]} applies only to {sensor}_unit = 'counts', "
                    f"got {sensor}_unit = {getattr(self, f'{sensor}_unit')!r}"
                )
            if counts and 0.0 in getattr(self, f"{sensor}_scale"):
                raise ValueError(f"{sensor}_scale must not be 0")
        if self.time_unit == "samples" and self.sample_rate_hz is None:
            raise ValueError("time_unit = 'samples' needs sample_rate_hz")

    def acc_reference_factor(self) -> float:
        """Factor from the unit of segments' ``reference_acc`` to m/s^2.

        That unit is ``acc_unit``; for raw counts it is ``acc_scale_unit`` (a
        reference in counts would need the scale the calibration is to find).
        """
        unit = self.acc_scale_unit if self.acc_unit == COUNTS else self.acc_unit
        return acceleration_factor(unit)

    def columns(self) -> list[Column]:
        """All data columns named here, time first (CSV layouts)."""
        cols: list[Column] = [self.time_column] if self.time_column is not None else []
        cols += list(self.acc_columns or []) + list(self.gyr_columns or [])
        if self.temp_column is not None:
            cols.append(self.temp_column)
        return cols + list(self.reference_columns.values())


def _check_unit(key: str, value: str) -> None:
    """ValueError unless `value` is a unit of `key`'s quantity (calib_core.units' tables, the
    one list of accepted names); raw counts for acc_unit / gyr_unit. Time also ``datenum``
    (MATLAB day number), ``iso`` (ISO-8601 text) and ``samples`` (an index / sample_rate_hz)."""
    if key == "time_unit":
        if value not in ("datenum", "iso", "samples"):
            time_factor(value)
    elif not (value == COUNTS and not key.endswith("scale_unit")):
        (acceleration_factor if key.startswith("acc") else angular_rate_factor)(value)


def _columns(name: str, meaning: str) -> Setting:
    return Setting(name, ("text", "integer"), "", None, meaning)


FORMAT = Settings(
    Setting("kind", "text", "", None, "the reader (FORMAT_KINDS; required)"),
    Setting("delimiter", "text", "", None, "',', ';', 'tab', 'whitespace' (None: detect)"),
    Setting("decimal", "text", "", None, "decimal mark (None: detect)", choices=(".", ",")),
    Setting("header", "bool", "", True, "a header line names the columns"),
    Setting("skip_lines", "integer", "", None, "lines before the header (None: detect)", low=0),
    # Segments pick their rows by `section` (default: their label). None: a 'part', 'label'
    # or 'section' column, used when a segment gives `section`.
    _columns("section_column", "column naming each row's segment"),
    _columns("time_column", "the time column"),
    Setting("time_unit", "text", "", "s", "unit of the time column"),
    Setting("acc_columns", "list", "", None, "accelerometer columns (x, y, z)"),
    Setting("acc_unit", "text", "", "m/s^2", "unit of the accelerometer columns"),
    Setting("gyr_columns", "list", "", None, "gyro columns (x, y, z)"),
    Setting("gyr_unit", "text", "", "rad/s", "unit of the gyro columns"),
    _columns("temp_column", "the temperature column (degC)"),
    Setting("reference_columns", "table", "", {}, "reference channel -> column (SI units)"),
    # Time from a sample rate: no time column, or time_unit = "samples" (a sample index).
    Setting("sample_rate_hz", "number", "Hz", None, "sample rate", low=0.0, low_open=True),
    # Raw counts (acc_unit / gyr_unit = "counts"): value = (raw - offset) / scale, where
    # scale is counts per one `*_scale_unit` (e.g. LSB per g, LSB per deg/s), per axis.
    *(Setting(f"{s}_{k}", "list", "", None, f"{s} raw counts' {k} (x, y, z)", length=3)
      for s in ("acc",) for k in ("scale", "offset")),
    Setting("acc_scale_unit", "text", "", "m/s^2", "unit counted by acc_scale"),
    *(Setting(f"{s}_{k}", "list", "", None, f"{s} raw counts' {k} (x, y, z)", length=3)
      for s in ("gyr",) for k in ("scale", "offset")),
    Setting("gyr_scale_unit", "text", "", "rad/s", "unit counted by gyr_scale"),
    name="FormatSpec", noun="field", base=FormatRules,
)  # fmt: skip
FormatSpec = FORMAT.type


def format_spec(value: Any) -> FormatSpec:
    """``[format]`` typed: its declared keys checked (texts stripped, whole numbers of a
    number as floats), a reader's own keys kept in ``extra``; SettingError naming the key."""
    if not isinstance(value, Mapping):
        raise SettingError("format", f"expected a table, got {value!r}", "")
    known = {k: v for k, v in value.items() if k in FORMAT}
    fmt = typed(FORMAT, known, "format", ("kind",))
    extra = {k: v for k, v in value.items() if k not in FORMAT}
    return dataclasses.replace(fmt, extra=extra, given=frozenset(known))


def format_dict(fmt: FormatSpec, given_only: bool = False) -> dict[str, Any]:
    """The [format] as the manifest writes it: every declared key (or only those given),
    then the reader's own keys."""
    keys = [s.name for s in FORMAT if not given_only or s.name in fmt.given]
    return {**{k: copy.deepcopy(getattr(fmt, k)) for k in keys}, **fmt.extra}


def extra_keys(fmt: FormatSpec, kind: str, keys: tuple[str, ...]) -> dict:
    """The reader's own keys of [format]; IngestError for any other key."""
    extra = dict(fmt.extra)
    unknown = sorted(set(extra) - set(keys))
    if unknown:
        raise IngestError(
            f"unknown key {unknown[0]!r} for format kind '{kind}'; expected: "
            + (", ".join(keys) or "none"),
            field=f"format.{unknown[0]}",
        )
    return extra
