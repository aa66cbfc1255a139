"""As found: a unit's earlier calibration evaluated on a new run's data (ISO/IEC 17025 7.8.4.2).

When a unit comes back, its earlier parameters are what is loaded in it. The new run's raw
samples are corrected with them (`Calibration.apply`, the same correction `calib apply`
makes) and the same procedure solves the error model again on the corrected samples: what it
finds is the error the unit showed as found, parameter by parameter, with the fit's
standard uncertainty. With the error model ``f_meas = (I + M) f + b`` the corrected samples
follow ``(I + M_found) f + b_found`` with ``I + M_found = (I + M_old)^-1 (I + M_new)`` and
``b_found = (I + M_old)^-1 (b_new - b_old)``: to first order the drift ``new - old``, exactly
the error the earlier parameters leave.

Uncertainty: the earlier parameters are exact constants here (they are what the unit holds,
not estimates under test), so the as-found error is a measurement on this run's data by this
run's procedure: its sensitivity to every input of the budget equals that of the as-left
value to first order (the correction differs from the identity by ``|M_old|``, about 1e-2),
and its expanded uncertainty is taken as the as-left U of the same parameter. It is judged
against the tolerance with the profile's decision rule like the as-left value.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from calib_core import procedures
from calib_core.calibration import Calibration
from calib_core.recording import Recording
from calib_core.tolerances import ToleranceProfile
from calib_core.uncertainty import Budget


@dataclass(frozen=True)
class AsFound:
    """One parameter as found and as left, SI units.

    Attributes
    ----------
    parameter : canonical name.
    earlier : the earlier calibration's value (0 when it did not have the parameter).
    as_left : this run's value.
    error : the error as found, solved on this run's data corrected with the earlier values.
    std : standard uncertainty of `error` from the fit (Type A).
    U : expanded uncertainty of `error` (the as-left U, module docstring); None without budget.
    k : coverage factor of U; None without budget.
    verdict : ILAC-G8 verdict of `error` against the tolerance; None when no limit applies.
    """

    parameter: str
    earlier: float
    as_left: float
    error: float
    std: float | None
    U: float | None
    k: float | None
    verdict: str | None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def evaluate(
    earlier: Calibration,
    segments: Mapping[str, Recording],
    procedure: str,
    gravity: float,
    settings: Mapping[str, Any],
) -> Calibration:
    """The error model of the unit as found: solved on `segments` corrected with `earlier`.

    Parameters
    ----------
    earlier : the calibration loaded in the unit before this run.
    segments : label -> Recording of this run's fit segments (preprocessed, SI, raw values).
    procedure, gravity, settings : this run's procedure, local gravity (m/s^2) and solver
        settings, so the as-found error is found by the same procedure as the as-left values.

    Raises
    ------
    ValueError as `calib_core.procedures.solve` does.
    """
    corrected = {label: earlier.apply(rec) for label, rec in segments.items()}
    return procedures.solve(procedure, corrected, gravity, dict(settings))


def judge(
    found: Calibration,
    earlier: Calibration,
    as_left: Calibration,
    budgets: Mapping[str, Budget],
    profile: ToleranceProfile | None,
) -> list[AsFound]:
    """Every error parameter as found beside its as-left value, judged against the tolerance.

    Noise parameters are left out: their re-solved value is this run's noise again, not an
    error the earlier calibration left.
    """
    out = []
    for name, p in sorted(found.parameters.items()):
        if ".noise." in name or name not in as_left.parameters:
            continue
        b = budgets.get(name)
        U, k = (None, None) if b is None else (float(b.U), float(b.k))
        verdict = None if profile is None else profile.judge(name, p.value, U or 0.0)
        out.append(
            AsFound(name, earlier.value(name), as_left.value(name), p.value, p.std, U, k, verdict)
        )
    return out
