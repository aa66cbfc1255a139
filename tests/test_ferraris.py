"""imucal's real Ferraris session: six-position + integral vs equipment-free, side by side.

The session (SOURCE.txt in the data folder): one continuous 102.4 Hz recording in
m/s^2 and deg/s, cut by a section list into six static faces (x_p = x up, x_a =
x down, ...) and one hand-made 360 deg turn about each axis (x_rot, y_rot, z_rot).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from calib_core import params
from calib_core.calibration import Calibration
from calib_core.procedures import solve
from calib_core.solvers.equipment_free import transport_residual_rms
from calib_core.units import DEG, STANDARD_GRAVITY
from calib_testing.ferraris import DATA, EXAMPLE_RATE_HZ, example_segments, example_session

RATE_HZ = EXAMPLE_RATE_HZ
GRAVITY = 9.81  # imucal's expected gravity; both methods use the same value
# The session has rests only near the six faces: tune the detector to hand-held rests
# (short windows, short settle) and start at the first rest, as the method requires.
EF_SETTINGS = {"init_static_s": 5.0, "window_s": 0.5, "settle_s": 0.3, "min_keep_s": 0.5}


@pytest.fixture(scope="module")
def session():
    if not DATA.is_dir():
        pytest.skip(f"imucal Ferraris session not found at {DATA} (shared/realdata missing)")
    rec, sections = example_session()
    segments = example_segments(rec, sections)
    first_rest = sections["x_p"]["start"]
    return rec, segments, rec.select(np.arange(first_rest, len(rec)))


@pytest.fixture(scope="module")
def both(session):
    rec, segments, from_first_rest = session
    ferraris = solve(
        "six_position_integral", segments, GRAVITY, {"rotation_directions": "any", "turns": 1}
    )
    free = solve("equipment_free", {"session": from_first_rest}, GRAVITY, EF_SETTINGS)
    return ferraris, free


def test_side_by_side_scale_factors(both, session, capsys):
    """Accelerometer scale factors agree within 0.5 % (acceptance). The gyro scale factors
    are printed and compared with their uncertainties; see the next test for gyro y."""
    ferraris, free = both
    with capsys.disabled():
        print("\nimucal Ferraris session: six_position_integral | equipment_free (std)")
        for sensor in ("acc", "gyr"):
            for kind in ("scale", "bias"):
                for a in params.AXES:
                    name = f"{sensor}.{kind}.{a}"
                    p, q = ferraris.parameters[name], free.parameters[name]
                    print(
                        f"  {name:12s} {p.value:+.5f} ({p.std:.5f}) | {q.value:+.5f} ({q.std:.5f})"
                        f"  diff {q.value - p.value:+.5f}"
                    )
    for a in params.AXES:
        k_six = 1 + ferraris.value(f"acc.scale.{a}")
        k_free = 1 + free.value(f"acc.scale.{a}")
        assert abs(k_free / k_six - 1) < 0.005, a
    # The faces cannot show accelerometer misalignment to the norm condition: flagged.
    assert free.info["acc_misalign_observable"] is False
    assert any("misalignments" in w for w in free.warnings)
    # Gyro: each difference within 3 combined standard uncertainties, the one claim the
    # two solutions' own error bars support.
    for a in params.AXES:
        name = f"gyr.scale.{a}"
        p, q = ferraris.parameters[name], free.parameters[name]
        assert abs(q.value - p.value) < 3 * np.hypot(p.std, q.std), name


def test_gyro_y_turn_was_not_a_full_turn(both, session, capsys):
    """Gyro x and z scale factors agree within 0.5 %; y differs by ~1.1 %. The Ferraris
    method takes each hand turn as exactly 360 deg; the equipment-free gyro, fitted to
    the face-to-face flips, puts the y turn at ~356 deg. The session decides between
    them: with the same gravity directions and bias, the hypothesis "the Ferraris gyro
    matrix is the true one" is rejected by the F-test of a fixed parameter point,
    F = ((SSR_0 - SSR) / p) / (SSR / (n - p)) ~ F(p, n - p), p = 9 matrix terms,
    n = 2 degrees of freedom per motion, at alpha = 0.05 (docs/methods.md 2.8)."""
    ferraris, free = both
    _, segments, from_first_rest = session
    for a in ("x", "z"):
        ratio = (1 + free.value(f"gyr.scale.{a}")) / (1 + ferraris.value(f"gyr.scale.{a}"))
        assert abs(ratio - 1) < 0.005, a
    y_turn = next(label for label in segments if label.startswith("y_c"))
    rec = segments[y_turn]
    # Not a section cut short: the 3 s on either side of it turn by < 0.1 deg about y.
    whole, _, _ = session
    start, end = np.searchsorted(whole.t, [rec.t[0], rec.t[-1]])
    for side in (
        slice(start - int(3 * RATE_HZ), start),
        slice(end + 1, end + 1 + int(3 * RATE_HZ)),
    ):
        outside = whole.gyr[side, 1] - ferraris.value("gyr.bias.y")
        assert abs(np.degrees(outside.sum() / RATE_HZ)) < 0.1
    integral = np.trapezoid(rec.gyr[:, 1] - ferraris.value("gyr.bias.y"), rec.t)
    angle = np.degrees(abs(integral)) / (1 + free.value("gyr.scale.y"))
    hybrid = Calibration("hybrid", GRAVITY, parameters=dict(free.parameters))
    for row in params.matrix_names("gyr"):
        for name in row:
            hybrid.parameters[name] = ferraris.parameters[name]
    miss_free = transport_residual_rms(from_first_rest, free, EF_SETTINGS)
    miss_0 = transport_residual_rms(from_first_rest, hybrid, EF_SETTINGS)
    n = 2 * free.info["gyr_motions"]
    p = 9
    ssr, ssr_0 = n * miss_free**2, n * miss_0**2
    f_stat = ((ssr_0 - ssr) / p) / (ssr / (n - p))
    p_value = float(stats.f.sf(f_stat, p, n - p))
    with capsys.disabled():
        print(
            f"\ny turn per the equipment-free gyro: {angle:.1f} deg; gravity transport rms "
            f"{miss_free:.4f} rad (equipment-free) vs {miss_0:.4f} rad (Ferraris gyro): "
            f"F = {f_stat:.1f}, p = {p_value:.2g}"
        )
    assert p_value < 0.05


def test_matches_imucals_own_calibrated_output(both, session):
    """imucal calibrated the first 50 rows of this session with its Ferraris solution
    (reference/ferraris_example_calibrated_head50.csv). Our six-position + integral
    calibration applied to the same raw rows agrees within the residual limits of
    docs/methods.md 3.6 (0.002 g, 0.1 deg/s): two implementations of one method."""
    ferraris, _ = both
    rec, _, _ = session
    ref = pd.read_csv(DATA / "reference" / "ferraris_example_calibrated_head50.csv")
    acc, gyr = ferraris.correct(rec.acc[:50], rec.gyr[:50])
    ref_acc = ref[["acc_x", "acc_y", "acc_z"]].to_numpy()
    ref_gyr = ref[["gyr_x", "gyr_y", "gyr_z"]].to_numpy() * DEG
    assert np.abs(acc - ref_acc).max() < 0.002 * STANDARD_GRAVITY
    assert np.abs(gyr - ref_gyr).max() < 0.1 * DEG
