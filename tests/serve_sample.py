"""A small archive for the `calib serve` tests, built by the real pipeline into a real SQLite file.

Contents (all runs written as lab files, then `process_run`):
- the two runs of data_samples/ (MPU0001 passes, IMU-2026-0042 fails on gyro noise);
- DRIFT-01 (MPU-6000): 4 six-position runs a few months apart whose x accelerometer
  bias drifts by DRIFT_PER_DAY, on cube CUBE-D whose calibration lapsed 2025-06-30
  (the last two runs are made while lapsed);
- TH-01 (MPU-6000): a thermal campaign at 6 temperatures and its fitted thermal model;
- EVIL-1: a unit whose model, manufacturer, operator and equipment serial are HTML and
  script (HOSTILE...), to show that every archived string is rendered as text.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from calib_core.simulate import TrueErrors, random_errors, six_position_integral_run
from calib_core.simulate.thermal import random_thermal_truth, thermal_campaign
from calib_core.units import DEG
from calib_testing.archives import processed_run
from calib_testing.run_writers import write_csv_run
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage.db import Archive, resolve_archive

DATA_SAMPLES = Path(__file__).resolve().parent.parent / "data_samples"
HOSTILE_MODEL = "<script>alert(1)</script>"
HOSTILE_OPERATOR = '<img src=x onerror="alert(2)">'
HOSTILE_EQUIPMENT = '"><script>alert(3)</script>'
HOSTILE_SERIAL = "<script>alert(1)</script>"  # refused by the archive: only ever a request string
DRIFT_SERIAL = "DRIFT-01"
THERMAL_SERIAL = "TH-01"
EVIL_SERIAL = "EVIL-1"
DRIFT_PER_DAY = 2e-5  # m/s^2 per day on acc.bias.x
DRIFT_DAYS = (0, 120, 300, 420)
DRIFT_START = datetime(2025, 1, 15, 9, 0, tzinfo=UTC)
CUBE_DUE = "2025-06-30"
THERMAL_TEMPS = (-10.0, 5.0, 20.0, 35.0, 50.0, 60.0)


@dataclass
class Sample:
    archive: Archive
    runs: dict[str, list[str]] = field(default_factory=dict)  # serial -> run ids, in time order


def _manifest(
    serial: str,
    started: datetime,
    *,
    temp: float = 20.0,
    model: str = "MPU-6000",
    manufacturer: str = "InvenSense",
    operator: str = "A. Tester",
    equipment: list[dict] | None = None,
) -> dict:
    return {
        "schema_version": 1,
        "unit": {"serial": serial, "model": model, "manufacturer": manufacturer},
        "run": {
            "started": started.isoformat(),
            "operator": operator,
            "procedure": "six_position_integral",
            "tolerance_profile": "mpu6000",
        },
        "site": {"gravity_model": "standard"},
        "environment": {"temperature_c": temp},
        "equipment": equipment or [],
    }


def quiet_truth(rng: np.random.Generator) -> TrueErrors:
    """A unit well inside every mpu6000 tolerance.

    The simulator's MEMS grade reaches the limits themselves (scale 0.03, g-sensitivity
    0.1 (deg/s)/g, gyro noise 0.05 deg/s); 80 % of them leaves a margin of > 100
    standard uncertainties.
    """
    truth = random_errors(rng)
    truth.gyr_noise = np.full(3, 0.04 * DEG)
    truth.gsens *= 0.8
    for m in (truth.acc_M, truth.gyr_M):
        m[np.diag_indices(3)] *= 0.8
    return truth


def build(root: Path) -> Sample:
    """Write the lab files under root/lab and archive them into root/archive (SQLite)."""
    from pipelines.thermal_campaign import thermal_fit

    archive = resolve_archive(str(root / "archive"))
    archive.upgrade()
    sample = Sample(archive)
    # The two single runs of data_samples/ (its campaign and history folders are the
    # demo's; this sample builds its own below, with the counts the tests expect).
    singles = [DATA_SAMPLES / "mpu6000_MPU0001", DATA_SAMPLES / "csv_IMU-2026-0042"]
    for source in discover_runs(singles):
        outcome = process_run(source, archive)
        assert outcome["status"] == "ok", outcome["error"]
        sample.runs.setdefault(outcome["serial"], []).append(outcome["run_id"])
    rng = np.random.default_rng(23)
    lab = root / "lab"

    base = quiet_truth(rng)
    cube = {
        "kind": "cube",
        "model": "PC-100",
        "serial": "CUBE-D",
        "calibration_due": CUBE_DUE,
        "calibrated_on": "2024-06-30",
    }
    for k, day in enumerate(DRIFT_DAYS):
        truth = replace(base, acc_bias=base.acc_bias + np.array([DRIFT_PER_DAY * day, 0, 0]))
        started = DRIFT_START + timedelta(days=day)
        run = six_position_integral_run(truth, rng)
        write_csv_run(
            run.segments, lab / f"drift{k}", _manifest(DRIFT_SERIAL, started, equipment=[cube])
        )
        sample.runs.setdefault(DRIFT_SERIAL, []).append(processed_run(lab / f"drift{k}", archive))

    thermal = random_thermal_truth(rng)
    start = datetime(2026, 3, 2, 8, 0, tzinfo=UTC)
    for i, point in enumerate(thermal_campaign(thermal, rng, THERMAL_TEMPS)):
        folder = lab / f"thermal{i}"
        write_csv_run(
            point.run.segments,
            folder,
            _manifest(THERMAL_SERIAL, start + timedelta(days=i), temp=point.temperature),
        )
        sample.runs.setdefault(THERMAL_SERIAL, []).append(processed_run(folder, archive))
    thermal_fit(archive, THERMAL_SERIAL)

    evil = {
        "kind": "daq",
        "model": HOSTILE_MODEL,
        "serial": HOSTILE_EQUIPMENT,
        "calibration_due": "2027-01-31",
    }
    run = six_position_integral_run(quiet_truth(rng), rng)
    write_csv_run(
        run.segments,
        lab / "evil",
        _manifest(
            EVIL_SERIAL,
            datetime(2026, 5, 5, 10, 0, tzinfo=UTC),
            model=HOSTILE_MODEL,
            manufacturer="<b>ACME</b>",
            operator=HOSTILE_OPERATOR,
            equipment=[evil],
        ),
    )
    sample.runs[EVIL_SERIAL] = [processed_run(lab / "evil", archive)]
    archive.dispose()
    return sample
