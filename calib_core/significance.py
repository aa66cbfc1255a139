"""Ordinary least squares with significance statistics, and stepwise model reduction.

Used wherever the product has to decide which terms a model needs: the
centrifuge high-g model (docs/methods.md 2.8) and the temperature fits.

For n observations and p columns (k regressors plus, usually, a constant):

    Q = sum (y - y_hat)^2                  residual sum of squares
    U = sum (y_hat - mean(y))^2            regression sum of squares
    R^2 = U / (U + Q)
    F = (U / k) / (Q / (n - k - 1))        compared with F(k, n - k - 1) at 1 - alpha
    t_j = beta_j / std_j                   |t_j| compared with t(n - k - 1) at 1 - alpha/2
                                           (two-sided, default) or 1 - alpha (one-sided)

The one-sided test is the centrifuge paper's: its critical values 1.676 and
1.671 are the 0.95 points of t at 50 and 60 degrees of freedom (a printed
table's rows; its models have n - k - 1 = 49 and 54, exactly 1.6766 and
1.6736), where the two-sided 0.05 test would need 2.01. One-sided, |t| is
compared with t(1 - alpha): a term is kept at half the evidence, so about
2 alpha of null terms survive each test instead of alpha.

Without a constant column the sums are taken about zero instead of the mean
and the degrees of freedom are k = p, n - p (the usual regression-through-the-
origin convention).

With weights w (inverse variances, up to a common factor) every sum is
weighted: Q = sum w (y - y_hat)^2, U = sum w (y_hat - ybar_w)^2 with the
weighted mean ybar_w. This is ordinary least squares on the rows scaled by
sqrt(w), so the F and t distributions hold when the variance of each row is
known up to that common factor (heteroscedastic data, e.g. centrifuge steps
whose scale-factor instability grows with the input).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib_core.distributions import f_ppf, f_sf, t_ppf, t_sf

CONST = "const"
T_TESTS = ("two-sided", "one-sided")
# How the stepwise reduction decides: by the weakest term's t test, by the model F, or
# the centrifuge paper's two phases (the model F test first, then the t tests).
STEERING = ("t", "F", "F-then-t")
# Columns are scaled to unit norm before the decomposition; a design whose
# scaled condition number exceeds this cannot give trustworthy t values.
MAX_CONDITION = 1e10


@dataclass(frozen=True, eq=False)
class OlsFit:
    """One least-squares fit with its significance statistics.

    Attributes
    ----------
    names : (p,) term names, in column order.
    coef, std, t, p : (p,) coefficients, standard errors, t values, p values of |t|
        (two-sided, or one-sided P(T > |t|), as `t_test`).
    cov : (p, p) coefficient covariance, sigma^2 (X^T X)^-1.
    residuals : (n,) y - X coef.
    n, k, dof : observations, regressors (constant not counted), n - k - 1.
    Q, U, r2 : residual and regression sums of squares, coefficient of determination.
    F, F_crit, F_p : model F statistic, its critical value F(k, dof) at 1 - alpha, p value.
    t_crit : critical t(dof) at alpha, two- or one-sided as `t_test`.
    alpha : significance level used.
    t_test : "two-sided" or "one-sided".
    has_const : whether a constant column (named ``"const"``) is in the model.
    """

    names: tuple[str, ...]
    coef: np.ndarray
    std: np.ndarray
    t: np.ndarray
    p: np.ndarray
    cov: np.ndarray
    residuals: np.ndarray
    n: int
    k: int
    dof: int
    Q: float
    U: float
    r2: float
    F: float
    F_crit: float
    F_p: float
    t_crit: float
    alpha: float
    has_const: bool
    t_test: str = "two-sided"

    @property
    def sigma(self) -> float:
        """Residual standard deviation sqrt(Q / dof), in y's unit."""
        return float(np.sqrt(self.Q / self.dof))

    @property
    def model_significant(self) -> bool:
        """Whether the model as a whole passes the F test."""
        return bool(self.F_crit < self.F)

    def coefficient(self, name: str) -> float:
        return float(self.coef[self._index(name)])

    def _index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"term {name!r} is not in the model {list(self.names)}") from None

    def table(self) -> list[dict[str, float | str]]:
        """One row per term: name, coef, std, t, p."""
        return [
            {"name": n, "coef": float(c), "std": float(s), "t": float(t), "p": float(p)}
            for n, c, s, t, p in zip(self.names, self.coef, self.std, self.t, self.p, strict=True)
        ]


def _check_inputs(
    X: np.ndarray, y: np.ndarray, names: Sequence[str]
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    if X.ndim != 2:
        raise ValueError(f"X must be 2-D (n, p), got shape {X.shape}")
    if y.shape != (X.shape[0],):
        raise ValueError(f"y must have shape ({X.shape[0]},) to match X, got {y.shape}")
    names = tuple(names)
    if len(names) != X.shape[1]:
        raise ValueError(f"{len(names)} names given for {X.shape[1]} columns of X")
    if len(set(names)) != len(names):
        raise ValueError(f"term names must be unique, got {list(names)}")
    bad_cols = [names[j] for j in np.flatnonzero(~np.isfinite(X).all(axis=0))]
    if bad_cols:
        raise ValueError(f"X has non-finite values in columns {bad_cols}")
    if not np.isfinite(y).all():
        raise ValueError(f"y has non-finite values at rows {np.flatnonzero(~np.isfinite(y))[:10]}")
    return X, y, names


def _with_constant(
    X: np.ndarray, names: tuple[str, ...], add_constant: bool
) -> tuple[np.ndarray, tuple[str, ...], bool]:
    """(X, names, has_const) with the constant column prepended if asked, and checked."""
    if add_constant:
        if CONST in names:
            raise ValueError(f"add_constant=True but a column is already named {CONST!r}")
        X = np.column_stack([np.ones(X.shape[0]), X])
        names = (CONST, *names)
    has_const = CONST in names
    if has_const:
        c = X[:, names.index(CONST)]
        if c[0] == 0.0 or not np.all(c == c[0]):
            raise ValueError(f"column {CONST!r} must hold one repeated non-zero value")
    return X, names, has_const


def _row_weights(weights: np.ndarray | None, n: int) -> np.ndarray:
    """(n,) row weights, all ones by default; finite and positive, else ValueError."""
    if weights is None:
        return np.ones(n)
    w = np.asarray(weights, dtype=float)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w <= 0.0):
        raise ValueError(f"weights must be {n} finite positive numbers, got shape {w.shape}")
    return w


def _weighted_solve(
    X: np.ndarray, y: np.ndarray, w: np.ndarray, names: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """(coef, (X^T W X)^-1) of the weighted fit, from one SVD; ValueError if rank deficient.

    Unit-norm columns make the singular values a fair rank test across terms
    of very different magnitude (a, a^2, a^3 at 200 m/s^2).
    """
    sw = np.sqrt(w)
    Xw, yw = X * sw[:, None], y * sw
    norms = np.linalg.norm(Xw, axis=0)
    zero = [names[j] for j in np.flatnonzero(norms == 0.0)]
    if zero:
        raise ValueError(f"design matrix is rank deficient: columns {zero} are all zero")
    Us, s, Vt = np.linalg.svd(Xw / norms, full_matrices=False)
    condition = s[0] / s[-1] if s[-1] > 0 else np.inf
    if condition > MAX_CONDITION:
        null = np.abs(Vt[-1])
        involved = [names[j] for j in np.flatnonzero(null > 0.1 * null.max())]
        raise ValueError(
            f"design matrix is rank deficient (scaled condition number {condition:.3g}): "
            f"columns {involved} are (nearly) linearly dependent; drop one of them"
        )
    coef = (Vt.T @ ((Us.T @ yw) / s)) / norms
    xtx_inv = (Vt.T / s**2) @ Vt / np.outer(norms, norms)
    return coef, xtx_inv


def fit_ols(
    X: np.ndarray,
    y: np.ndarray,
    names: Sequence[str],
    *,
    alpha: float = 0.05,
    add_constant: bool = False,
    weights: np.ndarray | None = None,
    t_test: str = "two-sided",
) -> OlsFit:
    """Least-squares fit of y on the columns of X, with F and t statistics.

    Parameters
    ----------
    X : (n, p) design matrix. A column named ``"const"`` is the constant term
        (it must hold one repeated non-zero value).
    y : (n,) observations.
    names : (p,) term names.
    alpha : significance level of the F and t critical values.
    add_constant : prepend a column of ones named ``"const"``.
    weights : (n,) positive row weights, 1 / variance up to a common factor
        (default: all equal). Q, U, R^2, F and t are then the weighted ones and
        `residuals` stay unweighted (y - X coef).
    t_test : "two-sided" (|t| against t(1 - alpha/2)) or "one-sided" (|t|
        against t(1 - alpha), the centrifuge paper's); p values follow.

    Returns
    -------
    OlsFit

    Raises
    ------
    ValueError
        on bad shapes, non-finite values, too few observations (n <= p), or a
        (nearly) rank-deficient design; the message names the dependent columns.

    The rank check, the coefficients and their covariance all come from the one SVD
    of the weighted, column-normalised design (`_weighted_solve`).
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    _check_choice("t_test", t_test, T_TESTS)
    sides = 2.0 if t_test == "two-sided" else 1.0
    X, y, names = _check_inputs(X, y, names)
    X, names, has_const = _with_constant(X, names, add_constant)
    n, p = X.shape
    k = p - 1 if has_const else p
    dof = n - p
    if dof < 1:
        raise ValueError(f"need more observations than terms: n = {n}, terms = {p} ({list(names)})")
    w = _row_weights(weights, n)
    coef, xtx_inv = _weighted_solve(X, y, w, names)

    fitted = X @ coef
    residuals = y - fitted
    Q = float(np.sum(w * residuals**2))
    centre = np.sum(w * y) / np.sum(w) if has_const else 0.0
    U = float(np.sum(w * (fitted - centre) ** 2))
    total = U + Q
    r2 = U / total if total > 0 else np.nan

    sigma2 = np.float64(Q) / dof  # an exact fit (Q = 0) gives F = inf, t = inf, not a crash
    std = np.sqrt(sigma2 * np.diag(xtx_inv))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = coef / std
        F = (U / k) / sigma2 if k > 0 else np.nan
    pval = sides * t_sf(np.abs(t), dof)
    F_crit = f_ppf(1.0 - alpha, k, dof) if k > 0 else np.nan
    F_p = f_sf(F, k, dof) if k > 0 else np.nan
    return OlsFit(
        names=names,
        coef=coef,
        std=std,
        t=t,
        p=pval,
        cov=sigma2 * xtx_inv,
        residuals=residuals,
        n=n,
        k=k,
        dof=dof,
        Q=Q,
        U=U,
        r2=float(r2),
        F=float(F),
        F_crit=F_crit,
        F_p=F_p,
        t_crit=t_ppf(1.0 - alpha / sides, dof),
        alpha=alpha,
        has_const=has_const,
        t_test=t_test,
    )


def _check_choice(field_name: str, value: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"{field_name} must be one of {list(choices)}, got {value!r}")


@dataclass(frozen=True, eq=False)
class RemovalStep:
    """One removal of the stepwise reduction.

    `fit` is the model the term was removed from (its F, R^2 and all t values);
    `t` and `p` are the removed term's statistics in that fit.
    """

    removed: str
    t: float
    p: float
    fit: OlsFit


@dataclass(frozen=True, eq=False)
class Reduction:
    """Result of `stepwise_reduce`: the full fit, the final fit, and the removals in order."""

    full: OlsFit
    final: OlsFit
    steps: tuple[RemovalStep, ...]

    @property
    def kept(self) -> tuple[str, ...]:
        return self.final.names

    @property
    def removed(self) -> tuple[str, ...]:
        return tuple(s.removed for s in self.steps)


def stepwise_reduce(
    X: np.ndarray,
    y: np.ndarray,
    names: Sequence[str],
    alpha: float = 0.05,
    keep: Sequence[str] = (CONST,),
    *,
    add_constant: bool = False,
    weights: np.ndarray | None = None,
    t_test: str = "two-sided",
    steer: str = "t",
) -> Reduction:
    """Backward elimination: drop the least significant term and refit until done.

    Each round takes the term (outside `keep`) with the smallest |t|. With
    ``steer="t"`` it is removed if |t| < t_crit(dof) at `alpha` (two- or
    one-sided, `t_test`); the rounds end when every term is significant. With
    ``steer="F"`` the model F test steers: the term is removed if the refitted
    model's F statistic is larger and the refitted model still passes its F
    test, so the reduction ends at the largest F along the path (the paper's
    F grows from 139.34 to 286.95). Dropping a term raises F when roughly
    t^2 < (dof + k) / (k - 1) for a strong model (k regressors), so the F
    steering can remove terms the t test keeps; their t and p stay in `steps`.
    ``steer="F-then-t"`` is the centrifuge paper's two phases (docs/methods.md
    2.8): in a round where the model fails its F test (F <= F_crit) the weakest
    term goes whatever its t; where it passes, the t rule above decides. The
    final model therefore passes its F test unless no candidate is left. The
    path is the t rule's; it is longer only where a model failing its F test
    has no term below t_crit. At least one column always stays.

    Parameters
    ----------
    X, y, names, add_constant, weights, t_test : as `fit_ols`.
    alpha : significance level of the coefficient t tests and the F test.
    keep : terms never removed (default the constant). Names absent from the
        model raise, except ``"const"`` when the model has no constant.
    steer : "t" (default), "F" or "F-then-t", as above.

    Returns
    -------
    Reduction
    """
    _check_choice("steer", steer, STEERING)
    X, y, names = _check_inputs(X, y, names)
    if add_constant:
        X = np.column_stack([np.ones(X.shape[0]), X])
        names = (CONST, *names)
    unknown = set(keep) - set(names) - {CONST}
    if unknown:
        raise ValueError(f"keep names {sorted(unknown)} are not terms of the model {list(names)}")

    def refit(cols: list[int]) -> OlsFit:
        cols_names = [names[j] for j in cols]
        return fit_ols(X[:, cols], y, cols_names, alpha=alpha, weights=weights, t_test=t_test)

    cols = list(range(len(names)))
    fit = full = refit(cols)
    steps: list[RemovalStep] = []
    while len(cols) > 1:
        candidates = [j for j, name in enumerate(fit.names) if name not in keep]
        if not candidates:
            break
        weakest = min(candidates, key=lambda j: abs(fit.t[j]))
        reduced_cols = cols[:weakest] + cols[weakest + 1 :]
        by_t = steer == "t" or (steer == "F-then-t" and fit.model_significant)
        if by_t and abs(fit.t[weakest]) >= fit.t_crit:
            break
        reduced = refit(reduced_cols)
        if steer == "F" and not (reduced.F > fit.F and reduced.model_significant):
            break
        steps.append(
            RemovalStep(fit.names[weakest], float(fit.t[weakest]), float(fit.p[weakest]), fit)
        )
        cols, fit = reduced_cols, reduced
    return Reduction(full=full, final=fit, steps=tuple(steps))
