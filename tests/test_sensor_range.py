"""Sensor range from the sensor: a clipped reading is refused, not solved.

The MPU-6000 program's manual keeps the readings within +-250 deg/s and +-2 g and asks
the operator to repeat a turn that went beyond (docs/methods.md 2.6). An MPU-6000 folder
without run.toml therefore gets those ranges; a run.toml may state others.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from test_ingest_mpu6000 import mpu6000_run_toml

from calib_core import procedures
from calib_core.recording import Recording, first_range_hit
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.units import DEG, STANDARD_GRAVITY
from calib_testing.run_writers import write_mpu6000_run
from pipelines.ingest import IngestError, discover_runs, load_run

TRUE_SCALE_X = 0.021  # the unit: gyr.scale.x = +0.021


def clipped_run(rate_dps: float = 300.0, range_dps: float = 250.0):
    """A six-position + integral run whose turns peak at rate_dps, clipped at range_dps."""
    rng = np.random.default_rng(18)
    truth = random_errors(rng)
    m = truth.gyr_M.copy()
    m[0, 0] = TRUE_SCALE_X
    truth = dataclasses.replace(truth, gyr_M=m)
    return six_position_integral_run(
        truth, rng, rotation_rate_dps=rate_dps, gyro_range_dps=range_dps
    )


def test_clipped_turn_solved_as_unclipped_is_refused_by_the_closure_guard():
    # Why the refusal matters: solved as if the range were 2000 deg/s (the old default)
    # the clipped turns lose angle (the scale would come out wrong by far more than its
    # uncertainty); the rotations' closure on whole turns catches it without the range:
    # the lost angle is ~24 standard uncertainties of the closure, against a limit of 6.
    run = clipped_run()
    with pytest.raises(ValueError, match=r"differ from whole turns by .* a turn is incomplete"):
        procedures.solve("six_position_integral", run.segments, run.gravity, {})


def test_mpu6000_folder_refuses_the_clipped_turn_naming_file_time_axis(tmp_path: Path):
    write_mpu6000_run(clipped_run().segments, tmp_path, "MPU0250")
    (source,) = discover_runs([tmp_path])
    with pytest.raises(IngestError) as info:
        load_run(source)
    err = info.value
    assert err.file == str(tmp_path / "MPU0250_x_ccw.txt")
    assert "gyro x reads 250.000 deg/s at t = " in err.problem
    assert "+-250 deg/s, MPU-6000" in err.problem and "repeat the rotation slower" in err.problem


def test_the_same_turn_slower_loads_and_solves(tmp_path: Path):
    # 200 deg/s peak stays inside +-250: accepted, and the scale comes back. Tolerance:
    # 5 standard uncertainties of the fit (the integral's own noise propagation).
    write_mpu6000_run(clipped_run(rate_dps=200.0).segments, tmp_path, "MPU0200")
    (source,) = discover_runs([tmp_path])
    run = load_run(source)
    assert run.manifest.run.settings["gyro_range_dps"] == 250.0
    cal = procedures.solve(
        "six_position_integral", run.segments, run.manifest.gravity(), run.manifest.run.settings
    )
    p = cal.parameters["gyr.scale.x"]
    assert abs(p.value - TRUE_SCALE_X) < 5 * p.std


def test_run_toml_states_a_larger_range(tmp_path: Path):
    # The same 300 deg/s turns recorded with the sensor set to +-500 deg/s: not clipped.
    write_mpu6000_run(clipped_run(range_dps=500.0).segments, tmp_path, "MPU0500")
    (tmp_path / "run.toml").write_text(mpu6000_run_toml("MPU0500", "gyro_range_dps = 500\n"))
    (source,) = discover_runs([tmp_path])
    run = load_run(source)
    assert run.manifest.run.settings["gyro_range_dps"] == 500.0
    # Without the statement the model's +-250 deg/s applies and the turn is refused.
    text = (tmp_path / "run.toml").read_text().replace("gyro_range_dps = 500\n", "")
    (tmp_path / "run.toml").write_text(text)
    with pytest.raises(IngestError, match=r"MPU0500_x_ccw.txt.*gyro x reads 25\d\.\d+ deg/s"):
        load_run(source)


def test_accelerometer_at_its_range_is_named():
    t = np.arange(10) * 0.01
    acc = np.zeros((10, 3))
    acc[:, 2] = STANDARD_GRAVITY
    acc[6, 1] = -2.0 * STANDARD_GRAVITY  # a knock that clipped at -2 g
    rec = Recording(t, acc, np.zeros((10, 3)))
    hit = first_range_hit(rec, 250 * DEG, 2 * STANDARD_GRAVITY)
    assert (hit.sensor, hit.axis, hit.index, hit.time) == ("acc", "y", 6, 0.06)
    # 0.1 % below full scale is still clipping (RANGE_MARGIN); 1 % below is not.
    acc[6, 1] = -0.9995 * 2.0 * STANDARD_GRAVITY
    assert first_range_hit(rec, None, 2 * STANDARD_GRAVITY).axis == "y"
    acc[6, 1] = -0.99 * 2.0 * STANDARD_GRAVITY
    assert first_range_hit(rec, 250 * DEG, 2 * STANDARD_GRAVITY) is None
