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
