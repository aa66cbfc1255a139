"""Tests of calib_core.significance against independent closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from calib_core.significance import fit_ols, stepwise_reduce


def _data(seed: int, n: int = 60, k: int = 10, beta=None, sigma: float = 0.5):
    rng = np.random.default_rng(seed)
    X = np.column_stack([np.ones(n), rng.normal(size=(n, k))])
    beta = rng.normal(size=k + 1) if beta is None else np.asarray(beta, dtype=float)
    y = X @ beta + rng.normal(0.0, sigma, n)
    return X, y, ["const", *(f"x{j}" for j in range(k))]


@pytest.mark.parametrize("seed", range(5))
def test_statistics_match_independent_normal_equations(seed):
    X, y, names = _data(seed)
    fit = fit_ols(X, y, names)
    # Independent route: normal equations with numpy.linalg.inv, scipy.stats distributions.
    n, p = X.shape
    inv = np.linalg.inv(X.T @ X)
    beta = inv @ X.T @ y
    res = y - X @ beta
    Q = res @ res
    U = np.sum((X @ beta - y.mean()) ** 2)
    s2 = Q / (n - p)
    se = np.sqrt(s2 * np.diag(inv))
    t = beta / se
    F = (U / (p - 1)) / (Q / (n - p))
    # Both are exact formulas in double precision; 1e-9 relative covers the rounding.
    np.testing.assert_allclose(fit.coef, beta, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(fit.std, se, rtol=1e-9)
    np.testing.assert_allclose(fit.t, t, rtol=1e-9)
    np.testing.assert_allclose(fit.p, 2 * stats.t.sf(np.abs(t), n - p), rtol=1e-7, atol=1e-300)
    assert pytest.approx(Q, rel=1e-9) == fit.Q
    assert pytest.approx(U, rel=1e-9) == fit.U
    assert fit.r2 == pytest.approx(1 - Q / np.sum((y - y.mean()) ** 2), rel=1e-9)
    assert pytest.approx(F, rel=1e-9) == fit.F
    assert fit.F_crit == pytest.approx(stats.f.ppf(0.95, p - 1, n - p), rel=1e-12)
    assert fit.t_crit == pytest.approx(stats.t.ppf(0.975, n - p), rel=1e-12)
    assert (fit.n, fit.k, fit.dof) == (60, 10, 49)


@pytest.mark.parametrize(("k", "table_value"), [(10, 2.03), (5, 2.39)])
def test_f_on_constructed_dataset_equals_closed_form(k, table_value):
    """n = 60: F(10, 49) and F(5, 54) at 0.05, as in the centrifuge paper.

    y = X b + e with e orthogonal to the columns of X, so the fit must return
    exactly b, Q = |e|^2, U = |X b - mean|^2 and F = (U/k) / (Q/(n-k-1)).
    """
    n = 60
    rng = np.random.default_rng(k)
    X = np.column_stack([np.ones(n), rng.normal(size=(n, k))])
    b = np.arange(1.0, k + 2)
    e = rng.normal(size=n)
    e -= X @ np.linalg.lstsq(X, e, rcond=None)[0]  # project out the column space
    y = X @ b + e
    fit = fit_ols(X, y, ["const", *(f"x{j}" for j in range(k))])
    U = np.sum((X @ b - y.mean()) ** 2)
    Q = e @ e
    np.testing.assert_allclose(fit.coef, b, rtol=1e-10)
    assert pytest.approx((U / k) / (Q / (n - k - 1)), rel=1e-10) == fit.F
    # Published F tables give 2 decimals: F(10, 49) = 2.03, F(5, 54) = 2.39.
    assert fit.F_crit == pytest.approx(table_value, abs=0.005)


def test_paper_f_and_r2_are_consistent_with_the_formula():
    """Paper: final 5-term model, n = 60, R^2 = 0.9637 (4 decimals), F = 286.95.

    F = (R^2/k) / ((1-R^2)/(n-k-1)); R^2 rounded to +-5e-5 moves F by
    dF/dR^2 * 5e-5 = 54/5/(1-R^2)^2 * 5e-5 = 0.41, the tolerance used.
    """
    r2, k, n = 0.9637, 5, 60
    F = (r2 / k) / ((1 - r2) / (n - k - 1))
    assert pytest.approx(286.95, abs=0.41) == F


def test_no_constant_uses_uncentred_sums():
    X, y, names = _data(7, k=3)
    fit = fit_ols(X[:, 1:], y, names[1:])
    beta = np.linalg.lstsq(X[:, 1:], y, rcond=None)[0]
    assert not fit.has_const and fit.k == 3 and fit.dof == 57
    assert pytest.approx(np.sum((X[:, 1:] @ beta) ** 2), rel=1e-9) == fit.U


def test_add_constant_equals_explicit_column():
    X, y, names = _data(3, k=4)
    a = fit_ols(X, y, names)
    b = fit_ols(X[:, 1:], y, names[1:], add_constant=True)
    np.testing.assert_allclose(a.coef, b.coef, rtol=1e-12)
    assert a.names == b.names


def test_rank_deficiency_names_the_dependent_columns():
    X, y, names = _data(1, k=4)
    X[:, 3] = 2.0 * X[:, 1] - X[:, 2]
    with pytest.raises(ValueError, match=r"rank deficient.*x0.*x1.*x2"):
        fit_ols(X, y, names)
    with pytest.raises(ValueError, match="more observations than terms"):
        fit_ols(X[:5], y[:5], names)
    with pytest.raises(ValueError, match="4 names given for 5 columns"):
        fit_ols(X, y, names[:4])
    with pytest.raises(ValueError, match="keep names"):
        stepwise_reduce(X[:, :3], y, names[:3], keep=("nope",))


def test_stepwise_keeps_strong_terms_and_records_the_removals():
    k = 10
    beta = np.zeros(k + 1)
    beta[[0, 1, 4, 7]] = [1.0, 2.0, -1.5, 1.0]  # effects ~ 30 sigma of their estimates
    X, y, names = _data(11, beta=beta, sigma=0.5)
    red = stepwise_reduce(X, y, names)
    assert {"const", "x0", "x3", "x6"} <= set(red.kept)
    assert len(red.removed) + len(red.kept) == k + 1
    # each removal: the smallest |t| of its fit, below t_crit of that fit
    for step in red.steps:
        ts = {n: abs(t) for n, t in zip(step.fit.names, step.fit.t, strict=True) if n != "const"}
        assert abs(step.t) == pytest.approx(min(ts.values()))
        assert abs(step.t) < step.fit.t_crit
    assert np.all(np.abs(red.final.t[1:]) > red.final.t_crit)
    assert red.full.k == 10 and red.final.k == len(red.kept) - 1


def test_keep_protects_terms():
    X, y, names = _data(2, k=4, beta=[1.0, 2.0, 0.0, 0.0, 0.0])
    red = stepwise_reduce(X, y, names, keep=("const", "x3"))
    assert "x3" in red.kept


def test_false_keep_rate_matches_alpha():
    """Null terms survive the reduction at about the test level.

    With m null terms each kept with probability ~alpha, exact recovery happens
    with probability ~(1 - alpha)^m. Over 300 seeds the binomial std of the
    observed rate is sqrt(p (1-p) / 300); allow 4 of them.
    """
    m, alpha, trials = 6, 0.05, 300
    beta = np.array([1.0, 2.0, -1.0, 1.5, 0, 0, 0, 0, 0, 0])
    exact = 0
    for seed in range(trials):
        X, y, names = _data(1000 + seed, n=60, k=9, beta=beta, sigma=0.5)
        red = stepwise_reduce(X, y, names, alpha=alpha)
        exact += set(red.kept) == {"const", "x0", "x1", "x2"}
    p = (1 - alpha) ** m
    assert abs(exact / trials - p) < 4 * np.sqrt(p * (1 - p) / trials)


@pytest.mark.parametrize("seed", range(3))
def test_weighted_statistics_match_independent_normal_equations(seed):
    """Weighted fit against (X^T W X)^-1 X^T W y and scipy.stats, with and without a constant."""
    X, y, names = _data(seed)
    rng = np.random.default_rng(100 + seed)
    w = rng.uniform(0.1, 10.0, len(y))
    for cols in (slice(None), slice(1, None)):
        Xc, nc = X[:, cols], names[cols]
        fit = fit_ols(Xc, y, nc, weights=w)
        n, p = Xc.shape
        inv = np.linalg.inv(Xc.T @ (w[:, None] * Xc))
        beta = inv @ Xc.T @ (w * y)
        res = y - Xc @ beta
        Q = np.sum(w * res**2)
        centre = np.sum(w * y) / np.sum(w) if nc[0] == "const" else 0.0
        U = np.sum(w * (Xc @ beta - centre) ** 2)
        k = p - 1 if nc[0] == "const" else p
        s2 = Q / (n - p)
        t = beta / np.sqrt(s2 * np.diag(inv))
        np.testing.assert_allclose(fit.coef, beta, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(fit.t, t, rtol=1e-9)
        np.testing.assert_allclose(fit.residuals, res, rtol=1e-9, atol=1e-12)
        assert pytest.approx(Q, rel=1e-9) == fit.Q
        assert pytest.approx(U, rel=1e-9) == fit.U
        assert pytest.approx((U / k) / s2, rel=1e-9) == fit.F
        assert pytest.approx(stats.f.sf((U / k) / s2, k, n - p), rel=1e-6) == fit.F_p
    # equal weights are ordinary least squares
    a, b = fit_ols(X, y, names), fit_ols(X, y, names, weights=np.full(len(y), 3.0))
    np.testing.assert_allclose(a.t, b.t, rtol=1e-10)
    assert pytest.approx(b.F, rel=1e-10) == a.F
    with pytest.raises(ValueError, match="weights must be 60 finite positive numbers"):
        fit_ols(X, y, names, weights=-w)


def test_weights_keep_the_test_level_under_heteroscedastic_noise():
    """Noise std growing 20-fold along a (like a scale instability with g).

    A null term a^2 is tested with weights 1/variance: its rejection rate
    must be alpha within 4 binomial std over 300 seeds.
    """
    trials, alpha = 300, 0.05
    rejected = 0
    a = np.repeat(np.linspace(1.0, 20.0, 10), 6)
    sd = 0.05 * a
    for seed in range(trials):
        rng = np.random.default_rng(5000 + seed)
        y = 1.0 + 0.3 * a + rng.normal(0.0, sd)
        fit = fit_ols(
            np.column_stack([a, a**2]), y, ["a", "a2"], add_constant=True, weights=1 / sd**2
        )
        rejected += bool(fit.p[2] < alpha)
    assert abs(rejected / trials - alpha) < 4 * np.sqrt(alpha * (1 - alpha) / trials)


def test_one_sided_t_test_reproduces_the_papers_critical_values():
    """The centrifuge paper tests t one-sided at alpha = 0.05: 1.676 and 1.671.

    Its models (n = 60, F(10, 49) full, F(5, 54) final; see the F test above)
    have n - k - 1 = 49 and 54. The printed values are the t table's rows 50
    and 60 (t_0.95(50) = 1.67591, t_0.95(60) = 1.67065): at 3 decimals, as
    printed, our one-sided critical values must equal them exactly. At the
    models' own dofs the exact values lie between the two rows, while the
    two-sided 0.05 test would need 2.01 (0.3 away), so one-sided is the paper's.
    """
    rng = np.random.default_rng(7)

    def t_crit(n, k, t_test):
        X = np.column_stack([np.ones(n), rng.normal(size=(n, k))])
        fit = fit_ols(X, rng.normal(size=n), ["const", *(f"x{j}" for j in range(k))], t_test=t_test)
        assert fit.dof == n - k - 1
        return fit.t_crit

    assert round(t_crit(61, 10, "one-sided"), 3) == 1.676  # dof 50
    assert round(t_crit(71, 10, "one-sided"), 3) == 1.671  # dof 60
    for k in (10, 5):  # the paper's full and final model, n = 60
        one, two = t_crit(60, k, "one-sided"), t_crit(60, k, "two-sided")
        assert 1.671 < one < 1.677
        assert two > 2.0 and two - one > 0.3


def test_one_sided_test_keeps_a_term_the_two_sided_test_removes():
    """A term with t = 1.85 (dof 56: 1.6725 one-sided, 2.0032 two-sided) stays one-sided only.

    y = X b + e with e orthogonal to the design, b of x2 set so that its t is
    exactly 1.85 (std does not depend on b). p values follow the side: the
    one-sided p is half the two-sided one.
    """
    n, k = 60, 3
    rng = np.random.default_rng(3)
    X = np.column_stack([np.ones(n), rng.normal(size=(n, k))])
    names = ["const", *(f"x{j}" for j in range(k))]
    e = rng.normal(size=n)
    e -= X @ np.linalg.lstsq(X, e, rcond=None)[0]
    b = np.array([1.0, 1.0, 1.0, 0.0])
    b[3] = 1.85 * fit_ols(X, X @ b + e, names).std[3]
    y = X @ b + e
    two, one = fit_ols(X, y, names), fit_ols(X, y, names, t_test="one-sided")
    assert one.t[3] == pytest.approx(1.85, rel=1e-9)
    assert one.p[3] == pytest.approx(two.p[3] / 2, rel=1e-12)
    assert stepwise_reduce(X, y, names, t_test="one-sided").kept == tuple(names)
    assert stepwise_reduce(X, y, names).removed == ("x2",)
    with pytest.raises(ValueError, match="t_test must be one of"):
        fit_ols(X, y, names, t_test="one")


def test_f_steering_ends_at_the_largest_model_f_along_the_path():
    """steer="F": each removal raised F; removing the next weakest term would lower it.

    The paper's F rose from 139.34 (10 terms) to 286.95 (5 terms). On the same
    shape (n = 60, 10 candidates) F steering reaches an F at least the t
    steering's, and its accepted removals are exactly those that raise F.
    """
    beta = np.array([1.0, 2.0, -1.5, 1.0, 0.3, 0.15, 0, 0, 0, 0, 0])
    X, y, names = _data(21, beta=beta, sigma=0.5)
    by_f = stepwise_reduce(X, y, names, steer="F")
    by_t = stepwise_reduce(X, y, names)
    fits = [s.fit for s in by_f.steps] + [by_f.final]
    assert all(b.F > a.F for a, b in zip(fits[:-1], fits[1:], strict=True))
    assert by_f.final.F >= by_t.final.F
    # the next removal (weakest |t| of the final fit) would not raise F
    cand = [j for j, nm in enumerate(by_f.final.names) if nm != "const"]
    weakest = min(cand, key=lambda j: abs(by_f.final.t[j]))
    cols = [names.index(nm) for nm in by_f.final.names if nm != by_f.final.names[weakest]]
    assert fit_ols(X[:, cols], y, [names[j] for j in cols]).F <= by_f.final.F
    assert {"const", "x0", "x1", "x2"} <= set(by_f.kept)
    with pytest.raises(ValueError, match="steer must be one of"):
        stepwise_reduce(X, y, names, steer="R2")


def _lone_term(t_value: float, n: int = 60):
    """y = 1 + b x0 + e, e orthogonal to the design, b set so that x0's t is `t_value`."""
    rng = np.random.default_rng(5)
    X = np.column_stack([np.ones(n), rng.normal(size=n)])
    e = rng.normal(size=n)
    e -= X @ np.linalg.lstsq(X, e, rcond=None)[0]
    names = ["const", "x0"]
    b = np.array([1.0, 0.0])
    b[1] = t_value * fit_ols(X, X @ b + e, names).std[1]
    return X, X @ b + e, names


def test_f_then_t_removes_a_term_whose_model_fails_the_f_test():
    """The paper's first phase: while F <= F_crit the weakest term goes whatever its t.

    One regressor, dof 58: F = t^2 and F_crit(1, 58) = 4.007 = t(0.975; 58)^2. A
    one-sided t of 1.85 passes t(0.95; 58) = 1.672 but F = 3.42 fails: the t rule
    keeps x0 in a model that fails its F test, "F-then-t" removes it. At t = 2.1
    (F = 4.41) both keep it; two-sided they agree (t_crit^2 = F_crit).
    """
    X, y, names = _lone_term(1.85)
    by_t = stepwise_reduce(X, y, names, t_test="one-sided", steer="t")
    paper = stepwise_reduce(X, y, names, t_test="one-sided", steer="F-then-t")
    assert pytest.approx(1.85**2, rel=1e-9) == by_t.final.F
    assert by_t.final.F_crit == pytest.approx(stats.f.ppf(0.95, 1, 58), rel=1e-12)
    assert by_t.final.F_crit == pytest.approx(stats.t.ppf(0.975, 58) ** 2, rel=1e-9)
    assert by_t.kept == ("const", "x0") and not by_t.final.model_significant
    assert paper.kept == ("const",) and paper.removed == ("x0",)
    assert paper.steps[0].t == pytest.approx(1.85, rel=1e-9)
    X, y, names = _lone_term(2.1)
    for steer in ("t", "F-then-t"):
        assert stepwise_reduce(X, y, names, t_test="one-sided", steer=steer).kept == tuple(names)
    X, y, names = _lone_term(1.85)
    assert stepwise_reduce(X, y, names, steer="F-then-t").kept == ("const",)
    assert stepwise_reduce(X, y, names, steer="t").kept == ("const",)


@pytest.mark.parametrize("t_test", ["two-sided", "one-sided"])
def test_f_then_t_follows_the_t_path_and_ends_in_a_model_that_passes_f(t_test):
    """Both rules remove the weakest |t| each round, so the t rule's removals are the
    first removals of "F-then-t"; a removal beyond them happens only where the model
    failed its F test, and the final model passes it (or has no candidate left).
    Null and weak-term data, n = 60, 10 candidates (the paper's shape)."""
    longer = 0
    for seed in range(40):
        beta = np.r_[1.0, 0.3 if seed % 2 else 0.0, np.zeros(9)]
        X, y, names = _data(100 + seed, beta=beta, sigma=1.0)
        by_t = stepwise_reduce(X, y, names, t_test=t_test, steer="t")
        paper = stepwise_reduce(X, y, names, t_test=t_test, steer="F-then-t")
        assert paper.removed[: len(by_t.removed)] == by_t.removed, seed
        for step in paper.steps[len(by_t.removed) :]:
            assert not step.fit.model_significant, seed
        assert paper.final.model_significant or paper.kept == ("const",), seed
        longer += len(paper.removed) > len(by_t.removed)
    # two-sided a model whose terms all pass t(0.975) passed F here in every case;
    # one-sided (t_crit^2 = 2.8 < F_crit(1, dof) = 4.0) some lone terms fail F
    assert (longer == 0) if t_test == "two-sided" else (longer > 0)


def test_an_exact_fit_gives_infinite_statistics_not_a_crash():
    """Q = 0 (a stuck sensor's constant output, a noiseless design): F and t are inf
    (or nan where the terms are zero too), never a ZeroDivisionError."""
    exact = fit_ols(np.ones((4, 1)), np.full(4, 2.0), ["c0"])
    assert exact.Q == 0.0 and np.isposinf(exact.F) and np.isposinf(exact.t[0])
    flat = fit_ols(np.ones((8, 1)), np.zeros(8), ["c0"])
    assert flat.Q == 0.0 and np.isnan(flat.F)
