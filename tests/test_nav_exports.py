"""`calib export RUN --format kalibr|openvins` (docs/exports.md, "Noise models for Kalibr and
OpenVINS"): a simulated static-bias run with known noise, archived by the real pipeline into a
real SQLite file, exported by the CLI and read back with PyYAML."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from calib_core.nav_noise import NavNoise, NavTerm, bootstrap_terms, noise_records
from calib_core.noise import NoiseParameters, cluster_sizes
from calib_core.simulate.noise import NoiseSpec, simulate_static
from calib_core.solvers.static_bias import sensor_statistics
from calib_testing.archives import static_bias_archive
from pipelines import nav_exports
from pipelines.cli import app
from pipelines.ingest import discover_runs
from pipelines.process import process_run
from storage.db import resolve_archive

DOCS = Path(__file__).parents[1] / "docs" / "exports.md"
# Truth of the simulated unit (white + random walk, Kalibr's units): crossovers
# sqrt(3) N / K = 12 s and 17 s, well inside the 900 s record.
ACC_N, ACC_K = 2.0e-3, 3.0e-4  # m/s^2/sqrt(Hz), m/s^3/sqrt(Hz)
GYR_N, GYR_K = 2.0e-4, 2.0e-5  # rad/s/sqrt(Hz), rad/s^2/sqrt(Hz)
RATE_HZ, DURATION_S = 50.0, 900.0
# The exported value is the largest of three axes, each known to its bootstrap u (itself
# known to ~16 % from 20 replicates): k = 3 keeps the chance of a false failure < 1 %.
K_COVER = 3.0


@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    rng = np.random.default_rng(39)
    rec = simulate_static(
        DURATION_S,
        RATE_HZ,
        gyro_bias=np.array([1e-3, -2e-3, 5e-4]),
        gyro_noise=NoiseSpec(GYR_N, 0.0, GYR_K),
        acc_noise=NoiseSpec(ACC_N, 0.0, ACC_K),
        rng=rng,
    )
    return static_bias_archive(tmp_path_factory.mktemp("nav"), rec, "NAV-0001")


def _export(archive, run_id: str, *args: str) -> str:
    res = CliRunner().invoke(app, ["export", run_id, "--archive", str(archive.root), *args])
    assert res.exit_code == 0, res.output
    return res.stdout


def _uncertainty(text: str, key: str) -> float:
    """The standard uncertainty the file's comments give for `key`."""
    m = re.search(rf"#\s+{key} \[[^\]]+\] = \S+ \(axis [xyz]\), u = (\S+) ", text)
    assert m, f"no uncertainty comment for {key}"
    return float(m[1])


TRUTH = {
    "accelerometer_noise_density": ACC_N,
    "accelerometer_random_walk": ACC_K,
    "gyroscope_noise_density": GYR_N,
    "gyroscope_random_walk": GYR_K,
}


def test_kalibr_export_recovers_the_simulated_noise(static_run):
    archive, run_id = static_run
    text = _export(archive, run_id, "--format", "kalibr", "--rostopic", "/sensors/imu")
    doc = yaml.safe_load(text)
    assert doc["rostopic"] == "/sensors/imu" and doc["update_rate"] == RATE_HZ
    for key, truth in TRUTH.items():
        u = _uncertainty(text, key)
        assert 0 < u < 0.5 * truth, (key, u)  # a 15 min record pins each term this well
        assert abs(doc[key] - truth) <= K_COVER * u, (key, doc[key], truth, u)
    # The conversion and the advice are in the comments, not applied.
    assert "Not inflated" in text and "sigma/sqrt(dt)" in text
    disc = math.sqrt(RATE_HZ) * doc["accelerometer_noise_density"]
    assert f"acc {disc:.6e} m/s^2" in text


def test_openvins_export_reads_back(static_run):
    archive, run_id = static_run
    text = _export(archive, run_id, "--format", "openvins", "--update-rate", "200")
    first, rest = text.split("\n", 1)
    assert first == "%YAML:1.0"  # OpenCV FileStorage's header, which PyYAML does not take
    imu = yaml.safe_load(rest)["imu0"]
    kalibr = yaml.safe_load(_export(archive, run_id, "--format", "kalibr"))
    for key in TRUTH:
        assert imu[key] == kalibr[key]  # the update rate does not change a continuous value
    assert imu["update_rate"] == 200.0 and imu["model"] == "kalibr" and imu["rostopic"] == "/imu0"
    assert np.array_equal(imu["Tw"], np.eye(3)) and np.array_equal(imu["T_i_b"], np.eye(4))
    assert np.array_equal(imu["Tg"], np.zeros((3, 3)))
    # OpenCV's reader: no comment after a value on the same line
    assert not [ln for ln in rest.splitlines() if "#" in ln and not ln.lstrip().startswith("#")]


def test_noise_model_of_another_procedure_is_refused(tmp_path):
    from serve_sample import DATA_SAMPLES

    archive = resolve_archive(str(tmp_path / "archive"))
    archive.upgrade()
    (source,) = discover_runs([DATA_SAMPLES / "mpu6000_MPU0001"])
    outcome = process_run(source, archive)
    res = CliRunner().invoke(
        app, ["export", outcome["run_id"], "--archive", str(archive.root), "--format", "kalibr"]
    )
    assert res.exit_code != 0
    assert "needs a static-bias (Allan) run" in res.output and "six_position_integral" in res.output


def test_bootstrap_uncertainty_covers_the_truth():
    """The bootstrap's u against the truth over independent records of one mix (the
    solver's own chain, then `bootstrap_terms` from the fitted values): the share within
    2u must be consistent with 95 % (binomial, 3 axes x 2 terms x 8 records)."""
    truth = NoiseParameters(ACC_N, 0.0, ACC_K, "model")
    rng = np.random.default_rng(7)
    n, hits, total = int(300 * RATE_HZ), 0, 0
    for _ in range(8):
        x = noise_records([truth] * 3, n, RATE_HZ, rng)
        taus = np.asarray(cluster_sizes(n, RATE_HZ), dtype=float) / RATE_HZ
        fitted = sensor_statistics(x, RATE_HZ, 3.0, taus)[4]
        boot = bootstrap_terms(fitted, n, RATE_HZ, 3.0, taus)
        for got, value, bias, sd in (
            ([p.arw for p in fitted], ACC_N, boot["n_bias"], boot["n_sd"]),
            ([p.rrw for p in fitted], ACC_K, boot["k_bias"], boot["k_sd"]),
        ):
            hits += int(np.sum(np.abs(np.array(got) - value) <= 2 * np.hypot(bias, sd)))
            total += 3
    # 48 comparisons at 95 %: fewer than 40 hits has probability < 0.3 %
    assert hits >= 40, (hits, total)


def _doc_example() -> tuple[str, str]:
    """The worked example's input line and YAML block in docs/exports.md."""
    text = DOCS.read_text()
    section = text.split("### Worked example", 1)[1]
    block = section.split("```yaml\n", 1)[1].split("```", 1)[0]
    return section, block


def test_docs_worked_example():
    """The numbers of docs/exports.md's worked example are what the writer produces."""
    section, block = _doc_example()
    vals = {k: float(v) for k, v in re.findall(r"`(\w+) = ([0-9.e+-]+)`", section)}

    def term(value: float, unit: str) -> NavTerm:
        return NavTerm(np.full(3, value), np.full(3, 0.01 * value), np.zeros(3), unit)

    nav = NavNoise(
        term(vals["N_acc"], "m/s^2/sqrt(Hz)"),
        term(vals["K_acc"], "m/s^3/sqrt(Hz)"),
        term(vals["N_gyr"], "rad/s/sqrt(Hz)"),
        term(vals["K_gyr"], "rad/s^2/sqrt(Hz)"),
        sample_rate_hz=vals["f"],
        duration_s=3600.0,
        methods={},
    )
    text = nav_exports.kalibr_yaml(nav, update_rate_hz=vals["f"])
    keys = [ln for ln in text.splitlines() if ln and not ln.startswith("#")]
    assert keys == [ln for ln in block.splitlines() if ln and not ln.startswith("#")]
    disc = nav.discrete(vals["f"])
    for name, value in disc.items():
        assert f"{value:.6e}" in section, name  # the discrete values the section quotes
        assert f"{value:.6e}" in text
