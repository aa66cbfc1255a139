"""The certificate's recommendations: whether to release the unit, when to recalibrate it
(its interval from pipelines.recall, docs/interval.md, or the default months), what the
residuals advise and the temperature range the calibration holds for.
"""

from __future__ import annotations

from typing import Any

from calib_core.calibration import Calibration
from calib_core.verification import NEEDS_REVIEW, PASS, ResidualDiagnosis

RECALIBRATION_MONTHS = 12  # default interval for a passed MEMS unit (lab practice)


def recommendations(
    verdict: str,
    cal: Calibration,
    diagnosis: ResidualDiagnosis | None,
    env: dict[str, Any],
    recall: dict[str, Any] | None = None,
) -> list[str]:
    """The certificate's recommendations: release or not by the verdict (with the
    recalibration interval of a released unit, `interval_text`), the residual diagnosis's
    advice when it failed, and the temperature range the calibration holds for."""
    out = []
    if verdict == PASS:
        out.append(
            f"Release the unit with this calibration; recalibrate within {interval_text(recall)}, "
            "or earlier after a shock, a repair or a drift seen in use."
        )
    elif verdict == NEEDS_REVIEW:
        out.append(
            "The unit's parameters are within tolerance, but the record has findings (see "
            "the verdict: a log cut while written, samples replaced beyond false alarms, a "
            "threshold raised) or the result does not repeat against earlier runs or was not "
            "determined by the run: a quality engineer decides; repeat the calibration under "
            "controlled conditions if in doubt."
        )
    else:
        out.append("Do not release the unit with this calibration; act on the failed checks.")
    if diagnosis is not None and not diagnosis.passed:
        out += diagnosis.advice
    if cal.info.get("thermal"):
        out.append("Apply the archived temperature compensation model in use.")
    else:
        temp = env.get("temperature_c")
        at = f" at {temp} deg C" if temp is not None else ""
        out.append(
            f"Calibrated{at} only: for use over a wide temperature range run a thermal "
            "campaign (e.g. -10, 0, 20, 40, 60 deg C) and apply temperature compensation."
        )
    return out


def interval_text(recall: dict[str, Any] | None) -> str:
    """The recalibration interval in words: the unit's own (pipelines.recall, docs/interval.md)
    with its method, or the default months."""
    if recall is None:
        return f"{RECALIBRATION_MONTHS} months"
    why = recall["method"]
    if recall.get("limiting_parameter") and why.startswith("variables"):
        why = (
            f"from this unit's and its model's measured drift, variables-data method "
            f"(NCSL RP-1 / ILAC-G24): probability {recall['reliability']:.0%} of "
            f"{recall['limiting_parameter']} being in tolerance at its end"
            + (", capped" if recall.get("capped") else "")
        )
    return f"{duration_text(recall)}, by {recall['due']} ({why})"


def duration_text(recall: dict[str, Any]) -> str:
    """An interval of pipelines.recall in words: months, or days under a month (a unit
    that drifts fast: "9 days", never "0 months")."""
    from pipelines.recall import DAYS_PER_MONTH

    months, days = recall["interval_months"], recall["interval_days"]
    if days >= round(DAYS_PER_MONTH, 1):  # as interval_days is rounded (0.1 day)
        return f"{months:g} month" + ("" if months == 1 else "s")
    if days >= 1:
        n = round(days)
        return f"{n} day" + ("" if n == 1 else "s")
    return f"{days:g} days"  # under a day (0 when due now)
