"""ILAC-G8 decision rules (calib_core.decision): every verdict at its boundaries."""

from __future__ import annotations

import math

import pytest

from calib_core.decision import COND_FAIL, COND_PASS, FAIL, PASS, DecisionRule, decide

UP = math.inf


def _after(x: float) -> float:
    return math.nextafter(x, UP)


def _before(x: float) -> float:
    return math.nextafter(x, -UP)


@pytest.mark.parametrize(
    ("rule", "w"),
    [(DecisionRule("guard_band"), 0.25), (DecisionRule("guard_band_r", r=0.5), 0.125)],
)
def test_guarded_acceptance_boundaries(rule, w):
    U, lo, hi = 0.25, -1.0, 1.0
    assert decide(hi - w, U, lo, hi, rule) == PASS
    assert decide(_after(hi - w), U, lo, hi, rule) == COND_PASS
    assert decide(hi, U, lo, hi, rule) == COND_PASS
    assert decide(_after(hi), U, lo, hi, rule) == COND_FAIL
    assert decide(hi + w, U, lo, hi, rule) == COND_FAIL
    assert decide(_after(hi + w), U, lo, hi, rule) == FAIL
    # the lower side mirrors it
    assert decide(lo + w, U, lo, hi, rule) == PASS
    assert decide(_before(lo + w), U, lo, hi, rule) == COND_PASS
    assert decide(_before(lo), U, lo, hi, rule) == COND_FAIL
    assert decide(_before(lo - w), U, lo, hi, rule) == FAIL


def test_simple_acceptance_is_binary():
    rule = DecisionRule("simple")
    assert decide(1.0, 0.5, -1.0, 1.0, rule) == PASS
    assert decide(_after(1.0), 0.5, -1.0, 1.0, rule) == FAIL
    assert decide(-1.0, 0.5, -1.0, 1.0, rule) == PASS
    assert decide(_before(-1.0), 0.5, -1.0, 1.0, rule) == FAIL


def test_one_sided_limit():
    rule = DecisionRule("guard_band")
    assert decide(0.7, 0.25, -math.inf, 1.0, rule) == PASS
    assert decide(0.8, 0.25, -math.inf, 1.0, rule) == COND_PASS


def test_statements_name_rule_and_risk():
    assert "simple acceptance" in DecisionRule("simple").statement()
    s = DecisionRule("guard_band").statement(k=2.0)
    assert "w = 1 U" in s and "2.3 %" in s  # 1 - Phi(2) = 2.28 %
    assert "w = 0.5 U" in DecisionRule("guard_band_r", r=0.5).statement()


def test_bad_rule_and_inputs_refused():
    with pytest.raises(ValueError, match="decision rule"):
        DecisionRule("strict")
    with pytest.raises(ValueError, match="r must be"):
        DecisionRule("guard_band_r", r=0.0)
    with pytest.raises(ValueError, match="expanded uncertainty"):
        decide(0.0, -1.0, -1.0, 1.0, DecisionRule())
    with pytest.raises(ValueError, match="lower limit"):
        decide(0.0, 0.1, 1.0, -1.0, DecisionRule())


def _profile_doc(rule):
    return {
        "name": "t",
        "version": "1",
        "device_model": "X",
        "decision_rule": rule,
        "limits": [{"pattern": "acc.scale.*", "bound": 1.0, "unit": "1"}],
    }


def test_profile_names_its_rule_and_judges():
    from calib_core.tolerances import ToleranceProfile

    prof = ToleranceProfile.from_dict(_profile_doc({"name": "guard_band_r", "r": 0.5}))
    assert prof.decision_rule == DecisionRule("guard_band_r", 0.5)
    assert prof.judge("acc.scale.x", 0.9, 0.25) == COND_PASS
    assert prof.judge("acc.bias.x", 0.9, 0.25) is None
    back = ToleranceProfile.from_dict(prof.to_dict())
    assert back.decision_rule == prof.decision_rule
    plain = ToleranceProfile.from_dict({k: v for k, v in _profile_doc({}).items()})
    assert plain.decision_rule == DecisionRule("simple")
    assert "decision_rule" not in plain.to_dict()
    with pytest.raises(ValueError, match="decision_rule"):
        ToleranceProfile.from_dict(_profile_doc({"name": "lenient"}))
