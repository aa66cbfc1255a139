"""Tolerance profiles (lab units -> SI, clear errors) and the pass/fail checks."""

from __future__ import annotations

import inspect
import math
import re
import textwrap
import tomllib

import numpy as np
import pytest

from calib_core.calibration import Calibration, CheckResult, SegmentResidual
from calib_core.checks import check_parameters, check_residuals, overall_verdict
from calib_core.procedures import solve
from calib_core.simulate import random_errors, six_position_integral_run
from calib_core.tolerances import ParameterLimit, ToleranceProfile, parse_unit
from calib_core.units import DEG, STANDARD_GRAVITY


def docstring_example() -> dict:
    """The MPU-6000 example of ToleranceProfile.from_dict's docstring, parsed as TOML."""
    doc = inspect.getdoc(ToleranceProfile.from_dict)
    block = doc.split("::", 1)[1].split("Raises", 1)[0]
    return tomllib.loads(textwrap.dedent(block))


@pytest.fixture
def mpu() -> ToleranceProfile:
    return ToleranceProfile.from_dict(docstring_example())


def test_docstring_example_converts_to_si(mpu):
    assert (mpu.name, mpu.device_model) == ("mpu6000", "MPU-6000")
    lim = mpu.limit_for("gyr.bias.y")
    assert (lim.low, lim.high) == pytest.approx((-20 * DEG, 20 * DEG))
    gs = mpu.limit_for("gyr.gsens.zx")
    assert gs.high == pytest.approx(0.1 * DEG / STANDARD_GRAVITY)
    noise = mpu.limit_for("gyr.noise.z")
    assert noise.low == -math.inf and noise.high == pytest.approx(0.05 * DEG)
    # first match wins: z has its own bias limit listed before acc.bias.*
    assert mpu.limit_for("acc.bias.z").high == 0.8
    assert mpu.limit_for("acc.bias.x").high == 0.5
    assert mpu.residual_limits["acc_std"] == pytest.approx(0.002 * STANDARD_GRAVITY)
    assert mpu.residual_limits["gyr_mean"] == pytest.approx(0.1 * DEG)  # default
    assert mpu.limit_for("acc.k2.x") is None


def test_round_trip(mpu):
    again = ToleranceProfile.from_dict(mpu.to_dict())
    assert again == mpu


@pytest.mark.parametrize(
    "unit, dim, factor",
    [
        ("%", "dimensionless", 0.01),
        ("mg", "acceleration", STANDARD_GRAVITY * 1e-3),
        ("deg/h", "angular rate", DEG / 3600),
        ("deg/s/g", "angular rate/acceleration", DEG / STANDARD_GRAVITY),
        ("(rad/s)/(m/s^2)", "angular rate/acceleration", 1.0),
        ("1/g", "1/acceleration", 1 / STANDARD_GRAVITY),
        ("1/(m/s^2)^2", "1/acceleration^2", 1.0),
    ],
)
def test_parse_unit(unit, dim, factor):
    d, f = parse_unit(unit)
    assert d == dim and f == pytest.approx(factor)


def bad(doc_change, index=None):
    doc = docstring_example()
    if index is None:
        doc.update(doc_change)
    else:
        doc["limits"][index] = doc_change
    return doc


@pytest.mark.parametrize(
    "doc, message",
    [
        (
            bad({"pattern": "gyr.bias.*", "bound": 20, "unit": "m/s^2"}, 2),
            r"limits\[2\]\.unit: 'm/s\^2' is a unit of acceleration, but .* angular rate",
        ),
        (bad({"pattern": "gyr.bias.*", "bound": 20, "unit": "furlong"}, 2), r"limits\[2\]\.unit"),
        (bad({"pattern": "gyr.bias.*", "bound": 20}, 2), r"limits\[2\]\.unit: missing"),
        (bad({"pattern": "gyr.bais.*", "bound": 20, "unit": "deg/s"}, 2), "matches no canonical"),
        (bad({"pattern": "gyr.*", "bound": 1, "unit": "1"}, 0), "different units"),
        (bad({"pattern": "acc.scale.*", "unit": "1"}, 5), r"limits\[5\]: missing bound"),
        (bad({"pattern": "acc.scale.*", "bound": "3%", "unit": "1"}, 5), r"limits\[5\]\.bound"),
        (bad({"pattern": "acc.scale.*", "low": 1, "high": 0, "unit": "1"}, 5), "above high"),
        (bad({"pattern": "acc.scale.*", "hgh": 1, "unit": "1"}, 5), "unknown field"),
        (bad({"residual_limits": {"acc_std": {"value": 2, "unit": "deg/s"}}}), "acc_std.unit"),
        (bad({"residual_limits": {"acc_sd": {"value": 2, "unit": "mg"}}}), "acc_sd: unknown key"),
        (bad({"device_model": ""}), "device_model"),
    ],
)
def test_profile_errors_name_the_field(doc, message):
    with pytest.raises(ValueError, match=message):
        ToleranceProfile.from_dict(doc)


@pytest.mark.parametrize(
    ("old", "new", "line_starts", "message"),
    [
        ('pattern = "gyr.bias.*"', 'pattern = "gyr.bais.*"', "pattern", r"limits\[2\]\.pattern: "),
        ('unit = "deg/s" }', 'unit = "m/s^2" }', "gyr_std", r"residual_limits\.gyr_std\.unit: "),
        ("[protocol]", "[recall]\nmethod = 'weekly'\n[protocol]", "method", r"recall\.method must"),
    ],
)
def test_profile_file_errors_name_file_line_and_field(
    tmp_path, monkeypatch, old, new, line_starts, message
):
    """As a manifest's: the file, the line that writes the key (of its inline table), the
    dotted field."""
    from pipelines.tolerances import SHIPPED, load_profile

    text = (SHIPPED / "mpu6000.toml").read_text(encoding="utf-8")
    assert old in text
    text = text.replace(old, new, 1)
    (tmp_path / "bad.toml").write_text(text, encoding="utf-8")
    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path))
    with pytest.raises(ValueError) as err:
        load_profile("bad")
    where = str(err.value).split(": ", 1)[0]
    assert where.startswith(f"tolerance profile {tmp_path / 'bad.toml'} line ")
    line = int(where.rsplit(" ", 1)[1])
    assert text.splitlines()[line - 1].startswith(line_starts)
    assert re.search(message, str(err.value))


def cal_with(**values) -> Calibration:
    cal = Calibration("six_position", STANDARD_GRAVITY)
    for name, v in values.items():
        cal.add(name.replace("_", "."), v, 1e-4)
    return cal


def test_check_parameters_bounds_inclusive_and_first_match(mpu):
    cal = cal_with(
        **{"acc_bias_z": 0.7, "acc_bias_x": 0.7, "gyr_scale_y": -0.03, "gyr_noise_x": 0.06 * DEG}
    )
    cal.add("acc.k2.x", 5.0)  # no limit: not checked
    res = {c.name: c for c in check_parameters(cal, mpu)}
    assert set(res) == {
        "param:acc.bias.z",
        "param:acc.bias.x",
        "param:gyr.scale.y",
        "param:gyr.noise.x",
    }
    assert res["param:acc.bias.z"].passed and res["param:acc.bias.z"].limit == 0.8
    assert not res["param:acc.bias.x"].passed and res["param:acc.bias.x"].limit == 0.5
    assert res["param:gyr.scale.y"].passed  # on the bound
    assert not res["param:gyr.noise.x"].passed
    assert res["param:gyr.noise.x"].limit == pytest.approx(0.05 * DEG)
    assert overall_verdict(list(res.values())) == "fail"


def test_check_residuals_worst_axis(mpu):
    cal = Calibration("six_position", STANDARD_GRAVITY)
    cal.residuals.append(
        SegmentResidual("x_up", "acc", (0.0, -0.03, 0.001), (0.01, 0.02, 0.01), 1000)
    )
    cal.residuals.append(
        SegmentResidual("x_up", "gyr", (1e-4, 0.0, 0.0), (0.2 * DEG, 0.0, 0.0), 1000)
    )
    res = {c.name: c for c in check_residuals(cal, mpu)}
    assert res["residual:x_up:acc:std"].value == 0.02
    assert not res["residual:x_up:acc:std"].passed  # 0.02 > 0.002 g = 0.0196
    assert res["residual:x_up:acc:mean"].value == 0.03 and not res["residual:x_up:acc:mean"].passed
    assert not res["residual:x_up:gyr:std"].passed
    assert res["residual:x_up:gyr:mean"].passed


def test_verdict():
    ok = CheckResult("a", 1.0, 2.0, True)
    assert overall_verdict([ok, ok]) == "pass"
    assert overall_verdict([ok, CheckResult("b", 3.0, 2.0, False)]) == "fail"


def test_simulated_mems_unit_passes_and_a_bad_one_fails(mpu):
    rng = np.random.default_rng(0)
    truth = random_errors(rng)
    # The simulator's MEMS noise (0.04-0.06 deg/s) straddles the 0.05 deg/s tolerance:
    # make this unit clearly quiet enough.
    truth.gyr_noise[:] = 0.03 * DEG
    run = six_position_integral_run(truth, rng)
    cal = solve("six_position_integral", run.segments, run.gravity, {})
    checks = check_parameters(cal, mpu) + check_residuals(cal, mpu)
    # 39 parameters less acc.noise.* (no limit in the profile); 18 residuals, std and mean.
    assert len(checks) == 36 + 2 * 18
    assert overall_verdict(checks) == "pass", [c for c in checks if not c.passed]
    truth.gyr_M[1, 1] = 0.05  # gyro y scale 5 %: outside +-3 %
    run = six_position_integral_run(truth, rng)
    cal = solve("six_position_integral", run.segments, run.gravity, {})
    failed = [
        c.name for c in check_parameters(cal, mpu) + check_residuals(cal, mpu) if not c.passed
    ]
    assert failed == ["param:gyr.scale.y"]


def test_parameter_limit_limit_property():
    assert ParameterLimit("acc.bias.*", -1.0, 1.0).limit == 1.0
    assert ParameterLimit("acc.noise.*", -math.inf, 0.1).limit == 0.1
    assert ParameterLimit("acc.scale.*", -0.5, math.inf).limit == -0.5
