"""Regenerate data_samples/: simulated lab runs with known truth, in every supported layout.

    .venv/bin/python scripts/make_data_samples.py

Deterministic (fixed seeds), so the committed files only change when the simulator or a
writer changes.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np

from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.units import DEG
from pipelines.run_writers import write_csv_run, write_mpu6000_run

ROOT = Path(__file__).resolve().parent.parent / "data_samples"

CSV_MANIFEST = {
    "schema_version": 1,
    "unit": {
        "serial": "IMU-2026-0042",
        "model": "MPU-6000",
        "manufacturer": "InvenSense",
        "specification": "6-axis MEMS, +-2000 deg/s, +-16 g",
    },
    "run": {
        "started": "2026-11-20T09:15:00+01:00",
        "operator": "J. Doe",
        "procedure": "six_position_integral",
        "tolerance_profile": "mpu6000",
        "settings": {"gyro_range_dps": 2000.0},
    },
    "site": {"latitude_deg": 48.137, "height_m": 519.0, "gravity_model": "helmert"},
    "environment": {
        "temperature_c": 20.4,
        "humidity_pct": 46.0,
        "pressure_hpa": 957.0,
        "vibration": "isolated granite table",
        "warmup_min": 20.0,
    },
    "equipment": [
        {
            "kind": "cube",
            "model": "Precision cube PC-100",
            "serial": "CUBE-7",
            "accuracy_class": "0.01 deg",
            "calibration_due": "2027-06-30",
        },
        {
            "kind": "daq",
            "model": "USB-IMU-Logger",
            "serial": "DAQ-12",
            "accuracy_class": "1 ms timestamp",
            "calibration_due": "2027-01-31",
        },
    ],
    "format": {"kind": "csv", "acc_unit": "g", "gyr_unit": "deg/s", "time_unit": "s"},
}


def main() -> None:
    if ROOT.exists():
        shutil.rmtree(ROOT)
    # MPU-6000 layout: recognised by file names, no manifest
    # a unit inside every MPU-6000 tolerance (gyro noise 0.03 deg/s < 0.05 deg/s): verdict pass
    rng = np.random.default_rng(20261120)
    truth = dataclasses.replace(random_errors(rng), gyr_noise=np.full(3, 0.03 * DEG))
    sim = six_position_integral_run(truth, rng)
    write_mpu6000_run(sim.segments, ROOT / "mpu6000_MPU0001", "MPU0001", truth=sim.truth_dict())
    # headered CSV + run.toml, Helmert gravity at the site
    from calib_core.earth import gravity_helmert

    # a unit with a noisy gyro x channel (0.06 deg/s > 0.05 deg/s): verdict fail on noise
    rng = np.random.default_rng(20261121)
    g = gravity_helmert(48.137, 519.0)
    truth = dataclasses.replace(random_errors(rng), gyr_noise=np.array([0.06, 0.03, 0.03]) * DEG)
    sim = six_position_integral_run(truth, rng, gravity=g, turns=2)
    write_csv_run(sim.segments, ROOT / "csv_IMU-2026-0042", CSV_MANIFEST, truth=sim.truth_dict())
    (ROOT / "README.md").write_text(
        "# data_samples\n\nSimulated lab runs with known truth, made by "
        "`scripts/make_data_samples.py` (calib_core.simulate); `make demo` processes them.\n\n"
        "- `mpu6000_MPU0001/`: the MPU-6000 text layout (`<serial>_<axis>_<up|dn|cw|ccw>.txt`, "
        "no manifest), truth in `MPU0001_truth.json`; within tolerance (pass).\n"
        "- `csv_IMU-2026-0042/`: one headered CSV (`imu.csv`, g and deg/s) described by "
        "`run.toml`, Helmert gravity at the site, 2-turn rotations, truth in `truth.json`; "
        "gyro x noise 0.06 deg/s exceeds the "
        "profile's 0.05 deg/s (fail).\n",
        encoding="utf-8",
    )
    print(f"wrote {ROOT}")


if __name__ == "__main__":
    main()
