"""Cramer-Rao bound of a procedure's measurement model, and the benchmark's scores against it.

Science only. A simulated run is the noise-free output of the error model, h(theta), plus
white Gaussian noise of known standard deviation per channel. The Fisher information of
theta is then

    I = sum over channels c of J_c^T J_c / sigma_c^2,   J_c = d h_c / d theta,

and the Cramer-Rao lower bound (CRLB) on the variance of any unbiased estimator of
theta_i is [I^+]_ii (the pseudo-inverse: a parameter the data cannot separate from another,
such as a gyro bias from a g-sensitivity seen in one orientation only, leaves a null
direction; the bound of a function the data do determine is still c^T I^+ c). Every
parameter the data depend on enters theta, reported or not (a nuisance the estimator
must find too widens the bound of the others, as it should).

A nuisance the design leaves unknown at every sample (the rate profile of a turn by hand or
by a table whose rate is not recorded: only its total angle is known) is given per segment
as its direction d_t (C,) at each sample t (zero where it is known). Its amplitudes a_t are
free but for their sum (the turn angle), so the information of theta is that left in the
whitened Jacobian once the span of {e_t d_t} less its uniform combination is projected out:
I = J^T J - J^T P_all J + J^T P_sum J.

The Jacobian is taken by differences of the noise-free model: one-sided where the model is
linear in its parameters (the static and integral models: exact), central otherwise
(second-order accurate).

The scores of a benchmark case over its replicates (same truth, same design, independent
noise):

- efficiency = CRLB variance / observed variance of the estimates, per parameter
  (1 for an efficient unbiased estimator; its relative standard error is about
  sqrt(2 / (n - 1)) from n replicates);
- coverage = fraction of replicates whose |estimate - truth| <= U (the stated expanded
  uncertainty, about 95 %);
- bias in units of the standard error of the mean error (|z| > 3: a biased estimator).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

# The noise-free model: theta (name -> value, SI) -> per segment the clean channels (N, C),
# the noise std of each channel (C,), same unit, and the direction (N, C) of a nuisance
# unknown at each sample but for its sum, or None.
Segment = tuple[np.ndarray, np.ndarray, np.ndarray | None]
Model = Callable[[Mapping[str, float]], Sequence[Segment]]


def fisher_information(
    model: Model, theta: Mapping[str, float], steps: Mapping[str, float], *, linear: bool = False
) -> tuple[list[str], np.ndarray]:
    """Fisher information of `theta` for white Gaussian noise, from the model's Jacobian.

    Parameters
    ----------
    model : theta -> [(clean (N, C), sigma (C,), nuisance (N, C) or None), ...] per
        segment, noise-free.
    theta : the true parameter values, name -> SI value.
    steps : name -> finite-difference step (SI); small against the value's range,
        large against rounding (1e-6 relative to the data's scale is typical).
    linear : the model is linear in theta: one-sided differences, exact and half the
        model evaluations; otherwise central ones.

    Returns
    -------
    names : the parameter order (that of `theta`).
    info : (P, P) Fisher information, in the parameters' SI units^-2.
    """
    names = list(theta)
    base = model(theta)
    cols = [[] for _ in base]  # per segment: whitened Jacobian column per parameter
    for name in names:
        h = float(steps[name])
        up = model({**theta, name: theta[name] + h})
        dn = base if linear else model({**theta, name: theta[name] - h})
        span = h if linear else 2.0 * h
        for k, ((u, s, _), (d, _, _)) in enumerate(zip(up, dn, strict=True)):
            cols[k].append((u - d) / span / np.asarray(s, float))
    info = np.zeros((len(names), len(names)))
    for (_, s, nuisance), seg_cols in zip(base, cols, strict=True):
        jac = np.stack(seg_cols, axis=-1)  # (N, C, P)
        flat = jac.reshape(-1, len(names))
        info += flat.T @ flat
        if nuisance is not None:
            info -= _nuisance_information(jac, np.asarray(nuisance, float) / np.asarray(s, float))
    return names, info


def _nuisance_information(jac: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """J^T (P_all - P_sum) J of one segment: the information an unknown per-sample amplitude
    along `direction` (N, C, whitened) takes away, its sum being known."""
    norm2 = np.einsum("nc,nc->n", direction, direction)
    moving = norm2 > 0
    if not moving.any():
        return np.zeros((jac.shape[2], jac.shape[2]))
    proj = np.einsum("nc,ncp->np", direction[moving], jac[moving]) / np.sqrt(norm2[moving])[:, None]
    total = proj.sum(axis=0) / math.sqrt(int(moving.sum()))  # the uniform combination
    return proj.T @ proj - np.outer(total, total)


def crlb_variances(info: np.ndarray, *, rcond: float = 1e-10) -> np.ndarray:
    """Diagonal of the pseudo-inverse of the Fisher information: the CRLB variances (P,).

    The information is scaled to unit diagonal first (parameters of very different units),
    so `rcond` is relative to the scale-free spectrum. A parameter with no information
    gets an infinite bound.
    """
    d = np.sqrt(np.clip(np.diag(info), 0.0, None))
    free = d > 0
    out = np.full(info.shape[0], math.inf)
    scaled = info[np.ix_(free, free)] / np.outer(d[free], d[free])
    inv = np.linalg.pinv(scaled, rcond=rcond, hermitian=True)
    out[free] = np.diag(inv) / d[free] ** 2
    return out


@dataclass(frozen=True)
class ParameterScore:
    """The scores of one parameter over a case's replicates (errors SI, in its unit).

    n : replicates. rms_error : sqrt(mean (estimate - truth)^2). mean_error : mean
    error (the estimator's bias). bias_z : mean error / its standard error. std : sample
    standard deviation of the estimates. crlb_std : sqrt of the CRLB variance (None: not
    scored against the bound). efficiency : CRLB variance / std^2. coverage : fraction
    with |error| <= U. mean_u_ratio : mean stated standard uncertainty / std (1: the
    stated uncertainty is the scatter; < 1 too small, > 1 too large).
    """

    name: str
    n: int
    rms_error: float
    mean_error: float
    bias_z: float
    std: float
    crlb_std: float | None
    efficiency: float | None
    coverage: float
    mean_u_ratio: float

    def to_dict(self) -> dict[str, float | int | str | None]:
        """JSON-friendly form (a figure that is not a number, such as the efficiency of a
        parameter that did not scatter, as None)."""
        return {
            k: None if isinstance(v, float) and not math.isfinite(v) else v
            for k, v in self.__dict__.items()
        }


def score_parameter(
    name: str,
    estimates: np.ndarray,
    truth: float,
    stds: np.ndarray,
    expanded: np.ndarray,
    crlb_variance: float | None,
) -> ParameterScore:
    """Scores of one parameter from its replicates.

    Parameters
    ----------
    estimates, stds, expanded : (n,) the estimate, its stated standard uncertainty and
        expanded uncertainty U (about 95 %) of each replicate, SI.
    truth : the simulated true value.
    crlb_variance : the parameter's CRLB variance, or None (not scored against the bound).
    """
    est = np.asarray(estimates, float)
    err = est - truth
    n = est.size
    std = float(np.std(est, ddof=1)) if n > 1 else math.nan
    mean_err = float(np.mean(err))
    sem = std / math.sqrt(n) if n > 1 else math.nan
    eff = None
    crlb_std = None
    if crlb_variance is not None and math.isfinite(crlb_variance):
        crlb_std = math.sqrt(crlb_variance)
        eff = crlb_variance / std**2 if std > 0 else math.nan
    return ParameterScore(
        name=name,
        n=n,
        rms_error=float(np.sqrt(np.mean(err**2))),
        mean_error=mean_err,
        bias_z=mean_err / sem if sem > 0 else math.nan,
        std=std,
        crlb_std=crlb_std,
        efficiency=eff,
        coverage=float(np.mean(np.abs(err) <= np.asarray(expanded, float))),
        mean_u_ratio=float(np.mean(stds)) / std if std > 0 else math.nan,
    )


def summarise(scores: Sequence[ParameterScore]) -> dict[str, float | str | None]:
    """A case's summary: median efficiency over the parameters scored against the bound,
    the lowest and which parameter, the coverage pooled over every parameter and replicate,
    the lowest and highest parameter coverage."""
    effs = [(s.efficiency, s.name) for s in scores if s.efficiency is not None]
    covs = [(s.coverage, s.name) for s in scores]
    low_eff = min(effs) if effs else (None, None)
    return {
        "efficiency_vs_crlb": float(np.median([e for e, _ in effs])) if effs else None,
        "efficiency_min": low_eff[0],
        "efficiency_min_parameter": low_eff[1],
        "coverage_95": float(np.mean([c for c, _ in covs])) if covs else None,
        "coverage_min": min(covs)[0] if covs else None,
        "coverage_min_parameter": min(covs)[1] if covs else None,
        "coverage_max": max(covs)[0] if covs else None,
        "parameters": len(scores),
        "replicates": max((s.n for s in scores), default=0),
    }
