"""The run manifest (``run.toml``): what a lab run is, where, with what, and which data is which.

The manifest is the lab's statement about a run: the unit under test, when and
by whom, the site (for local gravity), the environment, the equipment with its
calibration dates, the procedure and its settings, the tolerance profile, the
layout of the data files and which file or time window holds which segment.
docs/manifest.md describes every field with an example.

Every section forbids unknown keys, so a typo in a field name is an error rather
than a silently ignored value. ``[unit]``, ``[acquisition]``, ``[site]``,
``[environment]`` and ``[[equipment]]`` are declared as settings (calib_core.settings;
the last three in storage.run_input, as the archive keeps them); ``[run]``,
``[[segments]]``, ``[format]`` (pipelines.ingest.data_format) and the whole
(`run_manifest`) too. ``[format]`` is the one section with other keys: readers of other
formats (MAT, MCAP) keep their own keys there (``variables``, ``topics``, ...) and read
them from ``FormatSpec.extra``.

Times: ``run.started`` may be a TOML datetime or an ISO-8601 string. A value
without a UTC offset is taken as UTC (labs log in UTC or say their offset); it
is always stored converted to UTC.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import math
import re
import sys
import tomllib
from datetime import UTC, datetime
from pathlib import Path, PurePosixPath
from typing import Any

from calib_core import procedures
from calib_core.earth import local_gravity
from calib_core.settings import Setting, SettingError, Settings, key_line, key_path, typed
from pipelines.ingest.data_format import format_spec
from pipelines.ingest.errors import IngestError
from pipelines.ingest.free_text import check_free_text
from storage.naming import check_safe_name
from storage.run_input import ENVIRONMENT, SITE, Site, equipment_in

SCHEMA_VERSION = 1

# Segment labels of the six-position + integral procedures: the static
# positions ("x_up": x axis reads +g) and the rotations about a vertical axis
# (ccw = positive sense about that axis).
STATIC_LABELS = ("x_up", "x_dn", "y_up", "y_dn", "z_up", "z_dn")
ROTATION_LABELS = ("x_ccw", "x_cw", "y_ccw", "y_cw", "z_ccw", "z_cw")
SIX_POSITION_LABELS = STATIC_LABELS + ROTATION_LABELS


UNIT = Settings(
    Setting("serial", "text", "", None, "the unit's serial (a folder name in the archive)"),
    Setting("model", "text", "", None, "its model"),
    Setting("manufacturer", "text", "", None, "its manufacturer"),
    Setting("specification", "text", "", None, "free text: ranges, grade, data sheet"),
    # The sensor's full scale as set for this run; None: the model's (MODEL_RANGES), if known.
    Setting("gyro_range_dps", "number", "deg/s", None, "gyro full scale", low=0, low_open=True),
    Setting("acc_range_g", "number", "g", None, "accelerometer full scale", low=0, low_open=True),
    name="UnitSpec",
    noun="field",
)
UnitSpec = UNIT.type  # the unit under test


# Full scale (gyro deg/s, accelerometer g) of sensor models as their calibration program
# sets them, by lower-case model name. MPU-6000: the program's manual keeps the readings
# within +-250 deg/s and +-2 g (docs/methods.md 5; the chip's smallest ranges). A run on other
# settings says so in [unit] gyro_range_dps / acc_range_g or [run.settings] gyro_range_dps.
MODEL_RANGES: dict[str, tuple[float, float]] = {"mpu-6000": (250.0, 2.0)}


def sensor_ranges(unit: UnitSpec, settings: dict[str, Any]) -> tuple[float | None, float | None]:
    """(gyro full scale deg/s, accelerometer full scale g) of a run, None where unknown.

    The gyro range is [run.settings] gyro_range_dps, else [unit] gyro_range_dps, else the
    model's (MODEL_RANGES); the accelerometer range [unit] acc_range_g, else the model's.
    """
    gyro_model, acc_model = MODEL_RANGES.get(unit.model.strip().lower(), (None, None))
    gyro = settings.get("gyro_range_dps", unit.gyro_range_dps)
    gyro = gyro_model if gyro is None else gyro
    acc = acc_model if unit.acc_range_g is None else unit.acc_range_g
    return (None if gyro is None else float(gyro)), acc


RUN = Settings(
    Setting("started", "datetime", "", None, "when the run started (no offset: UTC)"),
    Setting("operator", "text", "", None, "who ran it"),
    Setting("procedure", "text", "", None, "calib_core.procedures' name"),
    Setting("tolerance_profile", "text", "", None, "the profile's file name"),
    Setting("settings", "table", "", {}, "the procedure's: turns, gyro_range_dps, solver..."),
    name="RunSpec",
    noun="field",
)
RunSpec = RUN.type  # when, who, which procedure and tolerance profile


def run_spec(value: Any) -> RunSpec:
    """``[run]`` typed: ``started`` (a TOML datetime or ISO-8601 text) in UTC, the
    tolerance profile a safe file name; SettingError naming the key."""
    if isinstance(value, dict) and isinstance(value.get("started"), str):
        with contextlib.suppress(ValueError):  # else refused by name
            value = {**value, "started": datetime.fromisoformat(value["started"].strip())}
    run = typed(RUN, value, "run", ("started", "operator", "procedure", "tolerance_profile"))
    try:
        check_safe_name(run.tolerance_profile, "tolerance profile name")  # names a file
    except ValueError as exc:
        raise SettingError("tolerance_profile", str(exc), "run") from None
    started = run.started  # documented choice: a naive time is UTC
    utc = started.replace(tzinfo=UTC) if started.tzinfo is None else started.astimezone(UTC)
    return dataclasses.replace(run, started=utc)


SiteSpec = Site  # [site]: storage.run_input.SITE


# How the data were taken, where the files do not say it; every field optional.
ACQUISITION = Settings(
    Setting("settle_s", "number", "s", None, "wait before recording each attitude", low=0.0),
    Setting("resolution_bits", "integer", "bit", None, "of the sensor's converter", low=1),
    name="AcquisitionSpec",
    noun="field",
)
AcquisitionSpec = ACQUISITION.type


# Converter resolution of sensor models (bits), by lower-case model name: the MPU-6000's
# accelerometer and gyro converters are 16 bit (InvenSense data sheet).
MODEL_RESOLUTION_BITS: dict[str, int] = {"mpu-6000": 16}


class SegmentRules:
    """Which file (and optionally which time window of it, s) holds one segment.

    The window is ``start_s <= t < end_s`` on the file's own time axis after
    conversion to seconds; a missing bound means the file's start / end.
    ``verification = true`` keeps the segment out of the fit; it is used only
    to verify the calibration. ``reference_acc`` is the true specific force of a
    static verification segment in the format's ``acc_unit`` (x, y, z), needed
    for attitudes other than "<axis>_<up|dn>..." labels.

    A segment's data is one ``file`` holding time, acc and gyr (and temp), or,
    for loggers that write each sensor to its own file, ``acc_file`` (time,
    acc, temp) and ``gyr_file`` (time, gyr) with the same time stamps; both
    are read with the same ``[format]`` columns (kind ``csv`` only).
    """

    @property
    def files(self) -> tuple[str, ...]:
        """The data files of this segment: (file,) or (acc_file, gyr_file)."""
        return (self.file,) if self.file is not None else (self.acc_file, self.gyr_file)

    def check(self, where: str) -> None:
        """SettingError naming ``where.key`` (``segments[2].file``): a label or file name
        that may not be one, no data file or two kinds, an empty time window."""
        if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}", self.label):
            raise SettingError("label", f"invalid segment label {self.label!r}: expected "
                               "letters, digits, '_', '.', '+', '-'", where)  # fmt: skip
        for key in ("file", "acc_file", "gyr_file"):
            try:
                if getattr(self, key) is not None:
                    check_relative_name(getattr(self, key))
            except ValueError as exc:
                raise SettingError(key, str(exc), where) from None
        split = (self.acc_file is not None, self.gyr_file is not None)
        if self.file is None and split != (True, True):
            problem = (
                "a segment needs 'file', or both 'acc_file' and 'gyr_file' (separate sensor files)"
            )
            raise SettingError(where, problem, "")
        if self.file is not None and any(split):
            raise SettingError(where, "give either 'file' or 'acc_file' + 'gyr_file', not both", "")
        if self.start_s is not None and self.end_s is not None and not self.end_s > self.start_s:
            problem = f"end_s ({self.end_s}) must be greater than start_s ({self.start_s})"
            raise SettingError(where, problem, "")


SEGMENT = Settings(
    Setting("label", "text", "", None, "the segment's label (required)"),
    *(Setting(k, "text", "", None, meaning) for k, meaning in {
        "file": "the data file", "acc_file": "the accelerometer's file (with gyr_file)",
        "gyr_file": "the gyro's file (with acc_file)"}.items()),
    Setting("start_s", "number", "s", None, "window start (None: the file's)"),
    Setting("end_s", "number", "s", None, "window end, exclusive (None: the file's)"),
    Setting("section", "text", "", None, "the value of [format] section_column for its rows"),
    Setting("verification", "bool", "", False, "kept out of the fit, used to verify it"),
    Setting("reference_acc", "list", "", None, "true specific force (x, y, z)", length=3),
    name="SegmentSpec",
    noun="field",
    base=SegmentRules,
)  # fmt: skip
SegmentSpec = SEGMENT.type


def check_relative_name(value: str) -> str:
    """Return `value` if it names a file inside the run folder, else raise ValueError.

    Accepted: a relative POSIX path such as ``imu.csv`` or ``raw/imu.csv``.
    Refused: absolute paths, drive letters, backslashes, ``..`` components.
    """
    path = PurePosixPath(value)
    if (
        not value
        or "\\" in value
        or path.is_absolute()
        or re.match(r"^[A-Za-z]:", value)
        or any(part in ("..", "") for part in value.split("/"))
    ):
        raise ValueError(
            f"segment file {value!r} must be a relative name inside the run folder "
            "(no absolute path, no '..', '/' as separator)"
        )
    return value


class ManifestRules:
    """What a `RunManifest` says beyond its sections: local gravity, stated conditions."""

    def gravity(self) -> float:
        """Local gravity for this site by the manifest's model, m/s^2."""
        s = self.site
        return local_gravity(s.model, s.latitude_deg, s.height_m, s.gravity)

    def recorded_conditions(self) -> dict[str, float | None]:
        """The conditions the lab states, keyed as calib_core.conditions checks them."""
        env, acq = self.environment, self.acquisition
        bits = acq.resolution_bits
        if bits is None:
            bits = MODEL_RESOLUTION_BITS.get(self.unit.model.strip().lower())
        return {
            "ambient_temperature_c": env.temperature_c,
            "temperature_drift_c_per_h": env.temperature_drift_c_per_h,
            "humidity_pct": env.humidity_pct,
            "pressure_hpa": env.pressure_hpa,
            "warmup_min": env.warmup_min,
            "settle_s": acq.settle_s,
            "resolution_bits": None if bits is None else float(bits),
        }

    def verification_labels(self) -> set[str]:
        """Labels of segments kept out of the fit."""
        return {s.label for s in self.segments if s.verification}


# A whole ``run.toml`` (docs/manifest.md): its sections, each typed by `run_manifest`.
MANIFEST = Settings(
    Setting("schema_version", "integer", "", None, "the manifest schema (1)"),
    *(Setting(k, "table", "", None, f"[{k}]") for k in ("unit", "run", "site", "environment",
                                                         "acquisition", "format")),
    *(Setting(k, "list", "", None, f"[[{k}]]") for k in ("equipment", "segments")),
    name="RunManifest", noun="field", base=ManifestRules,
)  # fmt: skip
RunManifest = MANIFEST.type


def run_manifest(data: Any) -> RunManifest:
    """A manifest's TOML tables typed, section by section; SettingError naming the key."""
    typed(MANIFEST, data, "", ("schema_version", "unit", "run", "format"))
    if data["schema_version"] != SCHEMA_VERSION:
        got = f"Input should be {SCHEMA_VERSION}, got {data['schema_version']!r}"
        raise SettingError("schema_version", got, "")
    unit = typed(UNIT, data["unit"], "unit", ("serial", "model", "manufacturer"))
    try:  # the serial becomes a folder name in the archive: no path tricks
        check_safe_name(unit.serial, "serial")
    except ValueError as exc:
        raise SettingError("serial", str(exc), "unit") from None
    site = typed(SITE, data.get("site", {}), "site")
    site.check()
    segments = [typed(SEGMENT, e, f"segments[{i}]", ("label",))
                for i, e in enumerate(data.get("segments", []))]  # fmt: skip
    for i, segment in enumerate(segments):
        segment.check(f"segments[{i}]")
    required = ("model", "calibration_due")  # the lab's own record: model and due date too
    return RunManifest(
        schema_version=SCHEMA_VERSION,
        unit=unit,
        run=run_spec(data["run"]),
        site=site,
        environment=typed(ENVIRONMENT, data.get("environment", {}), "environment"),
        acquisition=typed(ACQUISITION, data.get("acquisition", {}), "acquisition"),
        equipment=[
            equipment_in(e, f"equipment[{i}]", required)
            for i, e in enumerate(data.get("equipment", []))
        ],  # fmt: skip
        format=format_spec(data["format"]),
        segments=segments,
    )


def parse_manifest(text: str, source: str = "run.toml") -> RunManifest:
    """Parse and validate manifest text; errors name `source` and the field.

    Parameters
    ----------
    text : TOML text of a run manifest.
    source : file name used in error messages.
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise IngestError(
            f"not valid TOML: {exc}", file=source, line=int(m.group(1)) if m else None
        ) from None
    except RecursionError:
        raise _too_deep(text, source) from None
    except ValueError:  # Python's limit on the digits of an integer (4300)
        digits, line = _longest_number(text)
        raise IngestError(
            f"a number of {digits} digits; expected one of at most "
            f"{sys.get_int_max_str_digits()} digits",
            file=source,
            line=line,
        ) from None
    check_finite_numbers(data, source, text)
    try:
        check_free_text(data, source)
        manifest = run_manifest(data)
    except SettingError as exc:
        path = (*key_path(exc.root), *key_path(exc.key))
        raise IngestError(
            exc.problem, file=source, line=key_line(text, path), field=_field_path(path)
        ) from None
    except RecursionError:
        raise _too_deep(text, source) from None
    check_segments(manifest, source, text)
    check_settings(manifest, source, text)
    return manifest


def check_finite_numbers(data: Any, source: str, text: str, path: tuple = ()) -> None:
    """Refuse a number no field can hold: ``1e400`` (read as infinity), ``inf``, ``nan``.

    Raises IngestError naming `source`, the line of the key in `text` and its dotted path
    (no manifest field takes a non-finite number; caught here, before any solve, not as
    "not storable as JSON" after it)."""
    if isinstance(data, dict):
        for key, value in data.items():
            check_finite_numbers(value, source, text, (*path, key))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            check_finite_numbers(value, source, text, (*path, i))
    elif isinstance(data, float) and not math.isfinite(data):
        raise IngestError(
            f"{data} is not a finite number (a value beyond 1.8e308 reads as infinity); "
            "expected a finite number",
            file=source,
            line=key_line(text, path),
            field=_field_path(path),
        )


def _too_deep(text: str, source: str) -> IngestError:
    return IngestError(
        "arrays or tables nested too deep to read; a manifest nests a few levels",
        file=source,
        line=_deepest_line(text),
    )


def _deepest_line(text: str) -> int | None:
    """1-based line where brackets and braces open deepest (strings not told apart)."""
    depth, deepest, where = 0, 0, None
    for number, line in enumerate(text.splitlines(), start=1):
        for c in line:
            depth += (c in "[{") - (c in "]}")
            if depth > deepest:
                deepest, where = depth, number
    return where


def _longest_number(text: str) -> tuple[int, int | None]:
    """(digits, 1-based line) of the longest run of digits in `text`."""
    runs = [
        (len(m.group()), text.count("\n", 0, m.start()) + 1)
        for m in re.finditer(r"[\d_]{100,}", text)
    ]
    return max(runs) if runs else (0, None)


def check_settings(manifest: RunManifest, source: str = "run.toml", text: str = "") -> None:
    """The whole ``[run.settings]`` against the procedure's settings and the preprocessing
    tables (calib_core.procedures): an unknown key (with the closest valid one), a wrong type
    or a value out of bounds is an IngestError naming the file, the key and, found in the
    manifest's `text`, its line. An unknown procedure is left to the solve, which names the
    known ones."""
    if manifest.run.procedure not in procedures.BY_NAME:
        return
    try:
        procedures.validate_settings(manifest.run.procedure, manifest.run.settings)
    except procedures.SettingError as exc:
        raise IngestError(
            exc.problem,
            file=source,
            line=key_line(text, ("run", "settings", *exc.key.split("."))),
            field=f"run.settings.{exc.key}",
        ) from None


def check_segments(manifest: RunManifest, source: str = "run.toml", text: str = "") -> None:
    """Cross-checks of the segment list that need the whole manifest.

    Raises IngestError naming the segment field (and, found in the manifest's `text`, its
    line): a missing list (only MPU-6000 folders may leave it out: their file names say
    it), repeated labels, two segments whose windows of one file (and section) overlap
    (one sample would count twice), and, for the six-position procedures, labels that
    are not theirs (typos) unless the segment is a verification segment.
    """
    segments = manifest.segments
    if not segments and manifest.format.kind != "mpu6000":
        raise IngestError(
            f"format kind '{manifest.format.kind}' needs a [[segments]] list "
            "(label and file of each segment)",
            file=source,
            field="segments",
        )
    seen: dict[str, int] = {}
    for i, seg in enumerate(segments):
        if seg.label in seen:
            raise IngestError(
                f"label {seg.label!r} repeats segments[{seen[seg.label]}]; labels must be unique",
                file=source,
                field=f"segments[{i}].label",
            )
        seen[seg.label] = i
    check_overlaps(segments, source, text)
    procedure = manifest.run.procedure
    proc = procedures.BY_NAME.get(procedure)
    # The procedure's own labels (none: any label); with [run.settings.segmentation] the
    # listed segments are continuous recordings that automatic segmentation cuts and labels.
    labels = () if proc is None else proc.labels
    if labels and "segmentation" not in manifest.run.settings:
        for i, seg in enumerate(segments):
            if not seg.verification and seg.label not in labels:
                near = difflib.get_close_matches(seg.label, labels, n=1)
                hint = f" (did you mean '{near[0]}'?)" if near else ""
                raise IngestError(
                    f"{seg.label!r} is not a segment label of procedure '{procedure}'{hint}; "
                    f"expected one of: {', '.join(labels)} (or verification = true)",
                    file=source,
                    field=f"segments[{i}].label",
                )


def check_overlaps(segments: list[SegmentSpec], source: str, text: str = "") -> None:
    """Refuse two segments whose time windows of the same file (and section) overlap."""
    windows: dict[tuple, list[tuple[float, float, int]]] = {}
    for i, seg in enumerate(segments):
        start = -math.inf if seg.start_s is None else seg.start_s
        end = math.inf if seg.end_s is None else seg.end_s
        for j_start, j_end, j in windows.setdefault((seg.files, seg.section), []):
            if max(start, j_start) < min(end, j_end):
                other = segments[j]
                raise IngestError(
                    f"segment {seg.label!r} (t in [{seg.start_s}, {seg.end_s}) s) overlaps "
                    f"segment {other.label!r} (t in [{other.start_s}, {other.end_s}) s) of "
                    f"the same file {' + '.join(seg.files)!r}: a sample belongs to one "
                    "segment; expected windows that do not overlap",
                    file=source,
                    line=key_line(
                        text, ("segments", i, "start_s" if seg.start_s is not None else "label")
                    ),
                    field=f"segments[{i}]",
                )
        windows[(seg.files, seg.section)].append((start, end, i))


def load_manifest(path: Path) -> RunManifest:
    """Read and validate a ``run.toml``.

    Raises
    ------
    IngestError naming the file and, for TOML syntax errors, the line; for
    content errors the dotted field path and what was expected.
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise IngestError("manifest file not found", file=path) from None
    except UnicodeDecodeError as exc:
        raise IngestError(f"not UTF-8 text ({exc.reason} at byte {exc.start})", file=path) from None
    return parse_manifest(text, str(path))


def _field_path(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out
