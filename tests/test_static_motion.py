"""A static record that moves fails its motion check; a still one passes.

The check (calib_core.preprocess.motion) holds every window's scatter against the noise
the same record shows in its quietest windows, at a false-alarm rate of 1e-3 per record.
Simulated records with known motion, and the real Xsens session (imu_tk): its first
45 s are still, the hand-held poses after them are not.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from calib_core.checks import FAIL, PASS, overall_verdict, solver_checks
from calib_core.preprocess.motion import MOTION_ALPHA, motion_check
from calib_core.procedures import solve
from calib_core.recording import Recording
from calib_core.simulate.handheld import handheld_run
from calib_core.simulate.lab_run import random_errors, six_position_integral_run
from calib_core.simulate.noise import NoiseSpec, simulate_static
from calib_core.units import DEG

XSENS = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "imutk_xsens"
GYRO = NoiseSpec(arw=0.005 * DEG)  # rad/s/sqrt(Hz): 0.05 deg/s per sample at 100 Hz
ACC = NoiseSpec(arw=0.002)  # m/s^2/sqrt(Hz)


def _still(seed: int, duration_s: float = 120.0) -> Recording:
    rng = np.random.default_rng(seed)
    return simulate_static(
        duration_s, 100.0, gyro_bias=np.full(3, 0.01), gyro_noise=GYRO, acc_noise=ACC, rng=rng
    )


def _vibrating(rec: Recording, seed: int, gyro_std: float = 0.052) -> Recording:
    """The record on a moving vehicle for its middle third: band-limited (0.5-5 Hz) angular
    rate of `gyro_std` rad/s (the DataFlash log's) and 0.3 m/s^2 of acceleration."""
    rng = np.random.default_rng(seed)
    n = len(rec)
    mid = slice(n // 3, 2 * n // 3)
    sos = signal.butter(2, [0.5, 5.0], btype="band", fs=rec.sample_rate, output="sos")
    shake = signal.sosfilt(sos, rng.standard_normal((mid.stop - mid.start, 6)), axis=0)
    shake /= shake.std(axis=0)
    gyr, acc = rec.gyr.copy(), rec.acc.copy()
    gyr[mid] += gyro_std * shake[:, :3]
    acc[mid] += 0.3 * shake[:, 3:]
    return dataclasses.replace(rec, gyr=gyr, acc=acc)


def test_still_records_pass():
    """20 still records (white noise, 2 min at 100 Hz, bias 0.01 rad/s): none fails. Each
    fails with probability < 1e-3, all 20 pass with probability > 98 %."""
    for seed in range(20):
        check = motion_check("still", _still(seed))
        assert check["passed"], check
        assert check["value"] < check["limit"]
    assert MOTION_ALPHA == 1e-3


def test_low_passed_still_records_pass_and_a_low_passed_vehicle_fails():
    """A 5 Hz low-pass (a sensor's DLPF at 100 Hz) correlates the noise: a window holds
    ~10x fewer degrees of freedom than samples, and the limit follows (from the noise's
    autocorrelation time). 10 still records pass; the vehicle of the next test fails."""
    sos = signal.butter(4, 5.0, fs=100.0, output="sos")

    def low_passed(rec: Recording) -> Recording:
        return dataclasses.replace(
            rec,
            gyr=signal.sosfiltfilt(sos, rec.gyr, axis=0),
            acc=signal.sosfiltfilt(sos, rec.acc, axis=0),
        )

    for seed in range(10):
        assert motion_check("still", low_passed(_still(200 + seed)))["passed"]
    assert not motion_check("moving", low_passed(_vibrating(_still(210), 211)))["passed"]


def test_a_vehicle_moving_through_static_bias_fails_the_motion_check():
    """The issue's DataFlash case: a record of a moving vehicle (gyro scatter 0.052 rad/s)
    through static_bias: the run fails the named check motion:<label>, naming the moving
    window; the still record of the same unit passes it."""
    still = _still(100)
    moving = _vibrating(still, 101)
    for rec, expected in ((still, PASS), (moving, FAIL)):
        cal = solve("static_bias", {"long_static": rec}, 9.81, {})
        check = next(c for c in cal.info["solver_checks"] if c["name"] == "motion:long_static")
        assert check["passed"] is (expected == PASS), check
        assert overall_verdict(solver_checks(cal)) == expected
    cal = solve("static_bias", {"long_static": moving}, 9.81, {})
    check = next(c for c in cal.info["solver_checks"] if c["name"] == "motion:long_static")
    assert "the unit moved" in check["detail"] and check["value"] > 100 * check["limit"]
    start = float(check["detail"].split("(at ")[1].split(" s)")[0])
    assert 40.0 - 1.0 <= start <= 80.0  # the moving middle third


def test_a_hand_held_session_is_no_static_record():
    """A hand-held session (rests and turns, calib_core.simulate.handheld) given to
    static_bias as one static record: the turns fail the motion check."""
    rng = np.random.default_rng(7)
    run = handheld_run(random_errors(rng), rng, poses=6)
    check = motion_check("session", run.recording)
    assert not check["passed"] and "the unit moved" in check["detail"], check


def test_a_moving_face_of_a_six_position_run_fails_only_its_own_check():
    rng = np.random.default_rng(8)
    run = six_position_integral_run(random_errors(rng), rng)
    segments = dict(run.segments)
    segments["x_up"] = _vibrating(segments["x_up"], 9, gyro_std=0.02)
    cal = solve("six_position_integral", segments, run.gravity, {})
    motion = {
        c["name"]: c["passed"] for c in cal.info["solver_checks"] if c["name"].startswith("motion:")
    }
    assert set(motion) == {f"motion:{a}_{s}" for a in "xyz" for s in ("up", "dn")}
    assert [name for name, ok in motion.items() if not ok] == ["motion:x_up"]


def test_real_xsens_session_still_start_passes_hand_held_poses_fail():
    if not XSENS.is_dir():
        pytest.skip(f"real Xsens session not found at {XSENS} (shared/realdata missing)")
    acc = np.loadtxt(XSENS / "xsens_acc.mat")
    gyr = np.loadtxt(XSENS / "xsens_gyro.mat")
    # SOURCE.txt datasheet offsets and gains: counts to m/s^2 and rad/s.
    rec = Recording(
        acc[:, 0] - acc[0, 0],
        (acc[:, 1:] - [33123.0, 33276.0, 32360.0]) / [415.0, 413.0, 415.0],
        (gyr[:, 1:] - [32768.0, 32466.0, 32485.0]) / [4778.0, 4758.0, 4766.0],
        source=str(XSENS),
    )
    first = rec.select(np.arange(0, 4500))  # the first 45 s: still on the table
    assert motion_check("start", first)["passed"]
    poses = rec.select(np.arange(0, 10_000))  # the first 100 s: the rest, then poses
    assert not motion_check("poses", poses)["passed"]


def test_each_procedure_declares_which_segments_are_held_still() -> None:
    """The motion checks follow `Procedure.static_segments`; the motion module names no
    procedure, and a procedure that moves on purpose gets no motion check."""
    from calib_core import procedures
    from calib_core.preprocess import motion
    from calib_core.preprocess.motion import static_motion_checks

    declared = {name: procedures.get(name).static_segments for name in procedures.PROCEDURES}
    assert declared == {
        "six_position": "all but turns",
        "six_position_integral": "all but turns",
        "multi_position": "all but turns",
        "sensor_array": "all but turns",
        "static_bias": "all",
        "integral": "none",
        "rate_table": "none",
        "centrifuge": "none",
        "equipment_free": "none",
    }
    source = Path(motion.__file__).read_text()
    assert not [name for name in declared if f'"{name}"' in source]
    segs = {"x_up": _still(3), "x_ccw": _still(4)}
    assert [c["name"] for c in static_motion_checks("all but turns", segs)] == ["motion:x_up"]
    assert len(static_motion_checks("all", segs)) == 2
    assert static_motion_checks("none", segs) == []
    with pytest.raises(ValueError, match="static_segments"):
        static_motion_checks("some", segs)


def _streamed_statistics(rec: Recording, chunk: int) -> tuple[dict | None, list]:
    """`motion_statistics` of `rec` pushed through `StreamedMotion` in chunks of `chunk`
    rows (windows split across chunks), and the channels it read exactly in a last pass."""
    from calib_core.preprocess.motion import StreamedMotion, streamed_smallest_steps

    x = np.hstack([rec.gyr, rec.acc])
    motion = StreamedMotion(len(rec), rec.sample_rate)
    for i in range(0, len(rec), chunk):
        motion.push(rec.t[i : i + chunk], x[i : i + chunk])
    exact: list = []

    def steps(cols: np.ndarray) -> np.ndarray:
        exact.append(cols.tolist())
        return streamed_smallest_steps(x[i : i + chunk, cols] for i in range(0, len(x), chunk))

    return motion.result(steps), exact


def _quantised(rec: Recording, step: float) -> Recording:
    """The gyro rounded to `step` rad/s, its bias on the grid: the quiet windows mostly
    constant, the rounding variance setting the reference."""
    return dataclasses.replace(rec, gyr=np.round(rec.gyr / step) * step)


@pytest.mark.parametrize(
    ("kind", "make", "moves"),
    [
        ("still", lambda: _still(300), False),
        ("burst", lambda: _vibrating(_still(301), 302), True),
        ("quantised", lambda: _quantised(_still(303), 5e-3), False),
        ("quantised burst", lambda: _quantised(_vibrating(_still(304), 305), 5e-3), True),
    ],
)
def test_streamed_motion_check_is_the_in_memory_one(kind, make, moves):
    """The check from a record pushed in chunks (what `calib process` does with a record
    larger than its memory limit) is the in-memory one: the same windows (each one's rows
    the same, a window split by a chunk's end carried over), the same function from the
    windows' statistics to the check. Ratio and limit to a few ulps (the same arithmetic on
    the same rows: only a reduction's vectorisation may round differently); the channel and
    the window's time exactly. A quantised gyro (rounding variance above the noise's) takes
    the exact pass for its smallest step; a float record does not."""
    from calib_core.preprocess.motion import motion_statistics

    rec = make()
    ref = motion_statistics(rec)
    got, exact = _streamed_statistics(rec, 7777)  # 100-sample windows: split by chunks
    _same_statistics(got, ref)
    assert (got["ratio"] > got["limit"]) is moves, got
    assert bool(exact) is kind.startswith("quantised"), exact
    if exact:
        assert set(exact[0]) <= {0, 1, 2}  # the gyro's channels only


def _arbitrary_chunks(rec: Recording, seed: int, first: int) -> list[tuple]:
    """`rec` as (t, gyr, acc) chunks of random sizes after a first of `first` rows: half
    of them 1 to 150 rows (most shorter than a window), half up to 3000 rows."""
    rng = np.random.default_rng(seed)
    cuts = [0, first]
    while cuts[-1] < len(rec):
        size = int(rng.integers(1, 150 if rng.random() < 0.5 else 3001))
        cuts.append(min(cuts[-1] + size, len(rec)))
    return [(rec.t[a:b], rec.gyr[a:b], rec.acc[a:b]) for a, b in zip(cuts, cuts[1:], strict=False)]


def _first_pass(chunks: list[tuple]):
    from calib_core.solvers.static_bias import FirstPass

    first = FirstPass.empty()
    for chunk in chunks:
        first.push(chunk)
    first.close()
    return first


def _same_statistics(got: dict | None, ref: dict | None) -> None:
    """The test above's comparison: ratio and limit to a few ulps, the rest exactly."""
    assert ref is not None and got is not None
    assert got["ratio"] == pytest.approx(ref["ratio"], rel=1e-12, abs=0.0), (got, ref)
    assert got["limit"] == pytest.approx(ref["limit"], rel=1e-12, abs=0.0), (got, ref)
    assert (got["channel"], got["t_s"], got["window_s"]) == (
        ref["channel"],
        ref["t_s"],
        ref["window_s"],
    )


@pytest.mark.parametrize(
    ("make", "moves", "seed"),
    [
        (lambda: _still(310), False, 1),
        (lambda: _vibrating(_still(311), 312), True, 2),
        (lambda: _quantised(_vibrating(_still(313), 314), 5e-3), True, 3),
    ],
)
def test_first_pass_motion_is_the_in_memory_one(make, moves, seed):
    """The motion windows computed while the record is read (`FirstPass`, on its worker
    thread, at the width of the first chunk's rate) are the in-memory check's, whatever
    the chunks' sizes; the solve then takes them and its pass computes no window (its
    chunks carry no time, which a window needs)."""
    from calib_core.preprocess.motion import motion_statistics, streamed_smallest_steps
    from calib_core.solvers.static_bias import solve_static_bias_stream

    rec = make()
    chunks = _arbitrary_chunks(rec, seed, first=700)
    first = _first_pass(chunks)
    rate = 1.0 / first.step.median()
    motion = first.settled_motion(len(rec), rate)
    assert motion is not None  # the first pass's windows are the record's
    x = np.hstack([rec.gyr, rec.acc])
    got = motion.result(lambda cols: streamed_smallest_steps([x[:, cols]]))
    ref = motion_statistics(rec)
    _same_statistics(got, ref)
    assert (got["ratio"] > got["limit"]) is moves, got

    def timeless():
        for _, gyr, acc in chunks:
            yield None, gyr, acc

    cal = solve_static_bias_stream(timeless, first=first, up_axis="+z", motion_label="still")
    (check,) = [c for c in cal.info["solver_checks"] if c["name"] == "motion:still"]
    assert check["value"] == pytest.approx(ref["ratio"], rel=1e-12, abs=0.0)
    assert check["passed"] is not moves


def _moving(seed: int, duration_s: float = 120.0) -> Recording:
    return _vibrating(_still(seed, duration_s), seed + 1)


def _first_chunk_at(rec: Recording, rows: int, factor: float) -> Recording:
    """`rec` whose first `rows` samples come `factor` times as often (the record's median
    step unchanged: most steps are the others)."""
    step = float(np.median(np.diff(rec.t)))
    steps = np.full(len(rec) - 1, step)
    steps[: rows - 1] = step / factor
    return dataclasses.replace(rec, t=rec.t[0] + np.concatenate([[0.0], np.cumsum(steps)]))


@pytest.mark.parametrize(
    ("case", "make"),
    [
        ("first chunk at twice the rate", lambda: _first_chunk_at(_moving(320), 900, 2.0)),
        ("first chunk at 0.7 x the rate", lambda: _first_chunk_at(_moving(322), 900, 0.7)),
        ("short record: shorter windows", lambda: _moving(324, duration_s=12.0)),
    ],
)
def test_first_pass_motion_falls_back_to_the_solve_pass(case, make):
    """When the first chunk's rate does not give the record's window (its rate is not the
    record's median rate, or the record is too short for MOTION_WINDOW_S windows), the
    first pass's windows are not used: the solve's pass computes them again, and the check
    is still the in-memory one (a record that moves fails it)."""
    from calib_core.preprocess.motion import motion_statistics, motion_width
    from calib_core.solvers.static_bias import solve_static_bias_stream

    rec = make()
    chunks = _arbitrary_chunks(rec, 4, first=900)
    first = _first_pass(chunks)
    rate = 1.0 / first.step.median()
    assert first.motion is not None  # windows computed, at a width not the record's
    assert first.motion.width != motion_width(len(rec), rate), case
    assert first.settled_motion(len(rec), rate) is None
    ref = motion_statistics(rec)
    assert ref is not None and ref["ratio"] > ref["limit"]  # it moves
    cal = solve_static_bias_stream(
        lambda: iter(chunks), first=first, up_axis="+z", motion_label="still"
    )
    (check,) = [c for c in cal.info["solver_checks"] if c["name"] == "motion:still"]
    assert check == motion_check("still", rec) | {
        "value": pytest.approx(ref["ratio"], rel=1e-12, abs=0.0),
        "limit": pytest.approx(ref["limit"], rel=1e-12, abs=0.0),
    }
    assert check["passed"] is False


def test_solve_without_a_first_pass_judges_the_chunks_it_is_given():
    """The as-found solve passes no first pass (its chunks are the samples corrected by an
    earlier calibration): its own first pass keeps no motion windows, and its second
    pass's check is the in-memory one of the chunks given, not of the raw samples."""
    from calib_core.solvers.static_bias import first_pass, solve_static_bias_stream

    raw = _moving(330)
    mix = np.array([[1.0, 0.4, 0.1], [0.3, 1.0, 0.2], [0.2, 0.1, 1.0]])  # misalignment
    fixed = dataclasses.replace(raw, gyr=(raw.gyr - 0.01) @ mix.T, acc=raw.acc @ mix.T)
    chunks = _arbitrary_chunks(fixed, 5, first=900)
    assert first_pass(chunks).motion is None
    cal = solve_static_bias_stream(lambda: iter(chunks), up_axis="+z", motion_label="still")
    (check,) = [c for c in cal.info["solver_checks"] if c["name"] == "motion:still"]
    ref, other = motion_check("still", fixed), motion_check("still", raw)
    assert check["value"] == pytest.approx(ref["value"], rel=1e-12, abs=0.0)
    assert check["value"] != pytest.approx(other["value"], rel=1e-6)
    assert check["passed"] is False
