"""Applying an archived calibration to new raw data (`calib apply`), the pipeline glue.

The latest valid calibration of a serial as of a date, with its thermal model
(calib_core.thermal), applied to new raw data in any ingest format and written as
Parquet or CSV.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from calib_core import thermal
from calib_core.calibration import Calibration, StepRecord
from calib_core.recording import Recording
from pipelines.ingest import read_mpu6000_file, read_run
from pipelines.ingest.mpu6000 import parse_file_name
from pipelines.process import samples_table
from storage import queries
from storage.db import Archive


def read_input(
    path: Path, serial: str | None = None
) -> tuple[dict[str, Recording], float | None, str | None]:
    """New raw data in any ingest format -> (segments, manifest temperature or None, the
    serial the data name: the manifest's unit or the MPU-6000 file name; None if none).

    path : a run folder with run.toml (or the run.toml), a folder of MPU-6000
        files (the runs of `serial`), or one MPU-6000 file.
    """
    path = Path(path)
    if path.is_file() and (named := parse_file_name(path.name)) is not None:
        rec = read_mpu6000_file(path)
        return {rec.label or path.stem: rec}, None, named[0]
    loaded = read_run(path, serial)
    return loaded.segments, loaded.manifest.environment.temperature_c, loaded.manifest.unit.serial


def load_compensation(
    archive: Archive, serial: str, at: datetime | None
) -> tuple[Calibration, float | None, thermal.ThermalModel | None, dict[str, Any]]:
    """(calibration, its temperature, thermal model or None, facts) valid for `serial` at `at`."""
    latest = queries.latest_calibration(archive, serial, at)
    if latest is None:
        when = "now" if at is None else at.isoformat()
        raise LookupError(f"no valid (passed, current) calibration of {serial!r} as of {when}")
    cal = Calibration.from_dict(latest.document)
    temps = {p.temperature_c for p in latest.parameters if p.temperature_c is not None}
    cal_temp = float(temps.pop()) if len(temps) == 1 else None
    tm = queries.latest_thermal_model(archive, serial, None)
    model = None if tm is None else thermal.ThermalModel.from_dict(tm["document"])
    facts = {
        "serial": serial,
        "run_id": latest.run_id,
        "calibration_id": latest.calibration_id,
        "calibration_temperature_c": cal_temp,
        "thermal_model_id": None if tm is None else tm["id"],
    }
    return cal, cal_temp, model, facts


def calibrate_segments(
    segments: dict[str, Recording],
    cal: Calibration,
    cal_temp: float | None,
    model: thermal.ThermalModel | None,
    fallback_temp: float | None = None,
) -> tuple[dict[str, Recording], StepRecord]:
    """Pipeline step: apply calibration (+ thermal model) to each segment."""
    out = {}
    clipped = 0
    for label, rec in segments.items():
        if model is None:
            out[label] = cal.apply(rec)
            continue
        temp = rec.temp if rec.temp is not None else fallback_temp
        if temp is None:
            raise ValueError(
                f"segment {label!r} ({rec.source}): no temperature channel and no "
                f"environment.temperature_c: the thermal model needs a temperature"
            )
        t = np.broadcast_to(np.asarray(temp, dtype=float), (len(rec),))
        clipped += int(np.sum((t < model.t_min) | (t > model.t_max)))
        acc, gyr = model.correct(rec.acc, rec.gyr, t, cal, cal_temp)
        out[label] = Recording(rec.t, acc, gyr, rec.temp, rec.reference, rec.label, rec.source)
    stats = {
        "segments": len(out),
        "samples": sum(len(r) for r in out.values()),
        "thermal_model": model is not None,
        "samples_outside_thermal_range": clipped,
    }
    return out, StepRecord(
        "apply", settings={"calibration_temperature_c": cal_temp}, statistics=stats
    )


def write_samples(table: pa.Table, output: Path) -> Path:
    """Parquet for .parquet / .pq, CSV for .csv; anything else is refused."""
    output = Path(output)
    suffix = output.suffix.lower()
    if suffix in (".parquet", ".pq"):
        pq.write_table(table, output, compression="zstd")
    elif suffix == ".csv":
        pacsv.write_csv(table, output)
    else:
        raise ValueError(
            f"output {output}: unknown suffix {suffix!r}; expected .parquet, .pq or .csv"
        )
    return output


def apply_calibration(
    archive: Archive, serial: str, at: datetime | None, source: Path, output: Path
) -> dict[str, Any]:
    """Calibrate new raw data with the calibration (and thermal model) valid at `at`.

    Parameters
    ----------
    archive : the archive holding the unit's calibrations.
    serial : the unit.
    at : time-zone-aware date of validity; None for now (latest passed, current revision).
    source : the new raw data: a run folder, its run.toml, or one MPU-6000 file.
    output : the calibrated samples, ``.parquet`` / ``.pq`` or ``.csv`` (SI units).

    Returns
    -------
    dict of facts: which calibration and thermal model were used, samples
    written, samples outside the thermal model's range (clipped), output path.
    """
    if Path(output).suffix.lower() not in (".parquet", ".pq", ".csv"):
        raise ValueError(f"output {output}: expected a .parquet, .pq or .csv file name")
    cal, cal_temp, model, facts = load_compensation(archive, serial, at)
    segments, env_temp, data_serial = read_input(Path(source), serial)
    warnings = []
    if data_serial is not None and data_serial != serial:
        warnings.append(
            f"{source}: the data name serial {data_serial!r}, the calibration applied is "
            f"{serial!r}'s (--serial); check that this is the unit that recorded it"
        )
    done, step = calibrate_segments(segments, cal, cal_temp, model, env_temp)
    write_samples(samples_table(done), Path(output))
    return {
        **facts,
        "data_serial": data_serial,
        **step.statistics,
        "output": str(output),
        "warnings": warnings,
    }
