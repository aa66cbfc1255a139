"""Both Foundation layouts, file -> ingest -> preprocess -> solve, against the simulator's truth.

Over several seeds, every parameter must be within 4 reported standard uncertainties of the
truth, and the reported uncertainties must be honest: the RMS error over seeds divided by the
RMS reported std lies in [0.5, 2]. With 12 draws per parameter the ratio of a sample RMS to
its expectation has a relative spread of about 1/sqrt(2*12) = 0.2, so [0.5, 2] fails only
for uncertainties that are really wrong, not by chance. The file formats round values
(MPU-6000: 1e-4 m/s^2, 1e-3 deg/s), which is far below the simulated noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib_core.earth import gravity_helmert
from calib_core.simulate import random_errors, six_position_integral_run
from calib_testing.run_writers import write_csv_run, write_mpu6000_run
from pipelines.ingest import discover_runs, load_run
from pipelines.process import solve_loaded

SEEDS = range(12)

CSV_MANIFEST = {
    "schema_version": 1,
    "unit": {"serial": "TRUTH-1", "model": "MPU-6000", "manufacturer": "InvenSense"},
    "run": {
        "started": "2026-11-20T09:15:00Z",
        "operator": "test",
        "procedure": "six_position_integral",
        "tolerance_profile": "mpu6000",
    },
    "site": {"latitude_deg": 52.0, "height_m": 100.0, "gravity_model": "helmert"},
    "format": {"kind": "csv", "acc_unit": "g", "gyr_unit": "deg/s", "time_unit": "ms"},
}


def _solve_layout(layout: str, seed: int, folder: Path) -> tuple[dict, dict]:
    rng = np.random.default_rng(seed)
    if layout == "mpu6000":
        sim = six_position_integral_run(random_errors(rng), rng)
        write_mpu6000_run(sim.segments, folder, f"T{seed:04d}", truth=sim.truth_dict())
    else:
        g = gravity_helmert(52.0, 100.0)
        sim = six_position_integral_run(random_errors(rng), rng, gravity=g, turns=2)
        write_csv_run(sim.segments, folder, CSV_MANIFEST, truth=sim.truth_dict())
    (source,) = discover_runs([folder])
    cal, *_ = solve_loaded(load_run(source))
    truth = sim.truth_dict()["parameters"]
    return {n: (p.value, p.std) for n, p in cal.parameters.items()}, truth


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["mpu6000", "csv"])
def test_parameters_within_their_uncertainty_over_seeds(layout, tmp_path):
    errors: dict[str, list[float]] = {}
    stds: dict[str, list[float]] = {}
    for seed in SEEDS:
        got, truth = _solve_layout(layout, seed, tmp_path / f"{layout}-{seed}")
        for name, (value, std) in got.items():
            if ".noise." in name:  # a noise level, judged by its own test
                continue
            assert std is not None and std > 0, name
            err = value - truth[name]
            assert abs(err) <= 4 * std, f"seed {seed} {name}: error {err:.3g}, std {std:.3g}"
            errors.setdefault(name, []).append(err)
            stds.setdefault(name, []).append(std)
    assert len(errors) == 33  # 12 accelerometer + 12 gyro (bias + matrix) + 9 g-sensitivity
    for name in errors:
        ratio = np.sqrt(np.mean(np.square(errors[name]))) / np.sqrt(np.mean(np.square(stds[name])))
        assert 0.5 <= ratio <= 2.0, f"{name}: observed scatter / reported std = {ratio:.2f}"
