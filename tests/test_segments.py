"""Segmentation against a real hand-held Ferraris session and simulated rate plateaus."""

import json
from pathlib import Path

import numpy as np
import pytest

from calib_core.preprocess.segments import (
    StaticDetector,
    detect_rate_plateaus,
    detect_static,
    label_position,
    label_positions,
    segment,
)
from calib_core.recording import Recording
from calib_core.simulate.table import rate_table_run
from calib_core.units import DEG, STANDARD_GRAVITY

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "imucal_ferraris"
FS_FERRARIS = 102.4  # Hz (imucal examples/basic_ferraris.py)
FACES = {"x_p": "x_up", "x_a": "x_dn", "y_p": "y_up", "y_a": "y_dn", "z_p": "z_up", "z_a": "z_dn"}
TOL_S = 0.5


@pytest.fixture(scope="module")
def ferraris():
    csv = REALDATA / "example_ferraris_session.csv"
    if not csv.exists():
        pytest.skip(f"real data not found at {REALDATA} (needs shared/realdata beside the repo)")
    pd = pytest.importorskip("pandas")
    df = pd.read_csv(csv)
    sections = json.loads((REALDATA / "example_ferraris_session_list.json").read_text())
    rec = Recording(
        t=df["n_samples"].to_numpy() / FS_FERRARIS,
        acc=df[["acc_x", "acc_y", "acc_z"]].to_numpy(),  # m/s^2
        gyr=df[["gyr_x", "gyr_y", "gyr_z"]].to_numpy() * DEG,  # deg/s -> rad/s
        source=csv.name,
    )
    # Hand-held: the first ~2.8 s are at rest, then the unit is picked up.
    seg, record = segment(rec, gravity=STANDARD_GRAVITY, detector=StaticDetector(init_static_s=2.5))
    return rec, sections, seg, record


def only_overlap(intervals, labels, s0: float, s1: float, what: str):  # noqa: ANN201
    """(interval, label) of the one interval overlapping [s0, s1) s; fails unless exactly one."""
    pairs = zip(intervals, labels, strict=True)
    hits = [(iv, lab) for iv, lab in pairs if iv.end_s > s0 and iv.start_s < s1]
    assert len(hits) == 1, f"{what}: {len(hits)} intervals overlap the section"
    return hits[0]


def test_ferraris_six_faces_found_and_labelled_by_gravity(ferraris):
    rec, sections, seg, _ = ferraris
    for name, label in FACES.items():
        s0, s1 = sections[name]["start"] / FS_FERRARIS, sections[name]["end"] / FS_FERRARIS
        iv, lab = only_overlap(seg.statics, seg.static_labels, s0, s1, f"{name} static")
        assert lab == label, f"{name}: labelled {lab}"
        # The detector's rest interval (before the settle cuts) covers the annotated
        # face to within 0.5 s at both ends ...
        assert iv.detected_start_s <= s0 + TOL_S, f"{name}: rest found from {iv.detected_start_s}"
        assert iv.detected_end_s >= s1 - TOL_S, f"{name}: rest found until {iv.detected_end_s}"
        # ... and the samples kept after the settle cuts lie inside the section
        # ("or better: inside them"): they are the ones a solver averages.
        assert s0 <= iv.start_s and iv.end_s <= s1, (
            f"{name}: kept [{iv.start_s:.2f}, {iv.end_s:.2f}) s, section [{s0:.2f}, {s1:.2f}) s"
        )
        assert iv.end_s - iv.start_s > 0.4 * (s1 - s0)  # and most of it is kept
        # What the detector saw beyond the annotated end is rest too (the
        # annotation is a conservative sub-window): checked independently of the
        # detector, the gyro stays within 1 deg/s of the section's mean there
        # (hand motion is tens of deg/s; the noise is 0.05 deg/s, quantised at
        # 0.061 deg/s).
        extra = (rec.t >= s1) & (rec.t < iv.detected_end_s)
        inside = (rec.t >= s0) & (rec.t < s1)
        if extra.any():
            dev = np.abs(rec.gyr[extra] - rec.gyr[inside].mean(axis=0)).max()
            assert dev < 1.0 * DEG, f"{name}: {np.degrees(dev):.2f} deg/s after the section"


def test_ferraris_three_rotations_found_by_axis(ferraris):
    rec, sections, seg, record = ferraris
    assert len(seg.rotations) == 3
    for axis in "xyz":
        s0 = sections[f"{axis}_rot"]["start"] / FS_FERRARIS
        s1 = sections[f"{axis}_rot"]["end"] / FS_FERRARIS
        iv, lab = only_overlap(seg.rotations, seg.rotation_labels, s0, s1, f"{axis}_rot")
        assert iv.start_s <= s0 + TOL_S and iv.end_s >= s1 - TOL_S
        # Sign: independent integral of the raw gyro over the annotated window.
        inside = (rec.t >= s0) & (rec.t < s1)
        raw_turn = rec.gyr[inside, "xyz".index(axis)].sum() / FS_FERRARIS
        assert lab == f"{axis}_{'ccw' if raw_turn > 0 else 'cw'}"
        # One whole turn; the uncalibrated gyro's scale error is a few percent.
        assert np.degrees(abs(max(iv.angle, key=abs))) == pytest.approx(360.0, rel=0.06)
    assert [r["label"][0] for r in record.statistics["rotations"]] == ["x", "y", "z"]


def test_rate_plateaus_match_the_simulated_schedule():
    rates = np.array([-100, -50, 0, 50, 100]) * DEG
    run = rate_table_run(rates, imu_hz=100.0, hold_s=40.0, seed=2)
    rec = run.recording
    found = detect_rate_plateaus(rec.t, rec.gyr[:, 2])
    truth = run.schedule.plateaus  # (start, end, rate) of each hold
    # Rest before and after the run are plateaus too (rate 0).
    for start, end, rate in truth:
        hit = [iv for iv in found if iv.start_s < end and iv.end_s > start]
        assert len(hit) == 1
        iv = hit[0]
        # Detected within one window (1 s) of the true hold; 20 s settle cut.
        assert abs(iv.detected_start_s - start) < 1.0 and abs(iv.end_s - end) < 1.0
        assert iv.settle_s == 20.0 and iv.start_s >= start + 19.0
        # Level = true rate + bias (0.2 deg/s); 20 s at 100 Hz of 0.05 deg/s noise:
        # standard error 0.001 deg/s; 5 of them.
        assert iv.level == pytest.approx(rate + 0.2 * DEG, abs=5 * 0.05 * DEG / np.sqrt(2000))
    assert len(found) == len(truth) + 2


def rest_turn_rest(duration_s: float, turn: tuple[float, float], seed: int) -> Recording:
    """100 Hz at rest (z up), turning at 1 rad/s about z from turn[0] to turn[1] s."""
    fs = 100.0
    t = np.arange(int(duration_s * fs)) / fs
    rng = np.random.default_rng(seed)
    gyr = rng.normal(0, 1e-3, (t.size, 3))
    gyr[(t >= turn[0]) & (t < turn[1]), 2] += 1.0
    acc = np.array([0, 0, 9.81]) + rng.normal(0, 0.01, (t.size, 3))
    return Recording(t=t, acc=acc, gyr=gyr)


def test_settle_rule_for_short_intervals():
    # 60 s at rest, then 25 s of turning, then 12 s at rest.
    rec = rest_turn_rest(97.0, (60.0, 85.0), seed=0)
    first, second = detect_static(rec, StaticDetector(settle_s=30.0, min_keep_s=10.0))
    assert first.settle_s == 30.0 and not first.short
    # 12 s is shorter than 30 + 10: it keeps its middle, losing 25 % at the end
    # and max(25 %, all but 25 % and 10 s) = 25 % at the start.
    duration = second.detected_end_s - second.detected_start_s
    assert second.short
    assert second.settle_s == pytest.approx(0.25 * duration)
    assert second.end_cut_s == pytest.approx(0.25 * duration)
    # The rest found is ~11.5 s (half a window less at each end): half is kept,
    # to one sample (10 ms) at each end.
    assert 11.0 < duration < 12.0
    assert second.start_s == pytest.approx(second.detected_start_s + 0.25 * duration, abs=0.011)
    assert second.end_s == pytest.approx(second.detected_end_s - 0.25 * duration, abs=0.011)
    # Between short and long the kept length is continuous: min(d / 2, 10 s).
    assert first.end_cut_s == 0.0 and first.end_s == first.detected_end_s


def test_settle_rule_keeps_min_keep_for_medium_intervals():
    # 25 s of rest: short (< 30 + 10), and d / 2 = 12.5 > 10: keeps 10 s, of
    # which the end loses 25 % of 25 s and the start the rest.
    rec = rest_turn_rest(60.0, (15.0, 35.0), seed=1)
    _, second = detect_static(
        rec, StaticDetector(init_static_s=10.0, settle_s=30.0, min_keep_s=10.0)
    )
    duration = second.detected_end_s - second.detected_start_s
    assert second.short and 24.0 < duration < 25.5
    assert second.end_s - second.start_s == pytest.approx(10.0, abs=0.011)
    assert second.end_cut_s == pytest.approx(0.25 * duration)


def test_position_labels_by_gravity_not_order():
    g = STANDARD_GRAVITY
    faces = {"x_up": [g, 0, 0], "z_dn": [0.1, -0.2, -g], "y_dn": [0, -1.02 * g, 0.3]}
    segs = [
        Recording(t=np.arange(5.0), acc=np.tile(v, (5, 1)), gyr=np.zeros((5, 3)), source=name)
        for name, v in faces.items()
    ]
    assert label_positions(segs, g) == list(faces)
    with pytest.raises(ValueError, match=r"45\.0 deg.*tilted"):
        label_position(np.array([1.0, 1.0, 0.0]) * g / np.sqrt(2), g)
    tilted = Recording(
        t=np.arange(3.0),
        acc=np.tile([0, 0, 0.5 * g], (3, 1)),
        gyr=np.zeros((3, 3)),
        source="pos7.csv",
    )
    with pytest.raises(ValueError, match=r"pos7\.csv.*not a static face"):
        label_positions([tilted], g)


def test_recording_window_is_a_view_when_contiguous():
    """A time window of increasing t is a slice: its arrays share the recording's memory;
    a window of scattered samples (t not monotonic) is a copy."""
    n = 100
    t = np.arange(n) / 10.0
    rec = Recording(t, np.arange(3 * n, dtype=float).reshape(n, 3), np.ones((n, 3)), t + 20.0)
    part = rec.window(2.0, 3.0, label="x_up")
    assert part.label == "x_up" and np.array_equal(part.t, t[20:30])
    assert all(
        np.shares_memory(a, b)
        for a, b in zip(
            (part.t, part.acc, part.gyr, part.temp),
            (rec.t, rec.acc, rec.gyr, rec.temp),
            strict=True,
        )
    )
    assert len(rec.window(50.0, 60.0)) == 0
    twice = Recording(np.concatenate([t[:50], t[:50]]), rec.acc, rec.gyr)  # a clock restart
    both = twice.window(2.0, 3.0)
    picked = np.r_[20:30, 70:80]
    assert np.array_equal(both.acc, rec.acc[picked]) and not np.shares_memory(both.acc, rec.acc)


def test_recording_window_by_bisection_picks_the_same_samples():
    """With `increasing` (t known to increase) the window is found by bisection: the same
    samples as the full comparison for windows inside, across, between and beyond the
    samples, at sample times and between them, open-ended or empty; NaN bounds compare."""
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.5, 1.5, 200))
    rec = Recording(t, rng.normal(size=(200, 3)), rng.normal(size=(200, 3)))
    assert rec.strictly_increasing()
    assert not Recording(t[::-1].copy(), rec.acc, rec.gyr).strictly_increasing()
    inf, nan = float("inf"), float("nan")
    bounds = [
        (-inf, inf),
        (-inf, t[10]),
        (t[10], inf),
        (t[10], t[20]),
        (t[10] + 0.1, t[20] - 0.1),
        (t[20], t[10]),
        (t[5], t[5]),
        (t[-1], inf),
        (t[-1] + 1, inf),
        (-inf, t[0]),
        (-5.0, t[0] + 1e-9),
        (nan, t[20]),
        (t[10], nan),
    ]
    bounds += [tuple(sorted(rng.uniform(t[0] - 5, t[-1] + 5, 2))) for _ in range(200)]
    for start, end in bounds:
        fast, full = rec.window(start, end, increasing=True), rec.window(start, end)
        assert np.array_equal(fast.t, full.t) and np.array_equal(fast.acc, full.acc), (start, end)
