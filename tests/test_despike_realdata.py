"""The rotation despiker on imucal's two real Ferraris sessions: hand-turned motion is no spike.

Both sessions (SOURCE.txt in the data folder) hold one hand-made 360 deg turn about each
axis. The turns shake: single samples dip by up to 37 deg/s and recover, other axes jerk
with them. That is motion, and the integral must take it as it is: with the despiker
the gyro scale factors and misalignments are those without it (limits of the issue that
measured the damage: 0.01 % in scale, 6e-5 in misalignment), every rotation's despike
count is within what its false alarms explain, and the annotated session still agrees
with imucal's published calibration (reference/example_cal.json). A glitch no hand makes
(300 deg/s for one sample) is still found, counted in the solve step and sent for review.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from calib_core import params
from calib_core.procedures import solve, solve_step
from calib_core.recording import Recording
from calib_core.solvers import integral
from calib_core.units import DEG
from calib_testing.ferraris import DATA, example_segments, example_session, section_label

GRAVITY = 9.81  # imucal's expected gravity
SETTINGS = {"rotation_directions": "any", "turns": 1}
# The annotated session is in raw counts: the nominal sensitivities of a +-2000 deg/s,
# +-16 g MPU-6050 (16.4 counts per deg/s, 2048 per g) bring it near SI. Scale factors
# relative to imucal's and misalignments do not depend on them.
GYRO_COUNTS_PER_DPS = 16.4
ACC_COUNTS_PER_MS2 = 2048 / 9.80665
ANNOTATED_RATE_HZ = 204.8  # imucal tests/test_calibration_calculation.py
SCALE_LIMIT = 1e-4  # 0.01 %
MISALIGN_LIMIT = 6e-5


def annotated_session() -> dict[str, Recording]:
    df = pd.read_csv(DATA / "annotated_session.csv")
    segments = {}
    for name, part in df.groupby("part", sort=False):
        rec = Recording(
            part["samples"].to_numpy() / ANNOTATED_RATE_HZ,
            part[["acc_x", "acc_y", "acc_z"]].to_numpy() / ACC_COUNTS_PER_MS2,
            part[["gyr_x", "gyr_y", "gyr_z"]].to_numpy() / GYRO_COUNTS_PER_DPS * DEG,
            source=f"annotated_session.csv part {name}",
        )
        label = section_label(str(name), rec)
        segments[label] = rec.with_label(label)
    return segments


def _example() -> dict[str, Recording]:
    return example_segments(*example_session())


@pytest.fixture(scope="module", params=["annotated", "example"])
def session(request) -> dict[str, Recording]:
    if not DATA.is_dir():
        pytest.skip(f"imucal Ferraris session not found at {DATA} (shared/realdata missing)")
    return annotated_session() if request.param == "annotated" else _example()


def _gyro_matrix(cal) -> np.ndarray:
    return np.eye(3) + cal.matrix("gyr")


def _no_despiking(gyr, sigma):
    return np.asarray(gyr, dtype=float), np.zeros(3, dtype=int)


def _compare(g: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """Largest relative scale difference and largest misalignment difference (each row
    divided by its diagonal: the axis's sensitivity cancels)."""
    scale = np.abs(np.diag(g) / np.diag(ref) - 1.0).max()
    mis = g / np.diag(g)[:, None] - ref / np.diag(ref)[:, None]
    return float(scale), float(np.abs(mis - np.diag(np.diag(mis))).max())


def test_hand_turned_rotations_are_not_despiked(session, monkeypatch):
    cal = solve("six_position_integral", session, GRAVITY, SETTINGS)
    counts = cal.info["replaced_samples"]["despike"]
    rotations = [label for label in session if label.endswith("cw")]
    assert sorted(counts) == sorted(rotations)
    checks = {c["name"]: c for c in cal.info["solver_checks"]}
    for label in rotations:
        assert checks[f"model:replaced:despike:{label}"]["passed"], checks
        assert sum(counts[label].values()) == 0, (label, counts[label])
    monkeypatch.setattr(integral, "despike", _no_despiking)
    raw = solve("six_position_integral", session, GRAVITY, SETTINGS)
    scale, mis = _compare(_gyro_matrix(cal), _gyro_matrix(raw))
    assert scale <= SCALE_LIMIT and mis <= MISALIGN_LIMIT, (scale, mis)


def test_annotated_session_agrees_with_imucals_calibration():
    """imucal's model reads raw = K_g R_g w + ...: its gyro matrix is K_g R_g (R_g's
    diagonal is negative: imucal takes the turns the other way round). The scale factors
    agree within 0.01 %; the misalignments within 3 of our standard uncertainties
    (1.2-1.7e-4; the largest difference is 7.4e-5, with or without despiking). imucal
    integrates each whole record: compared with the paper's literal reading
    (turn_estimator "whole_record"); the default estimator against it is the next test."""
    if not DATA.is_dir():
        pytest.skip(f"imucal Ferraris session not found at {DATA} (shared/realdata missing)")
    literal = {**SETTINGS, "turn_estimator": "whole_record"}
    cal = solve("six_position_integral", annotated_session(), GRAVITY, literal)
    ref = json.loads((DATA / "reference" / "example_cal.json").read_text())
    g_ref = -np.asarray(ref["K_g"]) @ np.asarray(ref["R_g"]) / GYRO_COUNTS_PER_DPS
    g = _gyro_matrix(cal)
    scale, _ = _compare(g, g_ref)
    assert scale <= SCALE_LIMIT, scale
    mis = g / np.diag(g)[:, None] - g_ref / np.diag(g_ref)[:, None]
    for i, row in enumerate(params.matrix_names("gyr")):
        for j, name in enumerate(row):
            if i != j:
                assert abs(mis[i, j]) < 3 * cal.parameters[name].std, (name, mis[i, j])


def test_regression_estimator_agrees_with_the_literal_reading_on_hand_turns(session):
    """The default estimator (each turn's motion window, misalignments by regression where
    the cross-axis rate is proportional to the on-axis rate and that is the more precise,
    the rests as static data) and the paper's literal whole-record integrals, on the same
    hand-turned session, differ within 3 standard uncertainties of the two combined in
    quadrature for every gyro parameter (same data: the difference's own std is smaller;
    the largest measured is 0.9 of them, gyr.misalign.yz of the annotated session). The
    turns wobble: every misalignment keeps the integral over the turn."""
    default = solve("six_position_integral", session, GRAVITY, SETTINGS)
    literal = solve(
        "six_position_integral", session, GRAVITY, {**SETTINGS, "turn_estimator": "whole_record"}
    )
    assert default.info["turn_estimator"] == "regression"
    assert set(default.info["misalignment_by"].values()) == {"integral"}
    for name, p in literal.parameters.items():
        if name.startswith("gyr.") and ".noise." not in name:
            q = default.parameters[name]
            assert abs(q.value - p.value) < 3 * np.hypot(p.std, q.std), (name, q.value, p.value)


def test_a_glitch_in_a_real_rotation_is_found_counted_and_sent_for_review():
    """Two samples 300 deg/s off on the x rotation's axis, mid-turn (no hand does that within
    5 ms): replaced, counted in the solve step, its check failed (false alarms explain one
    replaced sample in a rotation of this length at alpha 1e-3, not two). The result is
    that of the session with those two samples set to their neighbours' mean, and differs
    from the untouched session's by at most what that replacement moves the x integral:
    sum |r| dt / (2 pi) in scale, r the sample's own distance from that mean."""
    if not DATA.is_dir():
        pytest.skip(f"imucal Ferraris session not found at {DATA} (shared/realdata missing)")
    segments = annotated_session()
    label = next(k for k in segments if k.startswith("x_c"))
    rec = segments[label]
    at = np.array([len(rec) // 2, 3 * len(rec) // 5])
    glitch, mended = rec.gyr.copy(), rec.gyr.copy()
    glitch[at, 0] += 300 * DEG
    mended[at, 0] = 0.5 * (rec.gyr[at - 1, 0] + rec.gyr[at + 1, 0])
    moved = np.abs(rec.gyr[at, 0] - mended[at, 0]).sum() / ANNOTATED_RATE_HZ / (2 * np.pi)

    def run(gyr):
        segs = {**segments, label: Recording(rec.t, rec.acc, gyr, source=rec.source)}
        return solve_step(
            segs, {"procedure": "six_position_integral", "gravity": GRAVITY, **SETTINGS}
        )

    cal, record = run(glitch)
    replaced = record.statistics["replaced_samples"]["despike"][label]
    assert replaced == {"gyr.x": 2, "gyr.y": 0, "gyr.z": 0}
    check = next(c for c in cal.info["solver_checks"] if c["name"].endswith(f"despike:{label}"))
    assert not check["passed"] and "replaced 2 of" in check["detail"]
    expected, _ = run(mended)
    np.testing.assert_allclose(_gyro_matrix(cal), _gyro_matrix(expected), rtol=0, atol=1e-12)
    clean, _ = run(rec.gyr)
    assert 0 < abs(cal.value("gyr.scale.x") - clean.value("gyr.scale.x")) <= moved * 1.001
