"""Writers of lab runs in the layouts ingest reads: the sample data and the test fixtures.

- :func:`write_mpu6000_run`: one text file per segment in the MPU-6000 layout
  (docs/methods.md section 5), with the underscore line, means and standard deviations.
- :func:`write_csv_run`: one headered CSV with all segments on one time base,
  and a ``run.toml`` whose segment windows point at them.
- :func:`write_centrifuge_run`: a simulated centrifuge run as a CSV run folder.

Both write the simulator's truth as JSON beside the data when given. The
printed precision of every column is a module constant, so a test can derive
its round-trip tolerance (half a unit of the last printed digit).
"""

from __future__ import annotations

import io
import json
import math
import re
from datetime import date, datetime
from pathlib import Path
from typing import Any

import numpy as np

from calib_core.recording import Recording
from calib_core.solvers.centrifuge_segments import step_label
from calib_core.units import acceleration_factor, angular_rate_factor, time_factor
from pipelines.ingest.mpu6000 import COLUMN_DECIMALS
from storage.naming import check_safe_name

# CSV: decimals printed per quantity, in the file's own units (time: per unit,
# so that every time unit resolves 1 us).
CSV_TIME_DECIMALS = {"s": 6, "ms": 3, "us": 0, "ns": 0}
CSV_ACC_DECIMALS = 7
CSV_GYR_DECIMALS = 7
CSV_TEMP_DECIMALS = 3
CSV_REFERENCE_DECIMALS = 9
CSV_NAME = "imu.csv"
CSV_GAP_S = 2.0  # s between consecutive segments on the common time base
CSV_START_S = 1.0  # s, time of the first sample

_LABEL = re.compile(r"^(?P<axis>[xyz])_(?P<sense>up|dn|cw|ccw)$")


def write_mpu6000_run(
    segments: dict[str, Recording],
    folder: Path,
    serial: str,
    truth: dict | None = None,
) -> list[Path]:
    """Write segments as MPU-6000 text files ``<serial>_<axis>_<sense>.txt``.

    Parameters
    ----------
    segments : label (``"x_up"``, ``"z_ccw"``, ...) -> Recording (SI units,
        with a temperature channel). Time is written in integer ms as given
        (not shifted); it must stay strictly increasing at 1 ms resolution.
    folder : created if missing.
    serial : the unit's serial (a safe file-name component).
    truth : written as ``<serial>_truth.json`` (name-spaced by serial because
        one MPU-6000 folder may hold several units).

    Returns
    -------
    The data files written, in the order of `segments`.
    """
    check_safe_name(serial, "serial")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for label, rec in segments.items():
        if not _LABEL.match(label):
            raise ValueError(f"MPU-6000 files need labels like 'x_up' or 'z_ccw', got {label!r}")
        if rec.temp is None:
            raise ValueError(f"segment {label!r}: the MPU-6000 layout needs a temperature channel")
        t_ms = np.round(rec.t * 1e3)
        if np.any(np.diff(t_ms) <= 0):
            raise ValueError(f"segment {label!r}: time not strictly increasing at 1 ms resolution")
        columns = np.column_stack([t_ms, rec.acc, np.degrees(rec.gyr), rec.temp])
        # Round as printed first, so the summary lines describe exactly the data lines.
        printed = np.column_stack(
            [np.round(columns[:, j], d) for j, d in enumerate(COLUMN_DECIMALS)]
        )
        data_fmt = ["%8.0f"] + ["%9.4f"] * 3 + ["%9.3f"] * 3 + ["%6.1f"]
        # One more decimal in the summary than in the data.
        summary_fmt = ["%10.1f"] + ["%9.5f"] * 3 + ["%9.4f"] * 3 + ["%6.2f"]
        buf = io.StringIO()
        np.savetxt(buf, printed, fmt=data_fmt, delimiter=" ")
        buf.write("_" * 72 + "\n")
        np.savetxt(buf, printed.mean(axis=0)[None, :], fmt=summary_fmt, delimiter=" ")
        np.savetxt(buf, printed.std(axis=0, ddof=1)[None, :], fmt=summary_fmt, delimiter=" ")
        path = folder / f"{serial}_{label}.txt"
        path.write_text(buf.getvalue(), encoding="ascii")
        written.append(path)
    if truth is not None:
        write_json(folder / f"{serial}_truth.json", truth)
    return written


def six_position_manifest(
    serial: str,
    *,
    started: str = "2026-11-20T09:15:00+00:00",
    operator: str = "test",
    temperature_c: float = 20.0,
) -> dict:
    """A minimal run-manifest dict for a simulated six-position + integral run (write_csv_run).

    MPU-6000 unit, standard gravity, the shipped ``mpu6000`` tolerance profile.
    """
    return {
        "schema_version": 1,
        "unit": {"serial": serial, "model": "MPU-6000", "manufacturer": "InvenSense"},
        "run": {
            "started": started,
            "operator": operator,
            "procedure": "six_position_integral",
            "tolerance_profile": "mpu6000",
        },
        "site": {"gravity_model": "standard"},
        "environment": {"temperature_c": temperature_c},
    }


def write_csv_run(
    segments: dict[str, Recording],
    folder: Path,
    manifest: dict,
    truth: dict | None = None,
) -> Path:
    """Write segments as one headered CSV on a common time base, plus ``run.toml``.

    Parameters
    ----------
    segments : label -> Recording (SI units). Each is shifted to start
        ``CSV_GAP_S`` after the previous one ends (the first at ``CSV_START_S``).
    folder : the run folder, created if missing.
    manifest : the manifest as a dict (sections unit, run, site, environment,
        equipment, ...). ``format`` may set ``acc_unit``, ``gyr_unit``,
        ``time_unit`` and ``delimiter`` (defaults m/s^2, rad/s, s, ','); the
        column names and kind are filled in. ``segments`` may list
        ``{"label": ..., "verification": true}`` entries to flag segments;
        every segment's file and window (mid-gap bounds) are filled in.
    truth : written as ``truth.json`` beside.

    Returns
    -------
    Path of the written run.toml.

    The layout (time base, columns, manifest windows) is one file's description:
    `_csv_format` names the columns, `_csv_blocks` places the segments on the
    time base, `_csv_decimals` gives each column its printed precision.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    doc = {k: v for k, v in manifest.items() if k not in ("format", "segments")}
    doc.setdefault("schema_version", 1)
    given = dict(manifest.get("format", {}))
    fmt, refs = _csv_format(segments, given)
    flags = {s["label"]: s for s in manifest.get("segments", [])}
    unknown = set(flags) - set(segments)
    if unknown:
        raise ValueError(f"manifest segments name labels with no data: {sorted(unknown)}")
    blocks, seg_docs = _csv_blocks(segments, fmt, refs, flags)

    names = ["time", *fmt["acc_columns"], *fmt["gyr_columns"]]
    names += ["temp"] if "temp_column" in fmt else []
    names += [f"ref_{name}" for name in refs]
    sep = {"tab": "\t", "whitespace": " "}.get(fmt["delimiter"], fmt["delimiter"])
    buf = io.StringIO()
    np.savetxt(
        buf,
        np.concatenate(blocks),
        fmt=[f"%.{d}f" for d in _csv_decimals(fmt, len(refs))],
        delimiter=sep,
        header=sep.join(names),
        comments="",
    )
    (folder / CSV_NAME).write_text(buf.getvalue(), encoding="utf-8")

    doc["format"] = {**fmt, **{k: v for k, v in given.items() if k not in fmt}}
    doc["segments"] = seg_docs
    path = folder / "run.toml"
    path.write_text(dumps_toml(doc), encoding="utf-8")
    if truth is not None:
        write_json(folder / "truth.json", truth)
    return path


def _csv_format(
    segments: dict[str, Recording], given: dict[str, Any]
) -> tuple[dict[str, Any], list[str]]:
    """The ``[format]`` section of the CSV (units from `given`) and the reference channels.

    Raises ValueError when only some segments have a temperature channel or the
    segments do not share their reference channels.
    """
    with_temp = [rec.temp is not None for rec in segments.values()]
    if any(with_temp) and not all(with_temp):
        raise ValueError("either every segment has a temperature channel or none")
    refs = sorted({name for rec in segments.values() for name in rec.reference})
    for label, rec in segments.items():
        if sorted(rec.reference) != refs:
            raise ValueError(f"segment {label!r} lacks reference channels of the others: {refs}")
    fmt: dict[str, Any] = {
        "kind": "csv",
        "delimiter": given.get("delimiter", ","),
        "header": True,
        "time_column": "time",
        "time_unit": given.get("time_unit", "s"),
        "acc_columns": ["acc_x", "acc_y", "acc_z"],
        "acc_unit": given.get("acc_unit", "m/s^2"),
        "gyr_columns": ["gyr_x", "gyr_y", "gyr_z"],
        "gyr_unit": given.get("gyr_unit", "rad/s"),
    }
    if all(with_temp) and with_temp:
        fmt["temp_column"] = "temp"
    if refs:
        fmt["reference_columns"] = {name: f"ref_{name}" for name in refs}
    return fmt, refs


def _csv_blocks(
    segments: dict[str, Recording],
    fmt: dict[str, Any],
    refs: list[str],
    flags: dict[str, dict[str, Any]],
) -> tuple[list[np.ndarray], list[dict[str, Any]]]:
    """Each segment's rows in the file's units on the common time base, and its manifest entry.

    Segment k starts ``CSV_GAP_S`` after segment k-1 ends (the first at
    ``CSV_START_S``); its window reaches half a gap either side.
    """
    blocks, seg_docs, offset = [], [], CSV_START_S
    for label, rec in segments.items():
        t = rec.t - rec.t[0] + offset
        block = [t / time_factor(fmt["time_unit"]), rec.acc / acceleration_factor(fmt["acc_unit"])]
        block.append(rec.gyr / angular_rate_factor(fmt["gyr_unit"]))
        if "temp_column" in fmt:
            block.append(rec.temp[:, None])
        block += [rec.reference[name][:, None] for name in refs]
        blocks.append(np.column_stack(block))
        seg = {k: v for k, v in flags.get(label, {}).items() if k != "label"}
        seg_docs.append(
            {
                "label": label,
                "file": CSV_NAME,
                "start_s": round(t[0] - CSV_GAP_S / 2, 6),
                "end_s": round(t[-1] + CSV_GAP_S / 2, 6),
                **seg,
            }
        )
        offset = t[-1] + CSV_GAP_S
    return blocks, seg_docs


def _csv_decimals(fmt: dict[str, Any], n_refs: int) -> list[int]:
    """Printed decimals per column: time, acc (3), gyr (3), temperature, references."""
    decimals = [CSV_TIME_DECIMALS[fmt["time_unit"]]] + [CSV_ACC_DECIMALS] * 3
    decimals += [CSV_GYR_DECIMALS] * 3
    decimals += [CSV_TEMP_DECIMALS] if "temp_column" in fmt else []
    return decimals + [CSV_REFERENCE_DECIMALS] * n_refs


def write_json(path: Path, doc: dict) -> None:
    """Write `doc` as indented JSON; numpy scalars and arrays become numbers and lists."""

    def plain(value: Any) -> Any:
        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, np.generic):
            return value.item()
        if isinstance(value, datetime | date):
            return value.isoformat()
        raise TypeError(f"cannot write {type(value).__name__} as JSON")

    Path(path).write_text(json.dumps(doc, indent=2, default=plain) + "\n", encoding="utf-8")


# --- a small TOML writer (tomli_w is not a dependency; manifests are simple data) ---

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(key: str) -> str:
    return key if _BARE_KEY.match(key) else json.dumps(key, ensure_ascii=False)


def _value(value: Any) -> str:
    """One TOML value: string, bool, int, float, date/datetime or a list of them."""
    if isinstance(value, bool | np.bool_):
        return "true" if value else "false"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        x = float(value)
        if math.isnan(x):
            return "nan"
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        return repr(x)
    if isinstance(value, str):
        # JSON string escapes are valid TOML basic-string escapes.
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, datetime | date):
        return value.isoformat()
    if isinstance(value, list | tuple | np.ndarray):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"cannot write {type(value).__name__} as a TOML value")


def _is_table_array(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def dumps_toml(doc: dict, _prefix: str = "") -> str:
    """`doc` as TOML text: scalars first, then tables, then arrays of tables.

    Nested dicts become ``[a.b]`` tables, lists of dicts ``[[a]]`` arrays of
    tables (their own nested dicts are written inline). None values are left
    out (TOML has no null).
    """
    lines: list[str] = []
    tables, arrays = [], []
    for key, value in doc.items():
        if value is None:
            continue
        if isinstance(value, dict):
            tables.append((key, value))
        elif _is_table_array(value):
            arrays.append((key, value))
        else:
            lines.append(f"{_key(key)} = {_value(value)}")
    out = "\n".join(lines) + ("\n" if lines else "")
    for key, value in tables:
        name = f"{_prefix}{_key(key)}"
        out += f"\n[{name}]\n" + dumps_toml(value, f"{name}.")
    for key, items in arrays:
        name = f"{_prefix}{_key(key)}"
        for item in items:
            flat = {k: v for k, v in item.items() if v is not None}
            out += f"\n[[{name}]]\n" + "".join(
                f"{_key(k)} = {_value(v)}\n" for k, v in flat.items()
            )
    return out


def write_centrifuge_run(run: Any, folder: Path, manifest: dict) -> Path:
    """Write a simulated centrifuge run as a CSV run folder (labels by `step_label`).

    `run` is a `calib_core.simulate.centrifuge.CentrifugeRun` (steps with their
    recordings, truth); not imported here, production code stays free of the simulator.

    `manifest` holds the sections unit, run, site...; the procedure is set to
    ``centrifuge`` and the truth goes to ``truth.json``. Returns the run.toml path.
    """
    segments = {}
    for step in run.steps:
        label = step_label(step)
        if label in segments:
            raise ValueError(f"two steps with the label {label!r}")
        segments[label] = step.recording
    doc = {**manifest, "run": {**manifest.get("run", {}), "procedure": "centrifuge"}}
    t = run.truth
    truth = {
        "model": t.model,
        "radius": t.radius,
        "phi_h": t.phi_h,
        "tilt": t.tilt,
        "direction": t.direction,
        "gravity": t.gravity,
        "run_offset": [float(v) for v in t.run_offset],
    }
    return write_csv_run(segments, Path(folder), doc, truth)
