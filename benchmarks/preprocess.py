"""Throughput of the preprocessing chain on 1 kHz, 1-hour rate-table data.

Chain: clock alignment of the table feedback (estimate + resample), rate-plateau
segmentation, outlier removal per plateau (3-sigma, interpolate), zero-phase
low-pass of all six channels. Compared with one plain scipy.signal.sosfiltfilt
pass over the same (N, 6) array, both timed REPEATS times in alternation
(medians; see main). Progress goes to stderr; the last stdout line is one JSON
object with the figures.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
from scipy.signal import sosfiltfilt

from calib_core.preprocess.filters import design_lowpass, lowpass
from calib_core.preprocess.outliers import remove_outliers
from calib_core.preprocess.segments import detect_rate_plateaus
from calib_core.preprocess.sync import ClockModel, synchronise
from calib_core.simulate.table import rate_table_run
from calib_core.units import DEG

FS = 1000.0
CUTOFF = 50.0
REPEATS = 5


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def main() -> None:
    # 36 plateaus of 90 s (+ ramps) at +-10..100 deg/s fill a little over one hour.
    rates = np.tile([10, -10, 50, -50, 100, -100], 6) * DEG
    log("simulating 1 h at 1 kHz ...")
    run = rate_table_run(
        rates, imu_hz=FS, ref_hz=FS, hold_s=90.0, offset_s=0.37, drift_ppm=80.0, seed=0
    )
    rec = run.recording
    n = len(rec)
    log(f"{n} samples x 6 channels ({rec.duration / 3600:.2f} h)")

    data = np.column_stack([rec.acc, rec.gyr])
    sos = design_lowpass(FS, CUTOFF, 4)

    def chain() -> tuple[dict, dict[str, float]]:
        marks = [time.process_time()]
        synced, sync_record = synchronise(rec, run.ref_t, run.ref_channels)
        marks.append(time.process_time())
        plateaus = detect_rate_plateaus(synced.t, synced.reference["table_rate"])
        marks.append(time.process_time())
        n_flagged = 0
        for iv in plateaus:
            _, out_record = remove_outliers(synced.select(iv.slice), "sigma", n_sigma=3.0)
            n_flagged += sum(out_record.statistics["n_flagged"].values())
        marks.append(time.process_time())
        lowpass(synced, cutoff_hz=CUTOFF)
        marks.append(time.process_time())
        steps = dict(zip(("sync", "plateaus", "outliers", "lowpass"), np.diff(marks), strict=True))
        steps["n_plateaus"], steps["n_flagged"] = len(plateaus), n_flagged
        return sync_record.statistics, steps

    # The machine is shared: wall time swings with other people's load, and so
    # does a single ratio. Baseline and chain alternate (same memory state),
    # each timed by wall clock and by this process's CPU time; the figures are
    # medians over REPEATS, the ratio the median of the per-repeat CPU ratios
    # (CPU time is not inflated by waiting for a core). One warm-up of each first.
    sosfiltfilt(sos, data, axis=0)
    chain()
    wall_base, wall_chain, ratios = [], [], []
    for k in range(REPEATS):
        w0, c0 = time.perf_counter(), time.process_time()
        sosfiltfilt(sos, data, axis=0)
        w1, c1 = time.perf_counter(), time.process_time()
        st, steps = chain()
        w2, c2 = time.perf_counter(), time.process_time()
        wall_base.append(w1 - w0)
        wall_chain.append(w2 - w1)
        ratios.append((c2 - c1) / (c1 - c0))
        log(
            f"repeat {k + 1}: sosfiltfilt {c1 - c0:.2f} s CPU ({w1 - w0:.2f} s wall), chain "
            f"{c2 - c1:.2f} s CPU ({w2 - w1:.2f} s wall), ratio {ratios[-1]:.2f} | sync "
            f"{steps['sync']:.2f}, plateaus {steps['plateaus']:.2f} ({steps['n_plateaus']} found), "
            f"outliers {steps['outliers']:.2f} ({steps['n_flagged']} flagged), "
            f"lowpass {steps['lowpass']:.2f} s CPU"
        )
    t_chain = float(np.median(wall_chain))
    log(
        f"median: chain {t_chain:.2f} s wall, sosfiltfilt {np.median(wall_base):.2f} s wall, "
        f"wall ratio {t_chain / np.median(wall_base):.2f}, CPU ratio {np.median(ratios):.2f} "
        f"(per repeat: {', '.join(f'{r:.2f}' for r in ratios)})"
    )

    est = ClockModel(st["offset_s"], st["drift_ppm"], st["t0_s"])
    err_ms = float(np.max(np.abs(est.to_ref(rec.t) - run.clocks.clock.to_ref(rec.t))) * 1e3)
    log(
        f"clock: offset {st['offset_s']:.6f} s (true 0.37), drift {st['drift_ppm']:.2f} ppm "
        f"(true 80), max timing error {err_ms:.4f} ms"
    )
    print(
        json.dumps(
            {
                "chain_samples_per_s": n / t_chain,
                "chain_ratio_to_sosfiltfilt": float(np.median(ratios)),
                "sync_error_ms_max": err_ms,
            }
        )
    )


if __name__ == "__main__":
    main()
