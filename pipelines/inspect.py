"""`calib inspect PATH`: what a file or run folder holds, without archiving anything.

For a file: the format found by content (and its variant: an MPU-6000 text's
encoding, line ends, separators and summary lines; a CSV's metadata lines,
delimiter, decimal mark and header units), its columns with units, and the
samples read: count, rate, duration, gaps, temperature range (or "not recorded"),
segments; for a log (ULog, DataFlash, ROS bag), every source of IMU samples it holds
with its rate (the default reads the fastest). For a
folder: every run found (discover_runs), its manifest's procedure, its segments
as read, and what the procedure lacks (the six-position procedures' twelve
labels). A file or run that cannot be read gives its IngestError: file, line or
field, expected, found. Nothing is written anywhere.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from calib_core.recording import Recording
from pipelines.ingest.data_format import FormatSpec
from pipelines.ingest.errors import IngestError

GAP_FACTOR = 1.5  # a time step above 1.5 median steps is a gap
SI_COLUMNS = ["t [s]", "acc x y z [m/s^2]", "gyr x y z [rad/s]", "temp [degC]"]


def samples_summary(rec: Recording) -> dict[str, Any]:
    """Count, rate (Hz, from the median step), duration (s), gaps, temperature range."""
    n = len(rec)
    dt = np.diff(rec.t)
    step = float(np.median(dt)) if dt.size else float("nan")
    gaps = np.flatnonzero(dt > GAP_FACTOR * step) if dt.size else np.array([], int)
    out: dict[str, Any] = {
        "samples": n,
        "rate_hz": round(1.0 / step, 3) if dt.size and step > 0 else None,
        "duration_s": round(float(rec.t[-1] - rec.t[0]), 6) if n else 0.0,
        "gaps": int(gaps.size),
        "largest_gap_s": round(float(dt[gaps].max()), 6) if gaps.size else None,
        "bad_samples": 0,  # the readers refuse a run with a NaN, inf or repeated time stamp
        "temperature_c": None,
    }
    if rec.temp is not None and n:
        out["temperature_c"] = [round(float(rec.temp.min()), 3), round(float(rec.temp.max()), 3)]
    else:
        out["temperature"] = "not recorded"  # never a 0 deg C the file does not hold
    if rec.reference:
        out["reference"] = sorted(rec.reference)
    return out


def orientation_display(rec: Recording) -> list[str]:
    """What the MPU-6000 program shows after each orientation (docs/methods.md 5): one
    line ``Ax : mean=... std=...`` per channel, accelerometer in m/s^2 (4 decimals),
    gyro in deg/s (3 decimals) as its files write them; std with ddof 1."""
    rows = [(f"A{a}", rec.acc[:, i], 4) for i, a in enumerate("xyz")]
    rows += [(f"G{a}", np.degrees(rec.gyr[:, i]), 3) for i, a in enumerate("xyz")]
    return [
        f"{name} : mean={x.mean():.{d}f} std={x.std(ddof=1 if len(x) > 1 else 0):.{d}f}"
        for name, x, d in rows
    ]


def _sniff_kind(path: Path) -> str:
    """The reader a file's content calls for (MPU-6000 by its name)."""
    from pipelines.ingest.dataflash_reader import DF_HEAD
    from pipelines.ingest.detect import MCAP_MAGIC, detect_format
    from pipelines.ingest.mpu6000 import parse_file_name
    from pipelines.ingest.rosbag_reader import ROS1_MAGIC, SQLITE_MAGIC
    from pipelines.ingest.ulog_reader import ULOG_MAGIC

    with path.open("rb") as fh:
        head = fh.read(64)
    for magic, kind in (
        (ULOG_MAGIC, "ulog"),
        (ROS1_MAGIC, "rosbag"),
        (SQLITE_MAGIC, "rosbag"),
        (MCAP_MAGIC, "mcap"),
        (DF_HEAD, "dataflash"),
    ):
        if head.startswith(magic):
            return kind
    if parse_file_name(path.name) is not None:
        return "mpu6000"
    kind = detect_format(path)
    return "csv" if kind == "text" else "mat"


def inspect_file(path: Path) -> dict[str, Any]:
    """What one data file holds (format, variant, columns, samples); 'error' if unreadable."""
    path = Path(path)
    doc: dict[str, Any] = {"path": str(path), "kind": "file"}
    try:
        kind = doc["format"] = _sniff_kind(path)
        rec = _read(path, kind, doc)
    except IngestError as exc:
        doc["error"] = str(exc)
        return doc
    doc.update(samples_summary(rec))
    doc["procedure"] = _file_procedure(path, kind)
    return doc


def _read(path: Path, kind: str, doc: dict[str, Any]) -> Recording:
    if kind == "mpu6000":
        from pipelines.ingest.mpu6000 import COLUMN_NAMES, read_mpu6000_text

        rec, variant = read_mpu6000_text(path)
        doc["variant"] = variant.describe()
        units = ("ms", "m/s^2", "m/s^2", "m/s^2", "deg/s", "deg/s", "deg/s", "degC")
        doc["columns"] = [f"{c} [{u}]" for c, u in zip(COLUMN_NAMES, units, strict=True)]
        doc["segment"] = rec.label
        doc["display"] = orientation_display(rec)
        return rec
    if kind == "csv":
        return _read_csv(path, doc)
    from pipelines.ingest.readers import reader_for

    doc["columns"] = SI_COLUMNS
    if kind == "mat":
        raise IngestError(
            "a MATLAB file: its variables are named in a run.toml ([format.variables])",
            file=path,
        )
    if kind in LOG_KINDS:
        doc["sources"] = [s.summary() for s in log_sources(path, kind)]
    return reader_for(kind)(path, FormatSpec(kind=kind))


LOG_KINDS = ("ulog", "dataflash", "rosbag")


def log_sources(path: Path, kind: str) -> list:
    """Every source of accelerometer + gyro samples a log holds, with its rate
    (pipelines.ingest.log_samples.LogSource); the default reads the fastest."""
    if kind == "ulog":
        from pipelines.ingest.ulog_reader import load_ulog, ulog_sources

        return ulog_sources(load_ulog(path)[0])
    if kind == "dataflash":
        from pipelines.ingest.dataflash_reader import dataflash_sources, imu_rows, open_dataflash

        return dataflash_sources(imu_rows(open_dataflash(path)[0], path))
    from pipelines.ingest.rosbag_reader import bag_sources

    return bag_sources(path)


def _read_csv(path: Path, doc: dict[str, Any]) -> Recording:
    from pipelines.ingest.csv_dialect import sniff, split_unit
    from pipelines.ingest.csv_layout import layout_of
    from pipelines.ingest.csv_reader import read_csv

    fmt = FormatSpec(kind="csv")
    dialect = sniff(path, fmt)
    doc["variant"] = {
        "delimiter": {"\t": "tab"}.get(dialect.delimiter, dialect.delimiter),
        "decimal": dialect.decimal,
        "header_line": dialect.header_line,
        "metadata_lines": dialect.metadata,
    }
    doc["columns"] = [
        f"{name} [{split_unit(name)[1]}]" if split_unit(name)[1] else name for name in dialect.names
    ]
    layout = layout_of(path, fmt)
    doc["roles"] = layout.roles
    return read_csv(path, fmt, progress=False)


def _file_procedure(path: Path, kind: str) -> str:
    if kind == "mpu6000":
        return (
            "six_position_integral: one of the 12 MPU-6000 files; inspect the folder to see "
            "which are missing"
        )
    return "needs a run.toml naming the procedure and which file or window is which segment"


def inspect_folder(folder: Path) -> dict[str, Any]:
    """Every run in `folder`: manifest, procedure, segments as read, what is missing."""
    from pipelines.ingest.run_loader import discover_runs, load_run

    doc: dict[str, Any] = {"path": str(folder), "kind": "folder", "runs": []}
    try:
        sources = discover_runs([folder])
    except IngestError as exc:
        doc["error"] = str(exc)
        return doc
    for source in sources:
        run: dict[str, Any] = {"run": source.name, "layout": source.kind}
        doc["runs"].append(run)
        try:
            loaded = load_run(source, hash_file=lambda p: ("", p.stat().st_size))
        except IngestError as exc:
            run["error"] = str(exc)
            continue
        m = loaded.manifest
        run.update(serial=m.unit.serial, format=m.format.kind, procedure=m.run.procedure)
        run["segments"] = {
            label: {"source": rec.source, **samples_summary(rec)}
            for label, rec in loaded.segments.items()
        }
        run["missing"] = _missing(m.run.procedure, set(loaded.segments), m.run.settings)
    return doc


def _missing(procedure: str, labels: set[str], settings: dict) -> list[str]:
    """Labels the procedure needs and the run lacks (`Procedure.missing`); none when
    automatic segmentation cuts and labels the recordings."""
    from calib_core.procedures import BY_NAME

    if procedure not in BY_NAME:
        return [f"procedure {procedure!r} is unknown; known: {', '.join(sorted(BY_NAME))}"]
    if "segmentation" in settings:
        return []
    return BY_NAME[procedure].missing(labels, settings)


def inspect_path(path: Path) -> dict[str, Any]:
    """:func:`inspect_folder` or :func:`inspect_file`; 'error' for a path that does not exist."""
    path = Path(path)
    if path.is_dir():
        return inspect_folder(path)
    if not path.exists():
        return {"path": str(path), "kind": "missing", "error": f"{path}: path does not exist"}
    return inspect_file(path)
