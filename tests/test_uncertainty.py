"""GUM budget arithmetic (calib_core.uncertainty) and its Type B propagation through the solvers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal, stats

from calib_core.simulate import STATIC_LABELS
from calib_core.uncertainty import (
    K_PROPAGATED,
    K_STUDENT,
    InputQuantity,
    budgets,
    coverage_factor,
    monte_carlo,
)
from calib_core.uncertainty_sources import EquipmentSpec, reference_forces, static_accel_budgets


def _linear(values):
    return {"y": 2.0 * values["x1"] + 0.5 * values["x2"]}


INPUTS = [
    InputQuantity("x1", 1.0, math.sqrt(3.0), "rectangular"),  # u = 1, c = 2 -> 2
    InputQuantity("x2", 4.0, 4.0, "normal", k=2.0),  # u = 2, c = 0.5 -> 1
]


def test_budget_arithmetic_by_hand():
    b = budgets(_linear, INPUTS, {"y": (2.0, 4.0)})["y"]
    assert b.value == pytest.approx(4.0)
    rows = {r.source: r for r in b.rows}
    assert rows["x1"].std_input == pytest.approx(1.0)
    assert rows["x1"].sensitivity == pytest.approx(2.0)
    assert rows["x2"].contribution == pytest.approx(1.0)
    assert b.uc == pytest.approx(3.0)  # sqrt(2^2 + 2^2 + 1^2)
    assert b.nu_eff == pytest.approx(81.0 / (16.0 / 4.0))  # 3^4 / (2^4 / 4) = 20.25
    assert math.isclose(b.U, b.k * 3.0)
    assert not b.type_a_only and b.label == "Type A + Type B"
    # A rectangular input contributes: k from the propagated distribution, not from t.
    assert b.k_method == K_PROPAGATED
    assert b.k == pytest.approx(_convolved_k(), rel=0.015)


def _convolved_k() -> float:
    """k of 2 t_4 + U(-2 sqrt 3, 2 sqrt 3) + N(0, 1) by numerical convolution of the pdfs.

    Independent of the sampling in `propagated_coverage_factor`, whose 1e5 draws put the
    quantiles ~0.4 % of U apart from the exact ones (sqrt(p (1 - p) / n) / f(q)), so 1.5 %
    is over three of those.
    """
    dx = 1e-3
    x = np.arange(-60.0, 60.0, dx)
    pdf = stats.t.pdf(x / 2.0, 4) / 2.0
    for other in (stats.uniform.pdf(x, -2 * math.sqrt(3), 4 * math.sqrt(3)), stats.norm.pdf(x)):
        pdf = signal.fftconvolve(pdf, other, mode="same") * dx
    cdf = np.cumsum(pdf) * dx
    lo, hi = np.interp([0.025, 0.975], cdf, x)
    return (hi - lo) / 2.0 / 3.0


def test_normal_inputs_take_student_t():
    inputs = [InputQuantity("x1", 1.0, 2.0, "normal", k=2.0), INPUTS[1]]  # u = 1 as before
    b = budgets(_linear, inputs, {"y": (2.0, 4.0)})["y"]
    assert b.nu_eff == pytest.approx(20.25) and b.k_method == K_STUDENT
    # Student t at 20.25 dof lies between the tabulated 2.086 (20) and 2.080 (21).
    assert 2.080 < b.k < 2.086


def test_dominant_rectangular_coverage_factor():
    # A lone rectangular input: the 95 % interval is +-0.95 a = +-1.645 u (GUM G.2.3 note).
    b = budgets(
        lambda v: {"y": v["x1"]},
        [InputQuantity("x1", 0.0, 1.0, "rectangular")],
        {"y": (0.0, math.inf)},
    )
    assert b["y"].k == pytest.approx(0.95 * math.sqrt(3.0), rel=0.01)
    back = type(b["y"]).from_dict(b["y"].to_dict())
    assert back == b["y"]


def test_distribution_divisors():
    assert InputQuantity("a", 0, 6.0, "triangular").std == pytest.approx(6 / math.sqrt(6))
    assert InputQuantity("a", 0, 2.0, "u-shaped").std == pytest.approx(2 / math.sqrt(2))
    with pytest.raises(ValueError, match="distribution"):
        InputQuantity("a", 0, 1.0, "gaussian")


def test_coverage_factor_normal_limit():
    assert coverage_factor(math.inf) == pytest.approx(1.95996, abs=1e-5)
    assert coverage_factor(10) == pytest.approx(stats.t.ppf(0.975, 10))


def test_equipment_unknown_is_labelled_type_a_only():
    b = budgets(lambda values: {"y": 4.0}, [], {"y": (2.0, math.inf)})["y"]
    assert b.type_a_only and "Type A only" in b.label and "equipment unknown" in b.notes[0]
    assert len(b.rows) == 1 and math.isclose(b.U, 1.95996 * 2.0, rel_tol=1e-5)


def test_monte_carlo_matches_linear_budget():
    n = 40_000
    b = budgets(_linear, INPUTS, {"y": (2.0, math.inf)})["y"]
    mean, lo, hi = monte_carlo(
        _linear, INPUTS, {"y": (2.0, math.inf)}, n, np.random.default_rng(1)
    )["y"]
    # Sum of a uniform (u = 2) and normals: nearly normal; the 2.5 % quantile's sampling
    # error at n = 40000 is ~1 % of U, so 4 % is four of those standard errors.
    assert (hi - lo) / 2 == pytest.approx(b.U, rel=0.04)
    assert mean == pytest.approx(4.0, abs=5 * b.uc / math.sqrt(n))


def test_gravity_sensitivity_through_the_static_solver():
    g, scale = 9.81, 0.01
    f = reference_forces(STATIC_LABELS, {"gravity": g})
    means = f * (1 + scale) + 0.1
    sem = np.full((6, 3), 1e-3)
    b, _ = static_accel_budgets(STATIC_LABELS, means, sem, 19, g, EquipmentSpec())
    rows = {r.source: r for r in b["acc.scale.x"].rows}
    # scale = (A_up - A_dn) / (2 g) - 1 -> d scale / d g = -(1 + scale) / g.
    assert rows["gravity"].sensitivity == pytest.approx(-(1 + scale) / g, rel=1e-6)
    assert rows["gravity"].std_input == pytest.approx(EquipmentSpec().gravity_expanded / 2)
    unknown, _ = static_accel_budgets(STATIC_LABELS, means, sem, 19, g, None)
    assert unknown["acc.scale.x"].type_a_only
    assert unknown["acc.scale.x"].U < b["acc.scale.x"].U
