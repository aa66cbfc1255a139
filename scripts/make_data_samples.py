"""Regenerate data_samples/: simulated lab runs with known truth, in every supported layout.

    .venv/bin/python scripts/make_data_samples.py

Deterministic (fixed seeds), so the committed files only change when the simulator or a
writer changes.
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import numpy as np

# calib_testing (the run writers) is a support package of the repository, not installed
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from calib_core.simulate import random_errors, six_position_integral_run  # noqa: E402
from calib_core.simulate.noise import NoiseSpec, simulate_static  # noqa: E402
from calib_core.simulate.thermal import (  # noqa: E402
    random_thermal_truth,
    recalibration_history,
    thermal_campaign,
)
from calib_core.units import DEG  # noqa: E402
from calib_testing.run_writers import write_csv_run, write_mpu6000_run  # noqa: E402

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
        "temperature_drift_c_per_h": 0.2,
    },
    # Sample values (the data are simulated): what a lab records of its acquisition.
    "acquisition": {"settle_s": 30.0, "resolution_bits": 16},
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


# Small runs that still keep the acquisition rules the checks judge (calib_core.conditions:
# the MPU-6000 program's ~50 Hz, >= 10 s per attitude): about 3.5 MB for both in all.
SMALL_RUN = {"rate_hz": 50.0, "static_s": 10.5}
THERMAL_SERIAL, THERMAL_TEMPS_C = "IMU-T-0007", (0.0, 20.0, 40.0, 60.0)
HISTORY_SERIAL = "IMU-R-0003"
HISTORY_DATES = ("2026-02-03", "2026-05-05", "2026-08-04", "2026-11-03")
NOISE_SERIAL = "IMU-N-0011"
# A static record of 10 min at 50 Hz (about 2.4 MB): the procedure asks for >= 60 min, which
# the sample fails on purpose (a few MB in the repository). Densities of an MPU-6000's data
# sheet: gyro 0.005 deg/s/sqrt(Hz), accelerometer 400 ug/sqrt(Hz); random walks a tenth.
NOISE_RUN = {"duration_s": 600.0, "rate_hz": 50.0}
GYRO_DENSITY, ACC_DENSITY = 0.005 * DEG, 400e-6 * 9.80665
STATICS = ("x_up", "x_dn", "y_up", "y_dn", "z_up", "z_dn")


def _manifest(serial: str, started: str, procedure: str, temperature_c: float) -> dict:
    """A CSV run's manifest: the unit, the run's start (its archive date), the procedure."""
    doc = {k: v for k, v in CSV_MANIFEST.items() if k not in ("unit", "run", "site")}
    return {
        **doc,
        "unit": {**CSV_MANIFEST["unit"], "serial": serial},
        "run": {
            "started": started,
            "operator": "J. Doe",
            "procedure": procedure,
            "tolerance_profile": "mpu6000",
            "settings": {"gyro_range_dps": 2000.0},
        },
        "site": {"gravity_model": "standard"},
        "environment": {**CSV_MANIFEST["environment"], "temperature_c": temperature_c},
    }


def write_thermal_campaign() -> None:
    """One unit at four chamber temperatures, a day apart: `calib thermal fit` material."""
    rng = np.random.default_rng(20261122)
    base = dataclasses.replace(random_errors(rng), gyr_noise=np.full(3, 0.03 * DEG))
    truth = random_thermal_truth(rng, base=base)
    for i, run in enumerate(thermal_campaign(truth, rng, THERMAL_TEMPS_C, **SMALL_RUN)):
        started = f"2026-10-{12 + i:02d}T09:00:00+02:00"
        folder = ROOT / "thermal_IMU-T-0007" / f"run_{run.temperature:+03.0f}C"
        manifest = _manifest(THERMAL_SERIAL, started, "six_position_integral", run.temperature)
        write_csv_run(run.run.segments, folder, manifest, truth=run.run.truth_dict())


def write_history() -> None:
    """One unit re-calibrated quarterly (six statics), its z accelerometer bias drifting
    by 2e-5 m/s^2 a day: `calib trend` and `calib repeatability` material."""
    rng = np.random.default_rng(20261123)
    base = dataclasses.replace(random_errors(rng), gyr_noise=np.full(3, 0.03 * DEG))
    drift = {"acc.bias.z": 2e-5}
    entries = recalibration_history(
        base,
        rng,
        n_runs=len(HISTORY_DATES),
        interval_days=91.0,
        jitter_days=0.0,
        drift_per_day=drift,
    )
    for date, entry in zip(HISTORY_DATES, entries, strict=True):
        sim = six_position_integral_run(entry.errors, rng, **SMALL_RUN)
        statics = {label: sim.segments[label] for label in STATICS}
        manifest = _manifest(HISTORY_SERIAL, f"{date}T10:00:00+01:00", "six_position", 20.0)
        write_csv_run(statics, ROOT / "history_IMU-R-0003" / date, manifest, truth=sim.truth_dict())


def write_noise_run() -> None:
    """A static-bias (noise) run: biases, noise and the Kalibr / OpenVINS noise models
    (`calib export RUN --format kalibr|openvins`)."""
    rng = np.random.default_rng(20261124)
    rec = simulate_static(
        NOISE_RUN["duration_s"],
        NOISE_RUN["rate_hz"],
        gyro_bias=np.array([1e-3, -2e-3, 5e-4]),
        gyro_noise=NoiseSpec(GYRO_DENSITY, 0.0, GYRO_DENSITY / 10.0),
        acc_bias=np.array([0.02, -0.01, 0.03]),
        acc_noise=NoiseSpec(ACC_DENSITY, 0.0, ACC_DENSITY / 10.0),
        rng=rng,
    )
    manifest = _manifest(NOISE_SERIAL, "2026-11-24T09:00:00+01:00", "static_bias", 20.4)
    manifest["run"]["settings"] = {"up_axis": "+z"}
    truth = {
        "gyr.bias": [1e-3, -2e-3, 5e-4],
        "acc.bias": [0.02, -0.01, 0.03],
        "gyroscope_noise_density": GYRO_DENSITY,
        "gyroscope_random_walk": GYRO_DENSITY / 10.0,
        "accelerometer_noise_density": ACC_DENSITY,
        "accelerometer_random_walk": ACC_DENSITY / 10.0,
    }
    write_csv_run({"static": rec}, ROOT / f"static_bias_{NOISE_SERIAL}", manifest, truth=truth)


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
    write_thermal_campaign()
    write_history()
    write_noise_run()
    (ROOT / "README.md").write_text(
        "# data_samples\n\nSimulated lab runs with known truth, made by "
        "`scripts/make_data_samples.py` (calib_core.simulate); `make demo` processes them.\n\n"
        "- `mpu6000_MPU0001/`: the MPU-6000 text layout (`<serial>_<axis>_<up|dn|cw|ccw>.txt`, "
        "no manifest), truth in `MPU0001_truth.json`; within tolerance (pass).\n"
        "- `csv_IMU-2026-0042/`: one headered CSV (`imu.csv`, g and deg/s) described by "
        "`run.toml`, Helmert gravity at the site, 2-turn rotations, truth in `truth.json`; "
        "gyro x noise 0.06 deg/s exceeds the "
        "profile's 0.05 deg/s (fail). Its lab conditions (`[environment]`, `[acquisition]`) "
        "are plausible sample values, not measurements (so are the two below); the MPU-6000 "
        'folder records none, so its certificate shows them "not recorded" and standard '
        "gravity with a warning.\n"
        "- `thermal_IMU-T-0007/`: a thermal campaign, one unit at 0, 20, 40 and 60 deg C on four "
        "days (CSV + run.toml each, `environment.temperature_c`), biases quadratic and scales "
        "linear in temperature: `calib thermal fit IMU-T-0007`.\n"
        "- `history_IMU-R-0003/`: one unit re-calibrated quarterly in 2026 (six statics; the "
        "dates are the manifests' `run.started`), its z accelerometer bias drifting by "
        "2e-5 m/s^2 a day: `calib trend`, `calib repeatability`.\n"
        f"- `static_bias_{NOISE_SERIAL}/`: a static-bias (noise) run, 10 min at 50 Hz on a "
        "level fixture (z up), white noise and random walk of known densities (truth in "
        "`truth.json`, SI units): biases and noise on its certificate, and the noise models "
        "for Kalibr and OpenVINS (`calib export RUN --format kalibr`). The procedure asks for "
        ">= 60 min of record: its certificate fails that condition, as a 10 min sample must.\n\n"
        "All of them are simulated (no real sensor recorded them); the real recordings the "
        "tests read are in `tests/realdata/`.\n",
        encoding="utf-8",
    )
    print(f"wrote {ROOT}")


if __name__ == "__main__":
    main()
