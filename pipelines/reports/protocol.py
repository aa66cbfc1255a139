"""The test protocol `<serial>_result.txt` in the MPU-6000 paper's layout.

Header with device type, serial, date and time; each parameter on its own line
with its tolerance and `+` when within, `-` when not; then the residual checks,
the verdict and signature lines for customer representative, quality control
and production.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from datetime import datetime
from typing import Any

from pipelines.reports.display import display, tolerance

_RULE = "-" * 78


def _fmt(value: float | None, width: int = 12, signed: bool = True) -> str:
    """A value right-aligned in `width`, 6 decimals; with its sign when `signed` (a
    parameter value), without for an uncertainty (never negative: no ``+``)."""
    if value is None:
        return f"{'':>{width}}"
    return f"{value:>+{width}.6f}" if signed else f"{value:>{width}.6f}"


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
    parameters: Iterable[Mapping[str, Any]],
    checks: Iterable[Mapping[str, Any]],
    verdict: str,
) -> str:
    """Render the protocol text.

    Parameters
    ----------
    parameters : dicts with name, value, std (SI units, canonical names).
    checks : dicts with name, value, limit, passed (``param:<name>`` checks
        give each parameter's tolerance; others are listed after the table).
    """
    checks = list(checks)
    by_param = {
        c["name"].removeprefix("param:"): c for c in checks if c["name"].startswith("param:")
    }
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
        _RULE,
        f"{'Parameter':<18}{'Value':>13}{'Std. unc.':>13}  {'Unit':<10}{'Tolerance':>12}  Result",
    ]
    for p in parameters:
        value, unit = display(p["name"], p["value"])
        std, _ = display(p["name"], p.get("std"))
        check = by_param.get(p["name"])
        tol = tolerance(p["name"], check)
        if tol is None:
            tol, mark = f"{'':>12}", " "
        else:
            tol, mark = f"{tol[0]:>3}{tol[1]:>9.4g}", "+" if check["passed"] else "-"
        u = _fmt(std, 13, signed=False)
        lines.append(f"{p['name']:<18}{_fmt(value, 13)}{u}  {unit:<10}{tol}  {mark}")
    other = [c for c in checks if not c["name"].startswith("param:")]
    if other:
        lines += [_RULE, "Checks", f"{'Check':<44}{'Value':>13}{'Limit':>13}  Result"]
        for c in other:
            limit = "" if c.get("limit") is None else f"{c['limit']:.4g}"
            value = "" if c.get("value") is None else f"{c['value']:.4g}"
            lines.append(f"{c['name']:<44}{value:>13}{limit:>13}  {'+' if c['passed'] else '-'}")
    lines += [
        _RULE,
        f"Overall result: {verdict.upper()}",
        "",
        "Customer representative: ______________________   Date: __________",
        "Quality control:         ______________________   Date: __________",
        "Production:              ______________________   Date: __________",
        "",
    ]
    return "\n".join(lines)
