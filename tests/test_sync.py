"""Clock alignment of IMU and rate-table logs against simulated truth."""

import numpy as np
import pytest

from calib_core.preprocess.sync import (
    ClockModel,
    align_reference,
    estimate_clock,
    repair_timestamps,
    synchronise,
)
from calib_core.simulate.table import rate_table_run
from calib_core.units import DEG

RATES = np.array([50, -50, 100, -100, 20, -20]) * DEG
# Offsets up to +-0.5 s and drifts up to +-100 ppm (the range), the four
# extreme corners plus an inside point, each with 1 % dropped samples in both
# logs and a 2 s gap in the table log.
CLOCKS = [(-0.5, -100.0), (-0.5, 100.0), (0.5, -100.0), (0.5, 100.0), (0.123, 37.0)]


@pytest.mark.parametrize("hz", [100.0, 1000.0])
@pytest.mark.parametrize(("offset", "drift"), CLOCKS)
def test_timing_error_below_one_millisecond(hz, offset, drift):
    run = rate_table_run(
        RATES,
        imu_hz=hz,
        ref_hz=hz,
        hold_s=20.0,
        offset_s=offset,
        drift_ppm=drift,
        drop_fraction=0.01,
        ref_gaps=[(60.0, 62.0)],
        seed=int(hz) + int(drift),
    )
    rec, record = synchronise(run.recording, run.ref_t, run.ref_channels)
    st = record.statistics
    est = ClockModel(st["offset_s"], st["drift_ppm"], st["t0_s"])
    t = run.recording.t
    # Timing error = estimated minus true table time of every IMU sample.
    error_ms = np.max(np.abs(est.to_ref(t) - run.clocks.clock.to_ref(t))) * 1e3
    assert error_ms <= 1.0, f"timing error {error_ms:.3f} ms at {hz} Hz, {offset} s, {drift} ppm"
    # The aligned table rate equals the true rate at the IMU sample times, up to
    # the timing error times the ramp acceleration (20 deg/s^2) and linear
    # interpolation (exact on the piecewise-linear profile except at corners).
    aligned = rec.reference["table_rate"]
    ok = ~np.isnan(aligned)
    truth = run.schedule.rate(t)
    corner = 20 * DEG / hz  # one sample's worth of rate change at a ramp corner
    assert np.max(np.abs(aligned[ok] - truth[ok])) <= 20 * DEG * 1e-3 + corner
    # The IMU samples inside the 2 s gap (and only those) are NaN and recorded.
    in_gap = (t > 60.0) & (t < 62.0)
    assert np.isnan(aligned[in_gap]).all()
    assert (~ok).sum() <= in_gap.sum() + 2 * hz * 0.02  # plus a few at the gap edges
    assert len(st["reference_gaps_s"]) == 1


def test_estimate_clock_recovers_offset_and_drift_without_drops():
    run = rate_table_run(RATES, imu_hz=200.0, ref_hz=50.0, offset_s=-0.2, drift_ppm=60.0, seed=3)
    clock = estimate_clock(
        run.recording.t, run.recording.gyr[:, 2], run.ref_t, run.ref_channels["table_rate"]
    )
    span = run.recording.duration
    # 1 ms over the run bounds the drift error by 1e-3 / span (~5 ppm here).
    assert clock.offset_s == pytest.approx(-0.2, abs=1e-3)
    assert clock.drift_ppm == pytest.approx(60.0, abs=1e-3 / span * 1e6)
    assert clock.n_windows >= 5


def test_angle_feedback_works_like_rate():
    run = rate_table_run(RATES, imu_hz=100.0, ref_hz=100.0, offset_s=0.3, drift_ppm=-50.0, seed=4)
    _, record = synchronise(
        run.recording, run.ref_t, run.ref_channels, signal="table_angle", signal_kind="angle"
    )
    est = ClockModel(
        record.statistics["offset_s"], record.statistics["drift_ppm"], record.statistics["t0_s"]
    )
    t = run.recording.t
    assert np.max(np.abs(est.to_ref(t) - run.clocks.clock.to_ref(t))) <= 1e-3


def test_clock_model_round_trip():
    c = ClockModel(offset_s=0.4, drift_ppm=-80.0, t0_s=12.0)
    t = np.linspace(0, 3600, 7)
    assert np.allclose(c.to_imu(c.to_ref(t)), t, atol=1e-9)


def test_align_reference_marks_gaps_and_outside_as_nan():
    ref_t = np.array([0.0, 1.0, 2.0, 10.0, 11.0])
    vals = np.array([0.0, 1.0, 2.0, 10.0, 11.0])
    out = align_reference(
        np.array([-1.0, 0.5, 5.0, 10.5, 12.0]), ref_t, vals, ClockModel(0.0), max_gap_s=2.0
    )
    assert np.isnan(out[[0, 2, 4]]).all()
    assert out[1] == 0.5 and out[3] == 10.5


def test_repair_timestamps_drops_duplicates_and_small_reversals():
    t = np.array([0.0, 0.01, 0.01, 0.02, 0.015, 0.03, 0.04])
    keep, record = repair_timestamps(t, source="imu.csv")
    assert keep.tolist() == [True, True, False, True, False, True, True]
    assert record.statistics["n_duplicates"] == 1
    assert record.statistics["n_reversed"] == 1
    assert record.statistics["dropped_indices"] == [2, 4]
    assert np.all(np.diff(t[keep]) > 0)


def test_repair_timestamps_rejects_a_clock_reset():
    t = np.concatenate([np.arange(100) * 0.01, np.arange(100) * 0.01])
    with pytest.raises(ValueError, match=r"imu\.csv.*sample 100.*split the log"):
        repair_timestamps(t, source="imu.csv")


def test_no_motion_is_a_clear_error():
    t = np.arange(20_000) / 100.0
    flat = np.random.default_rng(0).normal(0, 1e-3, t.size)
    with pytest.raises(ValueError, match="need motion"):
        estimate_clock(t, flat, t, np.random.default_rng(1).normal(0, 1e-3, t.size))
