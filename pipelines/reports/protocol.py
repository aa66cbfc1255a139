"""The test protocol `<serial>_result.txt` in the MPU-6000 paper's layout.

Header with device type, serial, date and time; each parameter on its own line
with its tolerance and `+` when within, `-` when not; then the lab conditions (one
verdict line each: +, -, warning or not recorded), the residual checks,
the verdict and signature lines for customer representative, quality control
and production.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from datetime import datetime
from typing import TYPE_CHECKING, Any

from calib_core import conditions
from calib_core.params import manual_name, manual_order
from pipelines.reports.display import (
    STANDARD_U,
    STANDARD_U_MEANING,
    check_counts,
    expanded_u,
    limit_text,
    number,
    shown,
    tolerance,
)

if TYPE_CHECKING:
    from calib_core.calibration import CheckResult, Parameter
    from storage.queries.records import ParameterValue

_RULE = "-" * 78


# The result column of a condition line: the manual's + and -, or what else it is.
RESULT_MARK = {
    "pass": "+",
    "fail": "-",
    conditions.WARNING: "warning",
    conditions.NOT_RECORDED: "not recorded",
    conditions.INFO: "info",
}


def condition_lines(checks: Iterable[CheckResult]) -> list[str]:
    """The "Conditions" block: one verdict line per lab condition / acquisition rule."""
    rows = [c for c in checks if c.name.startswith(conditions.CONDITION_PREFIX)]
    if not rows:
        return []
    lines = [_RULE, "Conditions", f"{'Condition':<30}{'Value':>12}  {'Result':<13}Requirement"]
    for c in rows:
        value = "" if c.value is None else number(c.value)
        mark = RESULT_MARK[conditions.status(c)]
        name = c.name.removeprefix(conditions.CONDITION_PREFIX)
        lines.append(f"{name:<30}{value:>12}  {mark:<13}{conditions.requirement(c)}")
    return lines


def render_protocol(
    *,
    device_model: str,
    serial: str,
    started_at: datetime,
    run_id: str,
    procedure: str,
    profile: str,
    gravity: float,
    operator: str,
    parameters: Iterable[Parameter | ParameterValue],
    checks: Iterable[CheckResult],
    verdict: str,
    budgets: Mapping[str, Mapping[str, Any]] | None = None,
    decision_rule: str | None = None,
    names: str = "canonical",
    notes: Iterable[tuple[str, str]] = (),
) -> str:
    """Render the protocol text.

    Parameters
    ----------
    parameters : name, value, std of each (SI units, canonical names).
    checks : the calibration's checks (``param:<name>`` checks
        give each parameter's tolerance; others are listed after the table).
    budgets : name -> `calib_core.uncertainty.Budget.to_dict()` (SI): the uncertainty table.
    decision_rule : the statement of the decision rule and its risk.
    names : "canonical", or "manual": each line also gives the MPU-6000 manual's name
        and the value in the manual's sign (calib_core.params.MANUAL_NAMES), the lines in
        the order of the manual's published protocol (gyro block first), so a lab
        compares line by line with its old protocols.
    notes : (name, text) of the findings about the record, the counts of samples
        replaced and the solve's warnings (`pipelines.reports.display.record_notes`),
        listed beside the verdict.
    """
    checks = list(checks)
    by_param = param_checks(checks)
    lines = [
        "IMU CALIBRATION TEST PROTOCOL",
        _RULE,
        f"Device type : {device_model}",
        f"Serial      : {serial}",
        f"Date / time : {started_at:%Y-%m-%d %H:%M:%S %Z}",
        f"Operator    : {operator}",
        f"Run         : {run_id}    Procedure: {procedure}",
        f"Profile     : {profile}    Gravity used: {gravity:.6f} m/s^2",
        "Convention  : f_meas = (I + M) f_true + b; misalign.rc = M[r, c]",
        f"Values      : in display units; {STANDARD_U_MEANING}",
        _RULE,
        f"{'Parameter':<18}{'Value':>13}{STANDARD_U:>13}  {'Unit':<10}{'Tolerance':>12}  Result"
        + (f"  {'Manual':<7}{'Value':>13}" if names == "manual" else ""),
    ]
    if names == "manual":
        lines.insert(-2, "Manual names: the MPU-6000 manual's (Axz = M[x,y], Axy = -M[x,z], ...)")
    if names == "manual":
        parameters = sorted(parameters, key=lambda p: manual_order(p.name))
    for p in parameters:
        s = shown(p.name, p.value, p.std)  # u to two digits, the value to its place
        check = by_param.get(p.name)
        tol = tolerance(p.name, check)
        if tol is None:
            tol, mark = f"{'':>12}", " "
        else:
            tol, mark = f"{tol[0]:>3}{limit_text(tol[1]):>9}", "+" if check.passed else "-"
        line = f"{p.name:<18}{s.signed:>13}{s.u:>13}  {s.unit:<10}{tol}  {mark}"
        if names == "manual":
            manual, signed = manual_name(p.name, p.value)
            in_sign = shown(p.name, signed, p.std).signed
            line += f"       {manual:<7}{in_sign:>13}" if manual else ""
        lines.append(line)
    lines += uncertainty_lines(budgets or {}, by_param, decision_rule)
    lines += condition_lines(checks)
    other = [c for c in checks if not c.name.startswith(("param:", conditions.CONDITION_PREFIX))]
    if other:
        lines += [_RULE, "Checks", f"{'Check':<44}{'Value':>13}{'Limit':>13}  Result"]
        for c in other:
            limit = "" if c.limit is None else limit_text(c.limit)
            value = "" if c.value is None else number(c.value)
            lines.append(f"{c.name:<44}{value:>13}{limit:>13}  {'+' if c.passed else '-'}")
    notes = list(notes)
    if notes:
        lines += [_RULE, "The record: findings, samples replaced, solver warnings"]
        lines += [f"{name}: {text}" for name, text in notes]
    lines += [
        _RULE,
        f"Checks: {check_counts(checks).sentence()}",
        f"Overall result: {verdict.upper()}",
        "",
        "Customer representative: ______________________   Date: __________",
        "Quality control:         ______________________   Date: __________",
        "Production:              ______________________   Date: __________",
        "",
    ]
    return "\n".join(lines)


def param_checks(checks: Iterable[CheckResult]) -> dict[str, CheckResult]:
    """The parameter checks (``param:<name>``) by parameter name."""
    return {c.name.removeprefix("param:"): c for c in checks if c.name.startswith("param:")}


def verdict_of(check: CheckResult | None) -> str:
    """The ILAC-G8 verdict a parameter check's detail states ("" without one)."""
    detail = "" if check is None else check.detail or ""
    _, sep, rest = detail.partition("; ")
    return rest.split(" (", 1)[0] if sep else ""


def guard_band_of(check: CheckResult | None) -> str:
    """The guard band "w = ..." a parameter check's detail states ("" without one)."""
    detail = "" if check is None else check.detail or ""
    _, sep, rest = detail.rpartition(", w = ")
    return rest.rstrip(")") if sep else ""


def dominant_text(budget: Mapping[str, Any], n: int = 2) -> str:
    """The `n` largest contributions as "source 61 %" (share of u_c^2)."""
    uc2 = budget["uc"] ** 2
    if uc2 == 0:
        return ""
    # Shares below 1 % say nothing on a certificate.
    rows = sorted(
        (r for r in budget["rows"] if r["contribution"] ** 2 >= 0.01 * uc2),
        key=lambda r: -r["contribution"],
    )[:n]
    return ", ".join(f"{r['source']} {100 * r['contribution'] ** 2 / uc2:.0f} %" for r in rows)


def uncertainty_lines(
    budgets: Mapping[str, Mapping[str, Any]],
    by_param: Mapping[str, CheckResult],
    decision_rule: str | None,
) -> list[str]:
    """The uncertainty table (value, U, k, coverage, verdict, dominant contributions)."""
    if not budgets:
        return []
    lines = [
        _RULE,
        "Measurement uncertainty (GUM): expanded uncertainty U = k u_c",
        f"{'Parameter':<18}{'Value':>13}{'U':>11}  {'Unit':<10}{'k':>5}{'p':>6}  "
        f"{'Verdict':<17}Dominant contributions",
    ]
    ks = {round(b["k"], 2) for b in budgets.values()}
    if len(ks) == 1:  # one coverage factor: say it as every other table does
        lines[-1] = lines[-1].replace(f"{'U':>11}", f"{expanded_u(ks.pop()):>11}", 1)
    for name in sorted(budgets):
        b = budgets[name]
        s = shown(name, b["value"], b["U"])  # U to two digits, the value to its place
        lines.append(
            f"{name:<18}{s.signed:>13}{s.u:>11}  {s.unit:<10}{b['k']:>5.2f}"
            f"{b['coverage']:>6.0%}  {verdict_of(by_param.get(name)):<17}"
            f"{dominant_text(b)}"
        )
    labels = sorted({b["label"] for b in budgets.values()})
    lines.append("Budget: " + "; ".join(labels))
    if decision_rule:
        lines.append(decision_rule)
    return lines
