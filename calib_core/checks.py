"""Checks of a calibration against its device type's tolerance profile, and the verdict.

The profile (`calib_core.tolerances.ToleranceProfile`) holds the limits in SI;
here each parameter, each segment's residuals and the procedure's own checks
become CheckResults, and `overall_verdict` turns a list of them into "pass", "needs
review" or "fail". `check_physical_bounds` refuses a result no sensor can have.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from calib_core import decision, params
from calib_core.calibration import Calibration, CheckResult
from calib_core.check_names import (  # noqa: F401 - the names checks are judged by
    DEVICE_PREFIX,
    FAIL,
    MODEL_PREFIX,
    NEEDS_REVIEW,
    PASS,
    RECORD_PREFIX,
    REPEAT_PREFIX,
)
from calib_core.condition_rules import counts_against_verdict
from calib_core.tolerances import ParameterLimit, ToleranceProfile, family
from calib_core.uncertainty import Budget

# Physical bounds of the dimensionless linear terms: no working sensor is 50 % off in
# scale or 30 deg misaligned. Beyond them the data were read wrongly (an attitude sign
# convention, a face label, a unit), and the number must not pass as a result: an
# inverted axis gives a scale near -2, a swapped one a misalignment near 1.
PHYSICAL_BOUNDS: dict[str, float] = {
    "acc.scale": 0.5,
    "gyr.scale": 0.5,
    "acc.misalign": 0.5,
    "gyr.misalign": 0.5,
}


def check_physical_bounds(cal: Calibration, hint: str) -> None:
    """Refuse a calibration whose scale factors or misalignments are not physical.

    Raises ValueError naming every parameter outside PHYSICAL_BOUNDS, with `hint`
    (what to check: the attitude convention, the labels, the units).
    """
    bad = [
        f"{name} = {p.value:.4g}"
        for name, p in cal.parameters.items()
        if family(name) in PHYSICAL_BOUNDS and abs(p.value) > PHYSICAL_BOUNDS[family(name)]
    ]
    if bad:
        bounds = ", ".join(f"|{k}| <= {v:g}" for k, v in PHYSICAL_BOUNDS.items())
        seen = f" (the solver noted: {'; '.join(cal.warnings)})" if cal.warnings else ""
        raise ValueError(
            f"{cal.procedure}: {', '.join(bad)} outside physical bounds ({bounds}); "
            f"not a sensor's error but input read wrongly: {hint}{seen}"
        )


def _allowed(lim: ParameterLimit, unit: str) -> str:
    """The limit in words: "allowed -0.03 .. 0.03 1", "allowed at most 0.000873 rad/s"."""
    if math.isinf(lim.low) and not math.isinf(lim.high):
        return f"allowed at most {lim.high:.6g} {unit}"
    if math.isinf(lim.high) and not math.isinf(lim.low):
        return f"allowed at least {lim.low:.6g} {unit}"
    return f"allowed {lim.low:.6g} .. {lim.high:.6g} {unit}"


def check_parameters(
    cal: Calibration, profile: ToleranceProfile, budgets: Mapping[str, Budget] | None = None
) -> list[CheckResult]:
    """Each parameter against the first limit that matches its name.

    Parameters without a matching limit are not checked. With `budgets` (name -> GUM budget)
    the statement of conformity follows the profile's decision rule (ILAC-G8): passed only for
    "pass"; the detail says the verdict, U, k and the guard band w. A parameter without a
    budget is judged with U = 0 and said so.

    Returns
    -------
    CheckResult "param:<canonical name>" with the value, limit = |bound| of a
    symmetric limit (else high); the detail starts "allowed LOW .. HIGH unit"
    ("allowed at most HIGH unit" for an upper bound only, as noise has).
    """
    out = []
    for name, p in cal.parameters.items():
        lim = profile.limit_for(name)
        if lim is None:
            continue
        unit = params.unit_of(name)
        detail = _allowed(lim, unit)
        passed = bool(lim.low <= p.value <= lim.high)
        if budgets is not None:
            b = budgets.get(name)
            U = 0.0 if b is None else b.U
            outcome = decision.decide(p.value, U, lim.low, lim.high, profile.decision_rule)
            passed = outcome == decision.PASS
            w = profile.decision_rule.guard_band(U)
            detail += (
                f"; {outcome} (rule {profile.decision_rule.name}, "
                + ("no uncertainty budget" if b is None else f"U = {U:.3g} {unit} at k = {b.k:.3g}")
                + f", w = {w:.3g} {unit})"
            )
        out.append(CheckResult(f"param:{name}", p.value, lim.limit, passed, detail))
    return out


def check_residuals(cal: Calibration, profile: ToleranceProfile) -> list[CheckResult]:
    """Residual std and |mean| of every segment and sensor, worst axis, against the limits.

    Returns
    -------
    CheckResult "residual:<segment>:<sensor>:std" and "...:mean" (SI values).
    """
    out = []
    for r in cal.residuals:
        unit = params.UNITS[f"{r.sensor}.bias"]
        for stat, values in (("std", r.std), ("mean", [abs(v) for v in r.mean])):
            limit = profile.residual_limits.get(f"{r.sensor}_{stat}")
            if limit is None:
                continue
            worst = int(max(range(3), key=lambda i, v=values: v[i]))
            value = float(values[worst])
            out.append(
                CheckResult.at_most(
                    f"residual:{r.segment}:{r.sensor}:{stat}",
                    value,
                    limit,
                    f"worst axis {params.AXES[worst]}, {unit}, n={r.n}",
                )
            )
    return out


def check_calibration(
    cal: Calibration, profile: ToleranceProfile, budgets: Mapping[str, Budget] | None = None
) -> list[CheckResult]:
    """Check a calibration against a tolerance profile: its parameters, then its residuals.

    Parameters
    ----------
    cal : the solved calibration.
    profile : the tolerance profile (`pipelines.load_profile` reads a shipped or lab one).
    budgets : name -> GUM budget: the parameters are judged by the profile's decision rule
        with their expanded uncertainty (`check_parameters`).

    Returns
    -------
    list of CheckResult: ``param:<name>`` (`check_parameters`) then
    ``residual:<segment>:<sensor>:<std|mean>`` (`check_residuals`), then the
    procedure's own (`solver_checks`, e.g. ``zero_shift:<position>:<axis>``, or
    ``model:...`` for what the run could not determine). `overall_verdict` turns them
    into "pass" / "needs review" / "fail". The archive's check step adds held-out
    verification points, repeatability and the unit's description to these.
    """
    return (
        check_parameters(cal, profile, budgets) + check_residuals(cal, profile) + solver_checks(cal)
    )


def solver_checks(cal: Calibration) -> list[CheckResult]:
    """Checks a procedure made itself (``cal.info["solver_checks"]``), e.g. the
    centrifuge's zero output before and after each position's run, and the
    ``model:`` checks: degrees of freedom, sensitivity to the static detector,
    the face-pair bias spread."""
    return [CheckResult(**c) for c in cal.info.get("solver_checks", [])]


def overall_verdict(checks: list[CheckResult]) -> str:
    """The run's verdict from its list of checks.

    Parameters
    ----------
    checks : CheckResult list, e.g. from `check_calibration`.

    Returns
    -------
    "pass" if every check passed; "needs review" when only repeatability
    (``repeat:``), device (``device:``), model (``model:``) or record (``record:``)
    checks failed: the numbers are within tolerance but do not repeat, belong to another
    unit, were not determined by the run, or come from a record with a finding (the unit's
    verdict is its parameters', the record's findings are named for a person to look); or
    parameters inside their tolerance but within the guard band of a limit (ILAC-G8
    conditional pass); else "fail". A lab condition that is only a warning or was not
    recorded (calib_core.conditions) leaves the verdict as it is.
    """
    failed = [c for c in checks if counts_against_verdict(c)]
    if not failed:
        return PASS
    if all(
        c.name.startswith((REPEAT_PREFIX, DEVICE_PREFIX, MODEL_PREFIX, RECORD_PREFIX))
        or _conditional_pass(c)
        for c in failed
    ):
        return NEEDS_REVIEW
    return FAIL


verdict = overall_verdict  # deprecated alias (public API `calib_core.verdict`): use overall_verdict


def _conditional_pass(c: CheckResult) -> bool:
    """A parameter check inside its tolerance but within the guard band of a limit."""
    return c.name.startswith("param:") and f"; {decision.COND_PASS} (" in c.detail
