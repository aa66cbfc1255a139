"""Time per calibration procedure on realistic sizes (1 kHz, each procedure's full duration),
and the CRLB efficiency of the linear rate-table least squares from a Monte Carlo run.

Run: ``.venv/bin/python benchmarks/solvers.py``. The last stdout line is one JSON object:
{"seconds": {"<procedure>": float, ...}, "crlb_efficiency_worst": float}, where the
efficiency is CRLB variance / observed variance of the worst parameter (1 = no
information wasted).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib_core.noise import FLICKER_FACTOR, allan_deviation  # noqa: E402
from calib_core.simulate.noise import NoiseSpec, simulate_static  # noqa: E402
from calib_core.simulate.rate_table import GyroTruth, simulate_rate_table  # noqa: E402
from calib_core.solvers.rate_table import rate_points, solve_rate_table  # noqa: E402
from calib_core.solvers.static_bias import solve_static_bias  # noqa: E402
from calib_core.units import DEG  # noqa: E402

RATE_HZ = 1000.0
RATES = tuple(r * DEG for r in (-100.0, -50.0, 0.0, 50.0, 100.0))
TRUTH = GyroTruth(
    bias=np.array([0.01, -0.02, 0.005]),
    M=np.array([[0.01, 0.002, -0.001], [0.003, -0.02, 0.004], [-0.002, 0.001, 0.015]]),
)


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def bench_allan_10m() -> float:
    """Octave overlapping Allan deviation of 10 M samples (one channel)."""
    x = np.random.default_rng(0).standard_normal(10_000_000)
    _, s = _timed(lambda: allan_deviation(x, RATE_HZ, "octave"))
    return s


def bench_static_bias() -> float:
    """60 min at 1 kHz (3.6 M samples x 6 channels), white + flicker + random walk."""
    b = 2e-4
    spec = NoiseSpec(
        arw=math.sqrt((FLICKER_FACTOR * b) ** 2 * 5),
        bias_instability=b,
        rrw=math.sqrt(3 * (FLICKER_FACTOR * b) ** 2 / 60),
    )
    rec = simulate_static(
        3600.0,
        RATE_HZ,
        gyro_bias=np.zeros(3),
        gyro_noise=spec,
        acc_noise=NoiseSpec(arw=1e-3),
        rng=np.random.default_rng(1),
    )
    _, s = _timed(lambda: solve_static_bias(rec, up_axis="+z"))
    return s


def bench_rate_table() -> float:
    """3 axes x 5 rates x (20 s settle + 10 s record) at 1 kHz: reduction + least squares."""
    run = simulate_rate_table(
        TRUTH,
        rates=RATES,
        rate_hz=RATE_HZ,
        gyro_noise_density=0.01 * DEG,
        rng=np.random.default_rng(2),
    )
    _, s = _timed(lambda: solve_rate_table(rate_points(run.recordings)))
    return s


def bench_six_position_integral() -> float | None:
    """Six 60 s statics + one turn each way about each axis at 1 kHz, if the solver exists."""
    try:
        from calib_core.procedures import solve
        from calib_core.simulate.lab_run import random_errors, six_position_integral_run
    except ImportError as exc:
        print(f"six_position_integral: skipped, solver not available ({exc})")
        return None
    rng = np.random.default_rng(3)
    run = six_position_integral_run(random_errors(rng), rng, rate_hz=RATE_HZ, static_s=60.0)
    _, s = _timed(lambda: solve("six_position_integral", run.segments, run.gravity, {}))
    return s


def crlb_efficiency_rate_table(runs: int = 200) -> float:
    """Worst CRLB variance / observed variance over the 12 rate-table parameters.

    White noise, 100 Hz plateaus (the efficiency does not depend on the rate); the
    bound is sigma^2 / n (A^T A)^-1 per channel with A = [1, w_x, w_y, w_z].
    """
    rate_hz, record_s, density = 100.0, 10.0, 0.01 * DEG
    names = [f"gyr.bias.{a}" for a in "xyz"] + [
        f"gyr.scale.{r}" if r == c else f"gyr.misalign.{r}{c}" for r in "xyz" for c in "xyz"
    ]
    truth = np.concatenate([TRUTH.bias, TRUTH.M.ravel()])
    errs = []
    for seed in range(runs):
        run = simulate_rate_table(
            TRUTH,
            rates=RATES,
            rate_hz=rate_hz,
            record_s=record_s,
            gyro_noise_density=density,
            rng=np.random.default_rng(1000 + seed),
        )
        cal = solve_rate_table(rate_points(run.recordings))
        errs.append([cal.parameters[n].value for n in names] - truth)
    observed = np.var(errs, axis=0, ddof=1)
    A = np.array([[1.0, *(w * np.eye(3)[ax])] for ax in range(3) for w in RATES])
    c = np.diag(np.linalg.inv(A.T @ A)) * density**2 / record_s
    crlb = np.concatenate([np.full(3, c[0]), np.tile(c[1:], 3)])
    return float(np.min(crlb / observed))


def main() -> None:
    seconds: dict[str, float] = {}
    seconds["allan_deviation_10M"] = bench_allan_10m()
    seconds["static_bias"] = bench_static_bias()
    seconds["rate_table"] = bench_rate_table()
    spi = bench_six_position_integral()
    if spi is not None:
        seconds["six_position_integral"] = spi
    for k, v in seconds.items():
        print(f"{k:24s} {v:8.3f} s")
    eff = crlb_efficiency_rate_table()
    print(f"rate_table CRLB efficiency (worst parameter, 200 runs): {eff:.3f}")
    print(json.dumps({"seconds": seconds, "crlb_efficiency_worst": eff}))


if __name__ == "__main__":
    main()
