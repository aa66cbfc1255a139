"""Centrifuge planning (table rates for the g levels) and the zero output before and after."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from calib_core import procedures
from calib_core.checks import check_calibration
from calib_core.earth import EARTH_RATE
from calib_core.simulate.centrifuge import CentrifugeSchedule, simulate_centrifuge
from calib_core.solvers.centrifuge import solve_centrifuge
from calib_core.solvers.centrifuge_model import CentrifugeSettings
from calib_core.solvers.centrifuge_plan import DEFAULT_G_LEVELS, plan_rates
from calib_core.solvers.centrifuge_segments import step_label
from calib_core.tolerances import ToleranceProfile
from calib_core.units import STANDARD_GRAVITY
from pipelines.centrifuge import render_report
from pipelines.cli import app

G = STANDARD_GRAVITY


def test_rates_give_the_procedures_g_levels_exactly():
    """docs/methods.md 2.8: steps 2 g .. 20 g, input R w (w + 2 Omega_V).

    The planned rate must give n g through the procedure's own formula (to
    rounding, 1e-12 relative), and differ from the Earth-rate-free sqrt(n g / R)
    by Omega_V (the root's shift): -Omega_V anticlockwise, +Omega_V in size clockwise.
    Hand value: 20 g on a 1 m arm at the equator is sqrt(196.133) = 14.00475 rad/s,
    133.736 rpm.
    """
    assert tuple(float(n) for n in range(2, 21, 2)) == DEFAULT_G_LEVELS
    radius, lat = 0.8, 50.0
    omega_v = EARTH_RATE * math.sin(math.radians(lat))
    for sense in (1, -1):
        points = plan_rates(radius, latitude_deg=lat, sense=sense)
        for p in points:
            assert radius * p.rate * (p.rate + 2 * omega_v) == pytest.approx(p.n_g * G, rel=1e-12)
            assert p.input == pytest.approx(p.n_g * G, rel=1e-12)
            plain = math.sqrt(p.n_g * G / radius)
            # the root's shift is Omega_V to first order; its square is 1e-10 relative
            assert abs(p.rate) - plain == pytest.approx(-sense * omega_v, rel=1e-3)
    p20 = plan_rates(1.0, [20])[0]
    assert p20.rate == pytest.approx(14.00475, abs=5e-6)
    assert p20.rpm == pytest.approx(133.736, abs=5e-4)
    with pytest.raises(ValueError, match=r"20 g at R = 1 m needs .* above the table"):
        plan_rates(1.0, [2, 20], max_rate=10.0)
    with pytest.raises(ValueError, match="radius must be a positive number"):
        plan_rates(0.0)
    with pytest.raises(ValueError, match="g levels must be positive"):
        plan_rates(1.0, [2, -4])


def test_plan_command_prints_the_rates():
    res = CliRunner().invoke(
        app, ["centrifuge", "plan", "--radius", "1.0", "--sense", "cw", "--json"]
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert [s["g"] for s in doc["steps"]] == list(DEFAULT_G_LEVELS)
    last = doc["steps"][-1]
    assert last["rate_rad_s"] < 0 and last["rpm"] == pytest.approx(133.736, abs=5e-4)
    # 5 min per step (the paper): turns = rate * 300 s / 2 pi
    assert last["revolutions"] == pytest.approx(abs(last["rate_rad_s"]) * 300 / (2 * math.pi))
    text = CliRunner().invoke(app, ["centrifuge", "plan", "--radius", "1", "--levels", "2,20"])
    assert text.exit_code == 0 and "133.7" in text.output
    bad = CliRunner().invoke(app, ["centrifuge", "plan", "--radius", "1", "--max-rpm", "100"])
    assert bad.exit_code == 2 and "above the table" in bad.output


def _run_with_zero_after(drift):
    truth = {a: {"const": 0.1, f"a_{a}": 1e-3} for a in "xyz"}
    return simulate_centrifuge(
        truth,
        rng=np.random.default_rng(4),
        schedule=CentrifugeSchedule(
            g_steps=(2, 6, 10, 14, 20),
            sample_rate=50.0,
            zero_duration=4.0,
            one_g_duration=20.0,
            step_duration=4.0,
            zero_after=True,
        ),
        zero_drift=drift,
    )


def test_zero_before_and_after_each_run_are_compared():
    """A zero that moved 0.05 m/s^2 on x+ (2.5 x the 0.002 g = 0.0196 m/s^2 limit) fails;
    the others pass: their shift is noise only, 0.05 / sqrt(4 x 200) x sqrt(2) = 0.0025
    m/s^2 std, the limit is 7.8 of those (false alarm ~1e-14 per axis)."""
    run = _run_with_zero_after({"x+": (0.05, 0.0, 0.0)})
    model, record = solve_centrifuge(run.steps, CentrifugeSettings(50.0))
    assert set(model.zero_shift) == set(model.radius)
    z = model.zero_shift["x+"]
    assert z.shift[0] == pytest.approx(0.05, abs=4 * z.std[0])
    assert list(z.passed) == [False, True, True]
    assert all(m.passed.all() for k, m in model.zero_shift.items() if k != "x+")
    assert record.settings["zero_shift_limit"] == pytest.approx(0.002 * G)
    text = render_report(model, CentrifugeSettings(50.0))
    zero_section = text.split("ZERO OUTPUT AFTER - BEFORE")[1].split("AXIS x")[0]
    rows = {line.split()[0]: line for line in zero_section.splitlines()[2:] if line.strip()}
    assert rows["x+"].endswith("FAIL") and rows["y-"].endswith("pass") and len(rows) == 6
    # the procedure: one check per position and axis, in the run's checks and verdict
    segments = {step_label(s): s.recording for s in run.steps}
    cal = procedures.solve("centrifuge", segments, G, {"latitude_deg": 50.0})
    checks = {c.name: c for c in check_calibration(cal, ToleranceProfile("t", "1", "HG", []))}
    assert not checks["zero_shift:x+:x"].passed and checks["zero_shift:x+:y"].passed
    assert checks["zero_shift:x+:x"].limit == pytest.approx(0.002 * G)
    assert any("x+ x: zero after - before" in w for w in cal.warnings)
    # a wider limit (setting) passes it
    cal = procedures.solve(
        "centrifuge", segments, G, {"latitude_deg": 50.0, "zero_shift_limit": 0.1}
    )
    assert all(c["passed"] for c in cal.info["solver_checks"])


def test_the_zero_output_averages_before_and_after_the_run():
    """docs/methods.md 2.8: the paper averages the four-position zero output before and
    after the run. With zeros after the run the zero used is the mean of both (x+ moved
    0.02 m/s^2 on x: its zero is half of that above the zero before, within noise); a run
    without zeros after uses the zero before alone."""
    from calib_core.solvers.centrifuge_model import zero_output

    run = _run_with_zero_after({"x+": (0.02, 0.0, 0.0)})
    model, _ = solve_centrifuge(run.steps, CentrifugeSettings(50.0))
    for mount in model.zero:
        kinds = {
            k: [s for s in run.steps if s.mount == mount and s.kind == k]
            for k in ("zero", "zero_after")
        }
        before, after = zero_output(kinds["zero"])[0], zero_output(kinds["zero_after"])[0]
        assert model.zero[mount] == pytest.approx((before + after) / 2.0, abs=1e-12), mount
    only_before = [s for s in run.steps if s.kind != "zero_after"]
    alone, _ = solve_centrifuge(only_before, CentrifugeSettings(50.0))
    x_plus = [s for s in only_before if s.mount == "x+" and s.kind == "zero"]
    assert alone.zero["x+"] == pytest.approx(zero_output(x_plus)[0], abs=1e-12)
    z = model.zero_shift["x+"]  # the after - before: half of it moves the zero used
    assert model.zero["x+"][0] - alone.zero["x+"][0] == pytest.approx(0.01, abs=2 * z.std[0])
    assert alone.zero_shift == {}


def _rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: rotation by `angle` (rad) about the unit vector `axis`."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


@pytest.mark.parametrize("latitude", [50.0, -35.0])
@pytest.mark.parametrize("direction", [1, -1])
def test_the_earth_rate_sign_from_the_kinematics(latitude, direction):
    """The centrifuge paper's E_rot - E_static = R w0 (w0 +- 2 Omega_V) (docs/methods.md
    2.8, eq. 2.5), its sign worked out from the motion itself, not from the formula: a point
    on the arm (R = 1 m, near 1 g) placed in inertial space by the Earth's turn about its
    axis and the table's about the local vertical, differentiated twice numerically (the
    Earth's own centripetal term at rest subtracted), projected on the arm towards the
    axis. It equals `centripetal_input` with w0 signed about up for both senses and both
    hemispheres; the opposite sign is off by 4 R |w0 Omega_V| (0.5e-3 .. 0.7e-3 m/s^2),
    60 - 90 times the differentiation's error (8e-6 m/s^2)."""
    from calib_core.solvers.centrifuge_model import centripetal_input, vertical_earth_rate

    radius, lat = 1.0, math.radians(latitude)
    w0 = direction * math.sqrt(G / radius)
    earth = np.array([0.0, math.cos(lat), math.sin(lat)])  # Earth's axis in local (E, N, U)

    def inertial(t: float, rate: float) -> np.ndarray:
        arm = radius * np.array([math.cos(rate * t), math.sin(rate * t), 0.0])
        return _rotation_about(earth, EARTH_RATE * t) @ arm

    def inward(t0: float, rate: float) -> float:
        h = 1e-3
        acc = (inertial(t0 + h, rate) - 2 * inertial(t0, rate) + inertial(t0 - h, rate)) / h**2
        body = _rotation_about(earth, EARTH_RATE * t0).T @ acc  # back to the local frame
        out = np.array([math.cos(rate * t0), math.sin(rate * t0), 0.0])
        return float(-body @ out)  # specific force of the turn points inward

    for t0 in (0.3, 1.7):
        measured = inward(t0, w0) - inward(t0, 0.0)
        expected = centripetal_input(radius, w0, vertical_earth_rate(latitude))
        wrong = radius * w0 * (w0 - 2.0 * vertical_earth_rate(latitude))
        assert abs(measured - expected) < abs(expected - wrong) / 50.0, (measured, expected)


def test_zero_positions_of_3_minutes_and_g_steps_of_5_minutes():
    """docs/methods.md 2.8: the zero output 3 min at each table position, each g step 5 min;
    the shortest record of each kind is judged (a warning: a shorter record is noisier,
    and its uncertainty says so), 2.9 min warns, 3 passes; 4.9 min warns, 5 passes."""
    from calib_core import conditions
    from calib_core.recording import Recording

    def record(minutes: float) -> Recording:
        t = np.arange(int(round(minutes * 60.0)) + 1, dtype=float)  # 1 Hz is enough here
        table = {"table_angle": np.zeros(len(t)), "table_rate": np.zeros(len(t))}
        zeros = np.zeros((len(t), 3))
        return Recording(t=t, acc=zeros, gyr=zeros, reference=table)

    def judged(zero_min: float, step_min: float) -> dict:
        segments = {f"xp_zero_{d}": record(3.0) for d in (0, 90, 180, 270)}
        segments |= {"xp_zero_after_90": record(zero_min), "xp_1g": record(1.0)}
        segments |= {"xp_step_2g": record(5.0), "xp_step_20g": record(step_min)}
        checks = conditions.check_conditions(
            segments, {}, procedure="centrifuge", settings={}, gravity=G, gravity_source="site"
        )
        return {c.name.removeprefix("condition:"): c for c in checks}

    short = judged(2.9, 4.9)
    zero, step = short["zero_position_min"], short["g_step_min"]
    assert conditions.status(zero) == conditions.WARNING and "xp_zero_after_90" in zero.detail
    assert conditions.status(step) == conditions.WARNING and "xp_step_20g" in step.detail
    assert zero.value == pytest.approx(2.9) and step.value == pytest.approx(4.9)
    full = judged(3.0, 5.0)
    assert full["zero_position_min"].passed and full["g_step_min"].passed
    assert "zero_position_min" not in {
        c.name.removeprefix("condition:")
        for c in conditions.check_conditions(
            {"z_up": record(1.0)},
            {},
            procedure="static_bias",
            settings={},
            gravity=G,
            gravity_source="site",
        )
    }
