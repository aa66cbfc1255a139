"""Samples a step replaced, dropped or down-weighted: counts, and what false alarms explain.

Every detector that alters samples (outlier removal on statics, the rotation despiker,
clipping, interpolation) has a false-alarm rate: the fraction of clean samples it flags
on noise alone. Over n tested samples the flagged count of clean data is binomial
(n, p); a count above its (1 - alpha) quantile is more than the method's false alarms
explain: the record has real spikes or glitches, or the detector mistook the signal
for them. Either way a person must look: the run says so in a ``model:`` check, which
leaves the verdict at "needs review" (calib_core.checks).
"""

from __future__ import annotations

from collections.abc import Mapping

from calib_core.check_names import REPLACED_PREFIX
from calib_core.distributions import binom_isf

# Significance of "more than false alarms explain": one run in a thousand of clean data
# is sent for review by chance.
REPLACED_ALPHA = 1e-3
CHECK_PREFIX = REPLACED_PREFIX


def explained_count(n_tests: int, p_false_alarm: float, alpha: float = REPLACED_ALPHA) -> int:
    """The largest flagged count that false alarms alone explain at significance alpha.

    Parameters
    ----------
    n_tests : samples tested (all channels together).
    p_false_alarm : probability that one clean sample is flagged.
    alpha : probability that clean data flag more than the returned count.

    Returns
    -------
    The (1 - alpha) quantile of Binomial(n_tests, p_false_alarm); 0 when nothing was
    tested.
    """
    if n_tests <= 0 or p_false_alarm <= 0.0:
        return 0
    return binom_isf(alpha, int(n_tests), min(float(p_false_alarm), 1.0))


def replaced_check(
    step: str,
    segment: str,
    counts: Mapping[str, int],
    n_tests: int,
    p_false_alarm: float,
    what: str = "replaced",
) -> dict:
    """The ``model:replaced:<step>:<segment>`` check of one segment's altered samples.

    Parameters
    ----------
    step : the step that altered them ("despike", "outliers", ...).
    segment : segment label.
    counts : channel ("gyr.x", ...) -> samples altered.
    n_tests : samples tested, all channels together.
    p_false_alarm : the detector's false-alarm probability per tested sample.
    what : the verb for the detail ("replaced", "deleted", "interpolated").

    Returns
    -------
    A check dict (CheckResult fields) for ``cal.info["solver_checks"]``: value the total
    count, limit the count false alarms explain; passed when within it.
    """
    total = int(sum(counts.values()))
    limit = explained_count(n_tests, p_false_alarm)
    per_channel = ", ".join(f"{k} {v}" for k, v in counts.items() if v)
    detail = (
        f"{step} {what} {total} of {n_tests} samples ({per_channel or 'none'}); its false "
        f"alarms (p = {p_false_alarm:.2g} per sample) explain at most {limit} "
        f"(alpha {REPLACED_ALPHA:g})"
    )
    if total > limit:
        detail += ": look at the record (glitches, or motion taken for spikes)"
    return {
        "name": f"{CHECK_PREFIX}{step}:{segment}",
        "value": float(total),
        "limit": float(limit),
        "passed": total <= limit,
        "detail": detail,
    }
