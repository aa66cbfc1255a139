"""Validation of the GUM budgets: coverage of the 95 % intervals and MC check.

Simulated runs with known truth: the true error model from calib_core.simulate.random_errors,
the Type B sources (local gravity, fixture face angles, table rate error) drawn from their stated
distributions in calib_core.uncertainty_sources.EquipmentSpec, and the noise of each plateau mean
with a standard uncertainty estimated from n samples (so the Type A part has n - 1 degrees of
freedom and the t coverage factor matters). Procedures: six-position accelerometer (static
least squares), six-position + integral gyro (statics and n-turn rotations whose actual angle and
axis carry the turn-angle and face-angle errors) and rate-table gyro. Each run's budgets give U at
about 95 % (k from Student's t, or from the linearised model's propagated distribution when a
rectangular input contributes: calib_core.uncertainty.combine); the fraction of (run, parameter)
intervals covering the truth is reported per procedure and parameter family. On a subset of runs
the Monte Carlo interval (JCGM 101, numpy sampling through the same solver) is compared with the
linearised U. Last line: one JSON object with coverage_worst, coverage_best,
mc_vs_linear_max_rel, runs.

Usage: python benchmarks/uncertainty.py [--runs N] [--mc-runs M] [--mc-draws D] [--seed S]
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict

import numpy as np

from calib_core import params
from calib_core.simulate import STATIC_LABELS, random_errors
from calib_core.solvers.integral import ROTATION_LABELS
from calib_core.solvers.multi_position import solve_accel_linear
from calib_core.solvers.rate_table import RatePoint
from calib_core.uncertainty import InputQuantity, budgets, monte_carlo
from calib_core.uncertainty_sources import (
    EquipmentSpec,
    integral_inputs,
    rate_table_budgets,
    reference_forces,
    static_accel_budgets,
    static_inputs,
    static_solve,
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
    f_true = reference_forces(STATIC_LABELS, actual)
    out = f_true @ (np.eye(3) + err.acc_M).T + err.acc_bias
    means, sem = _noisy(out, np.full_like(out, 2e-3), rng)
    b, mc = static_accel_budgets(STATIC_LABELS, means, sem, N_SAMPLES - 1, G, spec, mc_draws, rng)
    truth = {}
    for i, a in enumerate("xyz"):
        truth[f"acc.bias.{a}"] = err.acc_bias[i]
        for j, c in enumerate("xyz"):
            truth[f"acc.scale.{a}" if i == j else f"acc.misalign.{a}{c}"] = err.acc_M[i, j]
    return truth, b, mc


TURNS = 2
INTEGRAL_NOISE = 0.02 * DEG * np.sqrt(0.01 * 20.0)  # rad: 0.02 deg/s white noise, 100 Hz, 20 s


def integral_run(rng, spec, mc_draws=0):
    """(truth, budgets, mc) of one simulated six-position + integral gyro run.

    The statics see gravity through the tilted faces; each rotation turns 2 pi n plus its drawn
    turn-angle error about the vertical, which the face angle of "A_up" tilts in the body frame.
    The rotation integrals J carry white noise of known std (INTEGRAL_NOISE, dof infinite).
    """
    err = random_errors(rng)
    inputs = static_inputs(STATIC_LABELS, G, spec) + integral_inputs(ROTATION_LABELS, spec)
    actual = {q.name: _draw(q, rng) for q in inputs}
    f_true = reference_forces(STATIC_LABELS, actual)
    acc = _noisy(f_true @ (np.eye(3) + err.acc_M).T + err.acc_bias, np.full((6, 3), 2e-3), rng)
    gyr = _noisy(f_true @ err.gsens.T + err.gyr_bias, np.full((6, 3), 0.02 * DEG), rng)
    nominal = np.diag([2 * np.pi * TURNS * 2] * 3)  # ccw - cw per axis
    true_angles = np.zeros((3, 3))
    for label in ROTATION_LABELS:
        j = "xyz".index(label[0])
        up = reference_forces([f"{label[0]}_up"], actual)[0]  # the vertical in the body frame
        axis = up / np.linalg.norm(up)
        true_angles[:, j] += (2 * np.pi * TURNS + actual[f"turn.{label}"]) * axis
    J = (np.eye(3) + err.gyr_M) @ true_angles
    J += INTEGRAL_NOISE * np.sqrt(2.0) * rng.standard_normal((3, 3))  # ccw and cw records
    estimate = J @ np.linalg.inv(nominal)
    solve = static_solve(STATIC_LABELS, acc, gyr, G, (estimate, TURNS, ROTATION_LABELS))
    nominal_values = solve({})
    std_j = INTEGRAL_NOISE * np.sqrt(2.0) / nominal[0, 0]
    acc_fit = solve_accel_linear(reference_forces(STATIC_LABELS, {"gravity": G}), *acc)
    type_a = {n: (u, N_SAMPLES - 1) for n, u in acc_fit.std.items()}
    type_a.update({n: (std_j, np.inf) for row in params.matrix_names("gyr") for n in row})
    b = budgets(solve, inputs, type_a, estimates={n: nominal_values[n] for n in type_a})
    mc = monte_carlo(solve, inputs, type_a, mc_draws, rng) if mc_draws else None
    truth = {f"acc.bias.{a}": err.acc_bias[i] for i, a in enumerate("xyz")}
    for i, row in enumerate(params.matrix_names("acc")):
        truth.update({n: err.acc_M[i, j] for j, n in enumerate(row)})
    for i, row in enumerate(params.matrix_names("gyr")):
        truth.update({n: err.gyr_M[i, j] for j, n in enumerate(row)})
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
    points = [
        RatePoint("z", float(r), m, s, N_SAMPLES) for r, m, s in zip(rates, means, sem, strict=True)
    ]
    b, mc = rate_table_budgets(points, N_SAMPLES - 1, spec, mc_draws, rng)
    truth = {f"gyr.bias.{a}": err.gyr_bias[i] for i, a in enumerate("xyz")}
    truth.update(
        {
            "gyr.scale.z": err.gyr_M[2, 2],
            "gyr.misalign.xz": err.gyr_M[0, 2],
            "gyr.misalign.yz": err.gyr_M[1, 2],
        }
    )
    return truth, b, mc


def family(name: str) -> str:
    """ "acc.scale.x" -> "acc.scale"."""
    return name.rsplit(".", 1)[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=400, help="runs per procedure")
    ap.add_argument("--mc-runs", type=int, default=10, help="runs per procedure with MC check")
    ap.add_argument("--mc-draws", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=21)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    spec = EquipmentSpec()
    hits, total = defaultdict(int), defaultdict(int)
    mc_rel = []
    t0 = time.perf_counter()
    procedures = {
        "six_position": six_position_run,
        "integral": integral_run,
        "rate_table": rate_table_run,
    }
    for proc, make in procedures.items():
        for r in range(args.runs):
            draws = args.mc_draws if r < args.mc_runs else 0
            truth, b, mc = make(rng, spec, draws)
            for name, true in truth.items():
                fam = f"{proc}:{family(name)}"
                total[fam] += 1
                hits[fam] += abs(b[name].value - true) <= b[name].U
                if mc is not None:
                    half = (mc[name][2] - mc[name][1]) / 2
                    mc_rel.append(abs(half - b[name].U) / b[name].U)
    coverage = {f: hits[f] / total[f] for f in total}
    for f, c in sorted(coverage.items()):
        print(f"{f:28s} coverage {c:.4f} of {total[f]} intervals")
    print(
        json.dumps(
            {
                "coverage_worst": round(min(coverage.values()), 4),
                "coverage_best": round(max(coverage.values()), 4),
                "mc_vs_linear_max_rel": round(max(mc_rel), 4),
                "runs": len(procedures) * args.runs,
                "coverage": {f: round(c, 4) for f, c in coverage.items()},
                "seconds": round(time.perf_counter() - t0, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
