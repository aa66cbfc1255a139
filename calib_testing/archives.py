"""Small archives for the tests: runs given at the parameter level, archived as they are.

A test of the archive's read side (trends, intervals, shared references, thermal models)
needs runs with chosen parameters, dates and temperatures, not their processing:
`parameter_run` builds the `storage.run_input.RunIn` of such a run (one small raw file whose
text is unique to the run, no samples, no checks), `new_archive` an empty archive with the
current schema. `processed_run` archives one run folder through the real pipeline,
`static_bias_archive` one static record.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from calib_core.calibration import Parameter, StepRecord
from calib_core.recording import Recording
from calib_testing.run_writers import six_position_manifest, write_csv_run
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage.db import Archive, resolve_archive
from storage.run_input import RawFileIn, RunIn


def new_archive(root: Path) -> Archive:
    """An empty archive with the current schema under ``root / "archive"`` (SQLite)."""
    archive = resolve_archive(str(root / "archive"))
    archive.upgrade()
    return archive


def processed_outcome(folder: Path, archive: Archive) -> dict[str, Any]:
    """The outcome of the one run in `folder`, processed into `archive` (it must succeed)."""
    (source,) = discover_runs([folder])
    outcome = process_run(source, archive)
    assert outcome["status"] == "ok", outcome["error"]
    return outcome


def processed_run(folder: Path, archive: Archive) -> str:
    """The run id of the one run in `folder`, processed into `archive` (it must succeed)."""
    return processed_outcome(folder, archive)["run_id"]


def static_bias_archive(root: Path, rec: Recording, serial: str) -> tuple[Archive, str]:
    """A new archive under `root` holding `rec` processed as a static-bias run of `serial`
    (z up), written as a CSV run folder and archived by the real pipeline; its run id."""
    manifest = six_position_manifest(serial)
    manifest["run"] |= {"procedure": "static_bias", "settings": {"up_axis": "+z"}}
    write_csv_run({"static": rec}, root / "run", manifest)
    archive = new_archive(root)
    return archive, processed_run(root / "run", archive)


def parameter_run(
    folder: Path,
    serial: str,
    started_at: datetime,
    parameters: Sequence[Parameter] = (),
    *,
    temperature_c: float | None = 20.0,
    device_model: str = "SIM-IMU",
    manufacturer: str = "sim",
    procedure: str = "six_position_integral",
    operator: str | None = "test",
    gravity: float = 9.80665,
    equipment: Sequence[dict[str, Any]] = (),
    steps: Sequence[StepRecord] = (),
    profile_name: str | None = "mpu6000",
    profile_version: str | None = "3",
    software_version: str = "test",
    verdict: str = "pass",
) -> RunIn:
    """A run of `serial` started at `started_at` holding `parameters` (SI units).

    Parameters
    ----------
    folder : where its raw file is written (a ``.csv`` named by serial and start).
    temperature_c : the lab temperature (deg C) of its environment and of its
        parameters; None: not recorded.
    profile_name : the tolerance profile it was judged by (also its ``tolerance_profile``).
    Others : as `storage.run_input.RunIn`'s fields of the same name.
    """
    raw = folder / f"{serial}_{started_at:%Y%m%dT%H%M%S}.csv"
    raw.write_text(f"{serial} {started_at.isoformat()} {temperature_c}\n")
    digest = hashlib.sha256(raw.read_bytes()).hexdigest()
    return RunIn(
        serial=serial,
        device_model=device_model,
        manufacturer=manufacturer,
        specification=None,
        started_at=started_at,
        operator=operator,
        procedure=procedure,
        site={},
        gravity=gravity,
        environment={} if temperature_c is None else {"temperature_c": temperature_c},
        equipment=list(equipment),
        manifest_text=None,
        tolerance_profile=profile_name,
        raw_files=[RawFileIn(raw, raw.name, digest, raw.stat().st_size, "csv")],
        settings={},
        software_version=software_version,
        source_revision=None,
        steps=list(steps),
        calibration={"parameters": {}},
        parameters=list(parameters),
        checks=[],
        verdict=verdict,
        profile_name=profile_name,
        profile_version=profile_version,
        parameter_temperature_c=temperature_c,
    )
