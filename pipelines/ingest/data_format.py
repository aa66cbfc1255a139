"""The ``[format]`` section of a run manifest: the layout and units of a run's data files.

``kind`` picks the reader (pipelines.ingest.readers); the other fields describe a
delimited text file (CSV and its variants, docs/manifest.md). Readers of other
formats (MAT, MCAP) keep their own keys there and read ``FormatSpec.model_extra``.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)

from calib_core.units import acceleration_factor, angular_rate_factor, time_factor
from pipelines.ingest.errors import IngestError

# Formats a reader exists for; readers register in pipelines.ingest.readers.
# Extend this tuple when adding a format.
FORMAT_KINDS = ("csv", "mpu6000", "mat", "mcap", "ulog", "dataflash", "rosbag", "imutk")
DELIMITERS = {",": ",", ";": ";", "\t": "\t", "tab": "\t", "whitespace": "whitespace"}

Column = str | int  # a column name, or a 0-based index when the file has no header
PROGRESS_THRESHOLD_BYTES = 64 * 2**20  # a data file above: its reading shows progress on stderr
COUNTS = "counts"  # acc_unit / gyr_unit of raw sensor counts, with *_scale and *_offset


class FormatSpec(BaseModel):
    """Layout of the data files.

    ``kind`` picks the reader. The CSV fields below describe a delimited text
    file; readers of other kinds find their own keys in ``model_extra``.

    Columns are header names, or 0-based indices when ``header = false``.
    Units are names from calib_core.units (``m/s^2``, ``g``, ``mg``, ``deg/s``,
    ``rad/s``, ``deg/h``, ... ; time ``s``, ``ms``, ``us``, ``ns`` or ``datenum``).
    ``reference_columns`` maps reference channel names (``table_angle``,
    ``table_rate``) to columns already in SI units (rad, rad/s).
    """

    model_config = ConfigDict(extra="allow", str_strip_whitespace=True)

    kind: str
    delimiter: str | None = None  # None: detect among , ; tab whitespace
    decimal: Literal[".", ","] | None = None  # None: detect (',' inside ';'/tab fields)
    header: bool = True
    skip_lines: int | None = Field(default=None, ge=0)  # lines before the header; None: detect
    # Column naming each row's segment (values such as "x_up", "x_p"); segments pick theirs
    # by `section` (default: their label). None: a 'part', 'label' or 'section' column, used
    # when a segment gives `section`.
    section_column: Column | None = None
    time_column: Column | None = None
    time_unit: str = "s"
    acc_columns: list[Column] | None = None
    acc_unit: str = "m/s^2"
    gyr_columns: list[Column] | None = None
    gyr_unit: str = "rad/s"
    temp_column: Column | None = None
    reference_columns: dict[str, Column] = Field(default_factory=dict)
    # Time from a sample rate: no time column, or time_unit = "samples" (a sample index).
    sample_rate_hz: float | None = Field(default=None, gt=0.0)
    # Raw counts (acc_unit / gyr_unit = "counts"): value = (raw - offset) / scale, where
    # scale is counts per one `*_scale_unit` (e.g. LSB per g, LSB per deg/s), per axis.
    acc_scale: list[float] | None = None
    acc_offset: list[float] | None = None
    acc_scale_unit: str = "m/s^2"
    gyr_scale: list[float] | None = None
    gyr_offset: list[float] | None = None
    gyr_scale_unit: str = "rad/s"

    @field_validator("kind")
    @classmethod
    def _known_kind(cls, value: str) -> str:
        if value not in FORMAT_KINDS:
            known = ", ".join(FORMAT_KINDS)
            raise ValueError(f"unknown format kind {value!r}; expected one of: {known}")
        return value

    @field_validator("delimiter")
    @classmethod
    def _known_delimiter(cls, value: str | None) -> str | None:
        if value is None:
            return None
        if value not in DELIMITERS:
            raise ValueError(
                f"unknown delimiter {value!r}; expected one of ',', ';', 'tab', 'whitespace' "
                "(or leave it out to detect it)"
            )
        return DELIMITERS[value]

    # The unit tables of calib_core.units are the one list of accepted names.
    @field_validator("acc_unit", "acc_scale_unit", "gyr_unit", "gyr_scale_unit")
    @classmethod
    def _sensor_unit(cls, value: str, info: ValidationInfo) -> str:
        """A known unit of the sensor's quantity; raw counts for acc_unit / gyr_unit."""
        if value == COUNTS and not info.field_name.endswith("scale_unit"):
            return value
        factor = acceleration_factor if info.field_name.startswith("acc") else angular_rate_factor
        factor(value)
        return value

    @field_validator("time_unit")
    @classmethod
    def _time_unit(cls, value: str) -> str:
        # datenum: MATLAB serial day number (-> Unix s); iso: ISO-8601 text (-> Unix s);
        # samples: a sample index, divided by sample_rate_hz.
        if value not in ("datenum", "iso", "samples"):
            time_factor(value)
        return value

    @field_validator("acc_scale", "acc_offset", "gyr_scale", "gyr_offset")
    @classmethod
    def _three_numbers(cls, value: list[float] | None) -> list[float] | None:
        if value is not None and (len(value) != 3 or not all(math.isfinite(v) for v in value)):
            raise ValueError(f"expected 3 finite numbers (x, y, z), got {value}")
        return value

    @field_validator("acc_columns", "gyr_columns")
    @classmethod
    def _three(cls, value: list[Column] | None) -> list[Column] | None:
        if value is not None and len(value) != 3:
            raise ValueError(f"expected 3 columns (x, y, z), got {len(value)}")
        return value

    @model_validator(mode="after")
    def _csv_complete(self) -> FormatSpec:
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
        return self

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


def extra_keys(fmt: FormatSpec, kind: str, keys: tuple[str, ...]) -> dict:
    """The reader's own keys of [format]; IngestError for any other key."""
    extra = dict(fmt.model_extra or {})
    unknown = sorted(set(extra) - set(keys))
    if unknown:
        raise IngestError(
            f"unknown key {unknown[0]!r} for format kind '{kind}'; expected: "
            + (", ".join(keys) or "none"),
            field=f"format.{unknown[0]}",
        )
    return extra
