"""Attitude conventions explicit.

The rate-table procedure gives the reference force with a_x = +g sin(pitch); the project's
convention has a_x = -g sin(pitch). Its attitude list of six (pitch, roll) pairs, pitch 0 with
roll 0, 90, 180, 270 and pitch 90 with roll 0 and 180, reaches one x sense twice (at pitch 90
roll is free) and the other never. A unit recorded on such a table and solved in the wrong
convention gave acc.scale.x = -1.99 (truth -0.0125) without a warning.
"""

from __future__ import annotations

import numpy as np
import pytest

from calib_core import procedures
from calib_core.attitude import attitude_problems, specific_force, table_attitude
from calib_core.recording import Recording
from calib_core.units import DEG, STANDARD_GRAVITY

G = STANDARD_GRAVITY
# The procedure's attitude list: label "p<pitch>r<roll>" -> (pitch, roll), degrees.
ATTITUDES = {
    f"p{p:g}r{r:g}": (p, r)
    for p, r in [(0.0, 0.0), (0.0, 90.0), (0.0, 180.0), (0.0, 270.0), (90.0, 0.0), (90.0, 180.0)]
}
SETTINGS_ATTITUDES = {k: {"pitch_deg": p, "roll_deg": r} for k, (p, r) in ATTITUDES.items()}
ACC_NOISE = 0.01  # m/s^2 per sample
N = 2000  # samples per position


def procedure_table_run(seed: int = 3) -> tuple[dict[str, Recording], np.ndarray, np.ndarray]:
    """Static positions of a unit on a table in the procedure's convention; (segments, M, b)."""
    rng = np.random.default_rng(seed)
    m = rng.uniform(-0.004, 0.004, (3, 3))
    np.fill_diagonal(m, [-0.0125, 0.008, -0.006])  # the acc.scale.x = -0.0125
    b = np.array([0.05, -0.08, 0.12])
    out = {}
    for label, (p, r) in ATTITUDES.items():
        c = table_attitude(p * DEG, r * DEG, convention="rate_table_procedure")
        f = specific_force(c, G)
        acc = (np.eye(3) + m) @ f + b + ACC_NOISE * rng.standard_normal((N, 3))
        t = np.arange(N) * 0.01
        out[label] = Recording(t, acc, 1e-4 * rng.standard_normal((N, 3)), label=label)
    return out, m, b


def test_procedure_convention_is_a_x_plus_g_sin_pitch():
    for pitch in (-60.0, 30.0, 90.0):
        c_proc = table_attitude(pitch * DEG, 0.0, convention="rate_table_procedure")
        f_proc = specific_force(c_proc, G)
        f_proj = specific_force(table_attitude(pitch * DEG, 0.0), G)
        assert f_proc[0] == pytest.approx(G * np.sin(pitch * DEG), abs=1e-12)
        assert f_proj[0] == pytest.approx(-G * np.sin(pitch * DEG), abs=1e-12)
    with pytest.raises(ValueError, match="unknown attitude convention 'ned'"):
        table_attitude(0.0, 0.0, convention="ned")


def test_wrong_convention_fails_with_a_hint_instead_of_a_number():
    segments, _, _ = procedure_table_run()
    settings = {"attitudes": SETTINGS_ATTITUDES, "gyro_gsens": False}
    with pytest.raises(ValueError) as info:
        procedures.solve("multi_position", segments, G, settings)
    msg = str(info.value)
    assert "acc.scale.x = -1.9" in msg and "outside physical bounds" in msg
    assert "attitude_convention" in msg and "rate_table_procedure" in msg
    # ... and it names the duplicate attitude and the missing sense seen before solving.
    assert "attitudes p90r0, p90r180 are the same" in msg and "no attitude has +x up" in msg


def test_procedure_convention_by_name_solves_and_warns_about_the_attitude_list():
    segments, m, b = procedure_table_run()
    settings = {
        "attitudes": SETTINGS_ATTITUDES,
        "attitude_convention": "rate_table_procedure",
        "gyro_gsens": False,
    }
    cal = procedures.solve("multi_position", segments, G, settings)
    # Tolerance: 5 standard uncertainties of the least-squares fit, which propagates the
    # per-sample noise ACC_NOISE / sqrt(N) of each position mean (false alarm < 1e-5 each).
    for i, a in enumerate("xyz"):
        p = cal.parameters[f"acc.scale.{a}"]
        assert abs(p.value - m[i, i]) < 5 * p.std
        q = cal.parameters[f"acc.bias.{a}"]
        assert abs(q.value - b[i]) < 5 * q.std
    assert any("attitudes p90r0, p90r180 are the same" in w for w in cal.warnings)
    assert any("no attitude has -x up" in w for w in cal.warnings)
    # y and z are seen in both senses: no warning names them.
    assert not any("-y up" in w or "+z up" in w or "-z up" in w for w in cal.warnings)


def test_attitude_problems_of_a_complete_set_are_none():
    faces = np.array([[G, 0, 0], [-G, 0, 0], [0, G, 0], [0, -G, 0], [0, 0, G], [0, 0, -G]])
    assert attitude_problems(list("abcdef"), faces, G) == ([], [])
    # 0.5 deg apart is the same attitude, 2 deg apart is not (same_deg = 1).
    tilt = specific_force(table_attitude(np.radians([0.0, 0.5, 2.0]), 0.0), G)
    dup, _ = attitude_problems(["a", "b", "c"], tilt, G)
    assert dup == [
        "attitudes a, b are the same (gravity direction within 1 deg): the repeat adds no direction"
    ]


def test_six_position_with_a_swapped_face_label_is_refused():
    # A face label mistake (x_up and x_dn files swapped) inverts the x axis: scale near -2.
    from calib_core.simulate import random_errors, six_position_integral_run

    rng = np.random.default_rng(9)
    run = six_position_integral_run(random_errors(rng), rng)
    segs = dict(run.segments)
    segs["x_up"], segs["x_dn"] = segs["x_dn"], segs["x_up"]
    with pytest.raises(ValueError, match=r"acc.scale.x = -1.9.*check the segment labels"):
        procedures.solve("six_position", segs, run.gravity, {})
