"""Validation of the GUM budgets (issue 21 item 3): coverage of the 95 % intervals and MC check.

Simulated runs with known truth: the true error model from calib_core.simulate.random_errors,
the Type B sources (local gravity, fixture face angles, table rate error) drawn from their stated
distributions in calib_core.uncertainty_sources.EquipmentSpec, and the noise of each plateau mean
with a standard uncertainty estimated from n samples (so the Type A part has n - 1 degrees of
freedom and the t coverage factor matters). Families: six-position accelerometer (static
least squares) and rate-table gyro. Each run's budgets give U at about 95 %; the fraction of
(run, parameter) intervals covering the truth is reported per parameter family. On a subset of
runs the Monte Carlo interval (JCGM 101, numpy sampling through the same solver) is compared with
the linearised U. Last line: one JSON object with coverage_worst, coverage_best,
mc_vs_linear_max_rel, runs.

Usage: python benchmarks/uncertainty.py [--runs N] [--mc-runs M] [--mc-draws D] [--seed S]
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict

import numpy as np

from calib_core.simulate import STATIC_LABELS, random_errors
from calib_core.solvers.rate_table import RatePoint
from calib_core.uncertainty import InputQuantity
from calib_core.uncertainty_sources import (
    EquipmentSpec,
    rate_table_budgets,
    static_accel_budgets,
    static_inputs,
    static_reference,
)

G = 9.80665
N_SAMPLES = 12  # samples behind each plateau's estimated sem (Type A dof = 11)
DEG = np.pi / 180


def _draw(q: InputQuantity, rng: np.random.Generator) -> float:
    return float(q.sample(rng, 1)[0])


def _noisy(truth: np.ndarray, sigma: np.ndarray, rng: np.random.Generator):
    """Means with true std `sigma` and their sems estimated from N_SAMPLES samples."""
    x = truth[..., None] + sigma[..., None] * rng.standard_normal((*truth.shape, N_SAMPLES))
    return x.mean(-1), x.std(-1, ddof=1) / np.sqrt(N_SAMPLES)


def six_position_run(rng, spec, mc_draws=0):
    """(truth, budgets, mc) of one simulated six-position accelerometer run."""
    err = random_errors(rng)
    inputs = static_inputs(STATIC_LABELS, G, spec)
    actual = {q.name: _draw(q, rng) for q in inputs}
    f_true = static_reference(STATIC_LABELS, actual)
    out = f_true @ (np.eye(3) + err.acc_M).T + err.acc_bias
    means, sem = _noisy(out, np.full_like(out, 2e-3), rng)
    b, mc = static_accel_budgets(STATIC_LABELS, means, sem, N_SAMPLES - 1, G, spec, mc_draws, rng)
    truth = {}
    for i, a in enumerate("xyz"):
        truth[f"acc.bias.{a}"] = err.acc_bias[i]
        for j, c in enumerate("xyz"):
            truth[f"acc.scale.{a}" if i == j else f"acc.misalign.{a}{c}"] = err.acc_M[i, j]
    return truth, b, mc


def rate_table_run(rng, spec, mc_draws=0):
    """(truth, budgets, mc) of one simulated single-axis (z) rate-table gyro run."""
    err = random_errors(rng)
    eps = _draw(InputQuantity("r", 0.0, spec.table_rate_rel), rng)
    rates = np.array([-200, -100, -50, 0, 50, 100, 200]) * DEG
    w_true = np.zeros((len(rates), 3))
    w_true[:, 2] = rates * (1 + eps)  # the table turns at (1 + eps) times its reported rate
    out = w_true @ (np.eye(3) + err.gyr_M).T + err.gyr_bias
    means, sem = _noisy(out, np.full_like(out, 0.02 * DEG), rng)
    points = [RatePoint("z", float(r), m, s, N_SAMPLES)
              for r, m, s in zip(rates, means, sem, strict=True)]
    b, mc = rate_table_budgets(points, N_SAMPLES - 1, spec, mc_draws, rng)
    truth = {f"gyr.bias.{a}": err.gyr_bias[i] for i, a in enumerate("xyz")}
    truth.update({"gyr.scale.z": err.gyr_M[2, 2], "gyr.misalign.xz": err.gyr_M[0, 2],
                  "gyr.misalign.yz": err.gyr_M[1, 2]})
    return truth, b, mc


def family(name: str) -> str:
    """"acc.scale.x" -> "acc.scale"."""
    return name.rsplit(".", 1)[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=600, help="runs per procedure")
    ap.add_argument("--mc-runs", type=int, default=10, help="runs per procedure with MC check")
    ap.add_argument("--mc-draws", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=21)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    spec = EquipmentSpec()
    hits, total = defaultdict(int), defaultdict(int)
    mc_rel = []
    t0 = time.perf_counter()
    for make in (six_position_run, rate_table_run):
        for r in range(args.runs):
            draws = args.mc_draws if r < args.mc_runs else 0
            truth, b, mc = make(rng, spec, draws)
            for name, true in truth.items():
                fam = family(name)
                total[fam] += 1
                hits[fam] += abs(b[name].value - true) <= b[name].U
                if mc is not None:
                    half = (mc[name][2] - mc[name][1]) / 2
                    mc_rel.append(abs(half - b[name].U) / b[name].U)
    coverage = {f: hits[f] / total[f] for f in total}
    for f, c in sorted(coverage.items()):
        print(f"{f:18s} coverage {c:.4f} of {total[f]} intervals")
    print(json.dumps({
        "coverage_worst": round(min(coverage.values()), 4),
        "coverage_best": round(max(coverage.values()), 4),
        "mc_vs_linear_max_rel": round(max(mc_rel), 4),
        "runs": 2 * args.runs,
        "coverage": {f: round(c, 4) for f, c in coverage.items()},
        "seconds": round(time.perf_counter() - t0, 1),
    }))


if __name__ == "__main__":
    main()
