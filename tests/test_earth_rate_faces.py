"""Gyro bias, scale and misalignment from the six statics with Earth rate as the input
(six_position, gyro_from_earth_rate; docs/methods.md 2.1, the north-seeker note's FOG case)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2, norm

from calib_core.earth import earth_rate_local
from calib_core.procedures import SettingError, solve
from calib_core.procedures.six_position import solve_six_position
from calib_core.simulate import STATIC_LABELS, random_errors
from calib_core.simulate.lab_run import six_position_integral_run
from calib_core.solvers.earth_rate_faces import face_earth_rate, faces_earth_rate
from calib_core.solvers.static_bias import earth_rate_level_frame

LATITUDE = 52.3
GYRO = [f"gyr.{kind}.{a}" for kind in ("bias", "scale") for a in "xyz"] + [
    f"gyr.misalign.{a}{b}" for a in "xyz" for b in "xyz" if a != b
]
# Two solves of 12 estimates each, Gaussian (means of 60000 white samples): k such that
# all 24 fall within k standard uncertainties with probability 0.999 (Sidak).
N_ESTIMATES = 2 * len(GYRO)
K = float(norm.isf((1.0 - 0.999 ** (1.0 / N_ESTIMATES)) / 2.0))


def _level_axes_in_ned(heading_deg: float) -> np.ndarray:
    """(3, 3) rows e1 (at the heading), e2 (heading - 90 deg), e3 (up) in North-East-Down."""
    h = math.radians(heading_deg)
    return np.array([[math.cos(h), math.sin(h), 0.0], [math.sin(h), -math.cos(h), 0.0], [0, 0, -1]])


@pytest.mark.parametrize("heading", [0.0, 30.0, 120.0, 250.0])
def test_face_input_is_the_ned_earth_rate_seen_by_the_stated_body_axes(heading):
    """Independent of the module's index formula: build each position's body axes from the
    words of docs/methods.md (named axis up or down, the next axis of x->y->z->x at the
    heading, right-handed) and project the NED Earth rate (calib_core.earth) onto them."""
    e = _level_axes_in_ned(heading)
    w_ned = earth_rate_local(LATITUDE)
    np.testing.assert_allclose(e @ w_ned, earth_rate_level_frame(LATITUDE, heading), atol=1e-18)
    for label in STATIC_LABELS:
        axis, sense = "xyz".index(label[0]), 1.0 if label.endswith("up") else -1.0
        body = np.zeros((3, 3))  # rows: body x, y, z in NED
        body[axis] = sense * e[2]
        body[(axis + 1) % 3] = e[0]
        body[(axis + 2) % 3] = np.cross(body[axis], body[(axis + 1) % 3])
        assert np.linalg.det(body) == pytest.approx(1.0)
        np.testing.assert_allclose(
            face_earth_rate(label, LATITUDE, heading), body @ w_ned, atol=1e-18, err_msg=label
        )


def _fog_run(heading: float, seed: int = 3):
    truth = random_errors(np.random.default_rng(seed), "fog")
    run = six_position_integral_run(
        truth,
        np.random.default_rng(seed + 100),
        rate_hz=100.0,
        static_s=600.0,
        earth_rate_at=(LATITUDE, heading),
    )
    return truth, {label: run.segments[label] for label in STATIC_LABELS}, run.gravity


def _solve(segments, gravity, heading):
    """Through the procedure registry: settings validated, motion checks, physical bounds."""
    settings = {"gyro_from_earth_rate": True, "latitude_deg": LATITUDE, "heading_deg": heading}
    return solve("six_position", segments, gravity, settings)


def _z(cal, truth) -> dict[str, float]:
    true = truth.parameters()
    return {n: (cal.value(n) - true[n]) / cal.parameters[n].std for n in GYRO}


def _check(cal, name):
    return next(c for c in cal.info["solver_checks"] if c["name"] == name)


def test_fog_recovers_bias_scale_and_misalignment_at_two_headings_90_deg_apart():
    """The same unit on the fixture at 30 deg and at 120 deg: both solves give the truth
    within K standard uncertainties; the data of 120 deg solved as if at 30 deg do not."""
    worst = {}
    for heading in (30.0, 120.0):
        truth, segments, gravity = _fog_run(heading)
        cal = _solve(segments, gravity, heading)
        observable = _check(cal, "model:earth_rate_observable")
        assert observable["passed"] and observable["value"] < 1e-3
        z = _z(cal, truth)
        worst[heading] = max(abs(v) for v in z.values())
        assert worst[heading] < K, (heading, z)
        # The fit sees the misalignment: the nine M_ij jointly differ from zero far beyond
        # chance (a solver returning M = 0 would pass the K test above for the smallest).
        m = np.array([cal.value(n) / cal.parameters[n].std for n in GYRO if ".bias." not in n])
        assert float(m @ m) > chi2.isf(1e-6, 9)
        assert cal.parameters["gyr.bias.x"].std < 0.01 * math.pi / 180 / 3600  # < 0.01 deg/h
        assert not any(n.startswith("gyr.gsens") for n in cal.parameters)
    # Solved as if at 30 deg, the six means do not fit the model: the residuals reject it
    # (chi2 far above its 0.999 quantile), the uncertainties carry the misfit
    # (calib_core.stats.misfit_scale) and the record says so: the wrong heading cannot
    # pass for a precise result.
    wrong = _solve(segments, gravity, 30.0)
    widened = min(wrong.parameters[n].std / cal.parameters[n].std for n in GYRO)
    assert widened > 10 * K, widened
    assert any("gyro fit beyond their noise" in w for w in wrong.warnings), wrong.warnings
    assert not any("gyro fit" in w for w in cal.warnings), cal.warnings


def test_mems_gyro_is_refused_the_earth_rate_unobservable():
    truth = random_errors(np.random.default_rng(5), "mems")
    run = six_position_integral_run(
        truth, np.random.default_rng(6), static_s=20.0, earth_rate_at=(LATITUDE, 30.0)
    )
    segments = {label: run.segments[label] for label in STATIC_LABELS}
    with pytest.raises(ValueError, match=r"ratio 0\.4.*hides the Earth rate.*not identifiable"):
        _solve(segments, run.gravity, 30.0)
    # The same run without the setting: gyro bias and g-sensitivity as before.
    cal = solve_six_position(segments, run.gravity)
    assert "gyr.gsens.xx" in cal.parameters and "gyr.scale.x" not in cal.parameters


@pytest.mark.parametrize(
    ("latitude", "heading", "why"),
    [(LATITUDE, None, "heading_deg"), (None, 30.0, "latitude_deg"), (0.0, 0.0, "condition")],
)
def test_refused_when_the_input_does_not_determine_the_model(latitude, heading, why):
    with pytest.raises(ValueError, match=why):
        faces_earth_rate(latitude, heading)


def test_pole_is_well_posed_and_equator_facing_east_too():
    for latitude, heading in ((90.0, 0.0), (-90.0, 45.0), (0.0, 90.0)):
        w = faces_earth_rate(latitude, heading)
        assert w.shape == (6, 3)


def test_procedure_refuses_without_heading_naming_it():
    truth, segments, gravity = _fog_run(30.0)
    with pytest.raises(ValueError, match="heading_deg"):
        solve_six_position(segments, gravity, {"gyro_from_earth_rate": True, "latitude_deg": 50})


def test_setting_is_typed():
    truth, segments, gravity = _fog_run(30.0)
    with pytest.raises(SettingError, match="gyro_from_earth_rate"):
        solve("six_position", segments, gravity, {"gyro_from_earth_rate": "yes"})
