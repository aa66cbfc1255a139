"""Is the calibration believable? Residual diagnosis, accuracy on held-out points, repeatability.

Three questions a lab asks before it accepts a solver's numbers (docs/methods.md 3.6-3.8):

1. Do the residuals (measured - model) stay within the profile's limits at
   every segment? When not, which segments are worst and what to try. At the
   six static up/down positions the residual means carry a signature: a
   component that flips sign between "axis c up" and "axis c down" is a linear
   term in f_c the model lacks (scale, cross-coupling, g-sensitivity); one that
   keeps its sign is an even (quadratic) term.
2. Does the compensated output match the reference at points NOT used in the
   fit (accel <= 0.01 g, rate <= 0.5 deg/s by default)?
3. Do three or more runs of the same unit under the same conditions agree?
   Scale factors: coefficient of variation of K = 1 + scale <= 1 %. Parameters
   near zero (biases, misalignments, g-sensitivity, noise levels), where a CV
   is meaningless: the run-to-run scatter against the reported uncertainties
   (a chi-squared test, family-wise false-alarm rate `alpha`).

The overall verdict (`calib_core.checks.overall_verdict`) is "pass", "fail" (a
parameter, residual or verification check failed) or "needs review" (only
repeatability failed: the unit is within tolerance but does not repeat, a person
decides).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from calib_core import params
from calib_core.calibration import Calibration, CheckResult
from calib_core.checks import (  # noqa: F401  (the verdict's names, re-exported)
    DEVICE_PREFIX,
    FAIL,
    MODEL_PREFIX,
    NEEDS_REVIEW,
    PASS,
    REPEAT_PREFIX,
)
from calib_core.distributions import chi2_ppf
from calib_core.drift import shared_covariance
from calib_core.recording import Recording
from calib_core.solvers.rate_table import rate_point
from calib_core.tolerances import ToleranceProfile

VERIFY_PREFIX = "verify:"

# A residual-pattern component counts as a suspected missing term above this
# fraction of the residual-mean limit: half the allowance is far above the
# noise of a mean (std / sqrt(n), ~1e-3 of the limit for a 20 s position) and
# low enough to name a term that is only part of why a segment failed.
SUSPECT_FRACTION = 0.5
# Parameter families judged by a coefficient of variation (as K = 1 + value).
CV_FAMILIES = ("acc.scale", "gyr.scale")


# --- 1. residual diagnosis ------------------------------------------------------------


@dataclass(frozen=True)
class WorstSegment:
    """One residual statistic of one segment against its limit (ratio > 1 fails)."""

    segment: str
    sensor: str  # "acc" or "gyr"
    stat: str  # "std" or "mean" (|mean|)
    axis: str
    value: float  # SI
    limit: float  # SI
    ratio: float


@dataclass(frozen=True)
class SuspectTerm:
    """A model term the residual pattern points at.

    term : canonical parameter name where one exists (``acc.misalign.xy``),
        else a description (``acc.x ~ f_y^2``).
    estimate : the term's value that would explain the pattern (SI unit of the term).
    in_model : whether the calibration already has this parameter.
    """

    term: str
    estimate: float
    unit: str
    in_model: bool
    kind: str  # "linear" or "quadratic"


@dataclass
class ResidualDiagnosis:
    """What the residuals say: pass/fail, worst segments, suspected terms, advice."""

    passed: bool
    worst: list[WorstSegment] = field(default_factory=list)
    suspects: list[SuspectTerm] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "passed": self.passed,
            "worst": [asdict(w) for w in self.worst],
            "suspects": [asdict(s) for s in self.suspects],
            "advice": list(self.advice),
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> ResidualDiagnosis:
        return cls(
            passed=bool(doc["passed"]),
            worst=[WorstSegment(**w) for w in doc.get("worst", [])],
            suspects=[SuspectTerm(**s) for s in doc.get("suspects", [])],
            advice=list(doc.get("advice", [])),
        )


def _ranked_statistics(cal: Calibration, profile: ToleranceProfile) -> list[WorstSegment]:
    """Every (segment, sensor, std / |mean|) at its worst axis, largest ratio to the limit first."""
    out = []
    for r in cal.residuals:
        for stat, values in (("std", np.asarray(r.std)), ("mean", np.abs(r.mean))):
            limit = profile.residual_limits.get(f"{r.sensor}_{stat}")
            if limit is None:
                continue
            i = int(np.argmax(values))
            out.append(
                WorstSegment(
                    r.segment,
                    r.sensor,
                    stat,
                    params.AXES[i],
                    float(values[i]),
                    limit,
                    float(values[i] / limit),
                )
            )
    return sorted(out, key=lambda w: -w.ratio)


def _pattern_terms(cal: Calibration, sensor: str, limit: float) -> list[SuspectTerm]:
    """Missing terms read from the static residual means (needs all six up/down positions).

    For output axis r and input axis c, with R the residual mean at "c up" / "c down":
    odd = (R_r(c up) - R_r(c down)) / 2 is linear in f_c, so odd / g estimates the
    missing M[r, c] (or G[r, c] for the gyro). even = (R_r(c up) + R_r(c down)) / 2
    is even in f_c; the fitted bias takes out their common level, so the median
    over c is removed first and even / g^2 estimates a quadratic coefficient.
    """
    means = {r.segment: np.asarray(r.mean) for r in cal.residuals if r.sensor == sensor}
    labels = [f"{c}_{s}" for c in params.AXES for s in ("up", "dn")]
    if not all(label in means for label in labels):
        return []
    g = cal.gravity
    up = np.array([means[f"{c}_up"] for c in params.AXES])  # (c, r)
    dn = np.array([means[f"{c}_dn"] for c in params.AXES])
    odd = (up - dn).T / 2.0  # (r, c)
    even = (up + dn).T / 2.0
    even = even - np.median(even, axis=1, keepdims=True)
    out = []
    for ri, r in enumerate(params.AXES):
        for ci, c in enumerate(params.AXES):
            if abs(odd[ri, ci]) > SUSPECT_FRACTION * limit:
                if sensor == "gyr":
                    name = f"gyr.gsens.{r}{c}"
                else:
                    name = f"acc.scale.{r}" if r == c else f"acc.misalign.{r}{c}"
                out.append(
                    SuspectTerm(
                        name,
                        float(odd[ri, ci] / g),
                        params.unit_of(name),
                        name in cal.parameters,
                        "linear",
                    )
                )
            if abs(even[ri, ci]) > SUSPECT_FRACTION * limit:
                name = f"acc.k2.{r}" if sensor == "acc" and r == c else f"{sensor}.{r} ~ f_{c}^2"
                canonical = name.startswith("acc.k2.")
                unit = (
                    params.unit_of(name)
                    if canonical
                    else f"({params.UNITS[sensor + '.bias']})/(m/s^2)^2"
                )
                out.append(
                    SuspectTerm(
                        name, float(even[ri, ci] / g**2), unit, name in cal.parameters, "quadratic"
                    )
                )
    return sorted(out, key=lambda s: -abs(s.estimate))


def diagnose_residuals(
    cal: Calibration, profile: ToleranceProfile, n_worst: int = 3
) -> ResidualDiagnosis:
    """Residuals against the profile's limits, the worst segments and what to try.

    Parameters
    ----------
    cal : a solved calibration with per-segment residuals.
    profile : its residual limits are used (SI).
    n_worst : how many of the worst segment statistics to keep.

    Returns
    -------
    ResidualDiagnosis; `advice` is a list of sentences for the report.
    """
    ranked = _ranked_statistics(cal, profile)
    failed = [w for w in ranked if w.ratio > 1.0]
    suspects = []
    for sensor in ("acc", "gyr"):
        limit = profile.residual_limits.get(f"{sensor}_mean")
        if limit is not None:
            suspects += _pattern_terms(cal, sensor, limit)
    return ResidualDiagnosis(not failed, ranked[:n_worst], suspects, _advice(suspects, failed))


# What a pattern of the residuals suggests, "{}" standing for the terms or segments.
_MISSING_LINEAR = (
    "The residual means flip sign between up and down positions as cross-coupling "
    "terms the model lacks would make them: {}. Solve with the full linear "
    'model (12 parameters, cross-coupling included; accel_model = "linear").'
)
_QUADRATIC = (
    "The residual means keep their sign between up and down positions, as an even "
    "(quadratic) term would: {}. Add nonlinear terms (k2, k3) and tilted "
    "positions (12/18/24-position scheme or tumble) that separate them from the bias."
)
_NOISY = (
    "Residual scatter above the limit at {}: check the data "
    "(vibration, settle time, outliers, temperature drift) and repeat those segments."
)
_BIASED = (
    "Residual mean above the limit at {} without a model-term "
    "pattern: check those segments (wrong label, fixture not level, position moved) "
    "or add more positions."
)


def _advice(suspects: list[SuspectTerm], failed: list[WorstSegment]) -> list[str]:
    """The report's sentences: suspected terms first, then the segments to look at."""
    linear = ", ".join(
        f"{s.term} ~ {s.estimate:.4g}" for s in suspects if s.kind == "linear" and not s.in_model
    )
    quadratic = ", ".join(
        f"{s.term} ~ {s.estimate:.3g} {s.unit}" for s in suspects if s.kind == "quadratic"
    )
    noisy = ", ".join(sorted({w.segment for w in failed if w.stat == "std"}))
    biased = ", ".join(sorted({w.segment for w in failed if w.stat == "mean"}))
    found = [(linear, _MISSING_LINEAR), (quadratic, _QUADRATIC), (noisy, _NOISY)]
    found.append(("" if linear or quadratic else biased, _BIASED))
    advice = [text.format(items) for items, text in found if items]
    if not failed:
        advice.append("Residuals are within the limits at every segment.")
    return advice


# --- 2. accuracy verification on held-out points ----------------------------------------


@dataclass(frozen=True)
class ReferencePoint:
    """The truth at a verification segment.

    acc : (3,) true specific force, m/s^2, or None (not verified).
    gyr : (3,) true angular rate, rad/s, or None (zero at a static position; the table's
        commanded rate on its axis at a rate plateau).
    window : (start, end) time window of the segment compared, s; None: the whole segment
        (a rate plateau is compared over its record window, after the table settled).
    """

    label: str
    acc: np.ndarray | None
    gyr: np.ndarray | None
    window: tuple[float, float] | None = None


def reference_point(label: str, gravity: float, acc: np.ndarray | None = None) -> ReferencePoint:
    """Reference of a static verification segment: specific force and zero rate.

    Parameters
    ----------
    label : segment label; "<axis>_up" / "<axis>_dn" (optionally followed by
        "_<anything>", e.g. "x_up_2" for a repeated position) give the force.
    gravity : local gravity, m/s^2.
    acc : (3,) reference specific force, m/s^2, for other attitudes (tilts).

    Raises
    ------
    ValueError naming the label when neither gives a reference.
    """
    if acc is None:
        parts = label.split("_")
        if len(parts) < 2 or parts[0] not in params.AXES or parts[1] not in ("up", "dn"):
            raise ValueError(
                f"verification segment {label!r}: no reference specific force; give "
                "reference_acc in the manifest or use a label like 'x_up_2'"
            )
        acc = np.zeros(3)
        acc[params.AXIS_INDEX[parts[0]]] = gravity if parts[1] == "up" else -gravity
    acc = np.asarray(acc, dtype=float)
    if acc.shape != (3,) or not np.all(np.isfinite(acc)):
        raise ValueError(f"verification segment {label!r}: reference_acc must be 3 finite numbers")
    return ReferencePoint(label, acc, np.zeros(3))


def rate_reference(
    rec: Recording, *, settle_s: float = 20.0, record_s: float | None = None
) -> ReferencePoint:
    """Reference of a held-out rate plateau: the table's rate (its feedback's mean over the
    record window after `settle_s`, s) about the plateau's axis, no accelerometer reference
    (the table's tilt is not stated). `rec` has ``reference["table_rate"]`` (rad/s) and a
    label "<axis>_<rate>" (`calib_core.solvers.rate_table.rate_point`)."""
    point = rate_point(rec, settle_s=settle_s, record_s=record_s)
    gyr = np.zeros(3)
    gyr[params.AXIS_INDEX[point.axis]] = point.table_rate
    start = float(rec.t[0]) + settle_s
    end = np.inf if record_s is None else start + record_s
    return ReferencePoint(str(rec.label), None, gyr, (start, float(end)))


def verify_points(
    cal: Calibration,
    segments: dict[str, Recording],
    references: list[ReferencePoint],
    profile: ToleranceProfile,
) -> list[CheckResult]:
    """Compensated output against the reference at each held-out segment.

    The error is the Euclidean norm of (mean compensated output - reference)
    over the segment as recorded (no outlier removal: the whole chain is
    verified), or over the reference's window (a rate plateau after its settle).

    Returns
    -------
    CheckResult "verify:<label>:acc" (m/s^2) and "verify:<label>:gyr" (rad/s)
    against profile.verification_limits.
    """
    out = []
    for ref in references:
        rec = segments[ref.label]
        if ref.window is not None:
            rec = rec.window(*ref.window)
        acc, gyr = cal.correct(rec.acc, rec.gyr)
        for sensor, data, truth in (("acc", acc, ref.acc), ("gyr", gyr, ref.gyr)):
            if truth is None:
                continue
            err = data.mean(axis=0) - truth
            value = float(np.linalg.norm(err))
            limit = profile.verification_limits[sensor]
            unit = params.UNITS[f"{sensor}.bias"]
            detail = f"error x y z = {err[0]:+.4g} {err[1]:+.4g} {err[2]:+.4g} {unit}, "
            out.append(
                CheckResult.at_most(
                    f"{VERIFY_PREFIX}{ref.label}:{sensor}", value, limit, f"{detail}n={len(rec)}"
                )
            )
    return out


# --- 3. repeatability ------------------------------------------------------------------


@dataclass(frozen=True)
class RunValues:
    """One run's parameters for a repeatability group.

    values : canonical name -> (value, standard uncertainty or None), SI; the
        uncertainty is the run's own (Type A).
    shared : canonical name -> (identity of the reference the run used, or None; the
        reference's Type B standard uncertainty in the value, SI). Runs on the same
        reference share that error (`calib_core.drift.shared_covariance`); without an
        entry the values are judged on their own uncertainties alone.
    """

    run_id: str
    temperature_c: float | None
    values: dict[str, tuple[float, float | None]]
    shared: dict[str, tuple[str | None, float]] = field(default_factory=dict)


def comparable_runs(
    current: RunValues, others: list[RunValues], temperature_tol_c: float, max_runs: int
) -> list[RunValues]:
    """The group of `current` and the `others` taken under the same conditions.

    `others` must already share the serial and procedure and come most recent
    first. Same conditions: lab temperatures within `temperature_tol_c` of the
    current run's, or both unknown. At most `max_runs` runs, the current first.
    """
    group = [current]
    for run in others:
        if len(group) >= max_runs:
            break
        if run.run_id == current.run_id:
            continue
        t0, t1 = current.temperature_c, run.temperature_c
        same = (t0 is None and t1 is None) or (
            t0 is not None and t1 is not None and abs(t0 - t1) <= temperature_tol_c
        )
        if same:
            group.append(run)
    return group


def _scatter_chi2(x: np.ndarray, u: np.ndarray, shared: list) -> float:
    """r^T V^-1 r about the generalised least-squares mean; V = diag(u^2) unless every run
    names its shared reference (then `shared_covariance`)."""
    if all(s is not None for s in shared):
        V = shared_covariance(u, [s[1] for s in shared], [s[0] for s in shared])
    else:
        V = np.diag(u**2)
    Vi = np.linalg.inv(V)
    r = x - float(np.sum(Vi @ x) / np.sum(Vi))
    return float(r @ Vi @ r)


def repeatability(runs: list[RunValues], profile: ToleranceProfile) -> list[CheckResult]:
    """Run-to-run agreement of every parameter all runs share (docs/methods.md 3.7).

    Rules (named in each result's detail):

    - "cv": scale factors, the coefficient of variation std/|mean| (ddof=1) of
      K = 1 + scale, against ``cv_max``;
    - "scatter": every other parameter (near zero, where a CV is meaningless):
      chi2 = sum((x_i - x_w)^2 / u_i^2), x_w the inverse-variance weighted mean,
      which is chi-squared with n - 1 degrees of freedom when the runs differ by
      their reported uncertainties only. When every run gives the parameter's shared
      reference (`RunValues.shared`), the runs' covariance V holds the Type B parts
      shared by runs on the same reference, and chi2 = r^T V^-1 r about the
      generalised least-squares mean (runs on one reference scatter by Type A only; a
      change of reference adds its Type B). The limit is its 1 - alpha/m quantile,
      m the number of parameters so judged (Bonferroni: the chance that a
      repeatable unit fails any of them is <= alpha). Parameters without
      uncertainties in every run are not judged.

    Returns
    -------
    CheckResult "repeat:<name>"; [] when fewer than ``min_runs`` runs are given.
    """
    rules = profile.repeatability
    if len(runs) < int(rules["min_runs"]):
        return []
    names = sorted(set.intersection(*(set(r.values) for r in runs)))
    ids = ", ".join(r.run_id for r in runs)
    cv_names = [n for n in names if n.rsplit(".", 1)[0] in CV_FAMILIES]
    scatter_names = [
        n for n in names if n not in cv_names and all((r.values[n][1] or 0.0) > 0 for r in runs)
    ]
    out = []
    for n in cv_names:
        k = 1.0 + np.array([r.values[n][0] for r in runs])
        cv = float(np.std(k, ddof=1) / abs(np.mean(k)))
        out.append(
            CheckResult(
                f"{REPEAT_PREFIX}{n}",
                cv,
                float(rules["cv_max"]),
                bool(cv <= rules["cv_max"]),
                f"rule cv: CV of K = 1 + scale over {len(runs)} runs ({ids})",
            )
        )
    if scatter_names:
        dof = len(runs) - 1
        crit = chi2_ppf(1.0 - rules["alpha"] / len(scatter_names), dof)
        for n in scatter_names:
            x = np.array([r.values[n][0] for r in runs])
            u = np.array([r.values[n][1] for r in runs])
            chi2 = _scatter_chi2(x, u, [r.shared.get(n) for r in runs])
            out.append(
                CheckResult(
                    f"{REPEAT_PREFIX}{n}",
                    chi2,
                    crit,
                    bool(chi2 <= crit),
                    f"rule scatter: run-to-run std {np.std(x, ddof=1):.3g} vs rms uncertainty "
                    f"{np.sqrt(np.mean(u**2)):.3g} {params.unit_of(n)}, chi2 with {dof} dof "
                    f"over {len(runs)} runs ({ids})",
                )
            )
    return out
