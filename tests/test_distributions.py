"""calib_core.distributions evaluates what scipy.stats does, without importing it."""

import numpy as np
import pytest
from scipy import stats

from calib_core import distributions as d

RNG = np.random.default_rng(19)
X = RNG.normal(size=200) * 4.0
Q = RNG.uniform(size=200)
DOF = RNG.uniform(0.5, 300.0, size=200)
DOF2 = RNG.uniform(1.0, 50.0, size=200)

CASES = [
    (d.norm_pdf, stats.norm.pdf, (X,)),
    (d.norm_cdf, stats.norm.cdf, (X,)),
    (d.norm_sf, stats.norm.sf, (X,)),
    (d.norm_ppf, stats.norm.ppf, (Q,)),
    (d.t_sf, stats.t.sf, (X, DOF)),
    (d.t_ppf, stats.t.ppf, (Q, DOF)),
    (d.t_isf, stats.t.isf, (Q, DOF)),
    (d.chi2_sf, stats.chi2.sf, (np.abs(X) * 5.0, DOF)),
    (d.chi2_ppf, stats.chi2.ppf, (Q, DOF)),
    (d.f_sf, stats.f.sf, (np.abs(X), DOF, DOF2)),
    (d.f_ppf, stats.f.ppf, (Q, DOF, DOF2)),
]


@pytest.mark.parametrize(
    ("ours", "theirs", "args"), CASES, ids=lambda c: getattr(c, "__name__", "")
)
def test_same_values_as_scipy_stats(ours, theirs, args):
    # Both evaluate the same scipy.special routines: equal to rounding (a few ulp).
    np.testing.assert_allclose(ours(*args), theirs(*args), rtol=1e-12, atol=1e-300)
    scalar = ours(*(a[0] for a in args))
    assert isinstance(scalar, np.float64)
    assert scalar == pytest.approx(float(theirs(*(a[0] for a in args))), rel=1e-12)


def test_outside_domain_is_nan_and_infinite_dof_is_normal():
    assert np.isnan(d.t_ppf(0.975, 0.0)) and np.isnan(d.chi2_ppf(0.5, -1.0))
    assert np.isnan(d.norm_ppf(1.5))
    assert d.t_ppf(0.975, np.inf) == pytest.approx(d.norm_ppf(0.975), rel=1e-12)


@pytest.mark.parametrize("k", [1, 2, 6, 24, 1000])
def test_max_normal_moments_match_adaptive_quadrature(k):
    from scipy import integrate

    from calib_core.stats import max_normal_moments

    def density(z):
        return k * stats.norm.pdf(z) * stats.norm.cdf(z) ** (k - 1)

    tight = {"epsabs": 1e-14, "epsrel": 1e-13, "limit": 500}
    q1 = integrate.quad(lambda z: z * density(z), -12.0, 12.0, **tight)[0]
    q2 = integrate.quad(lambda z: z * z * density(z), -12.0, 12.0, **tight)[0]
    m1, var = max_normal_moments(k)
    # quad run to 1e-13; the 4801-point grid agrees to 1e-12 (see stats.py).
    assert m1 == pytest.approx(q1, abs=1e-12) and var == pytest.approx(q2 - q1 * q1, abs=1e-12)


def test_binomial_quantile_same_as_scipy_stats():
    """`binom_isf` against `scipy.stats.binom.isf` over counts up to a day of six channels
    at 1 kHz and false-alarm rates from 1e-9 to 1 (the replaced-samples check's)."""
    rng = np.random.default_rng(0)
    cases = [
        (1e-3, n, p) for n in (1, 10, 1000, 10**6, 5 * 10**8) for p in (1e-9, 2.7e-3, 0.5, 1.0)
    ]
    draws = zip(
        10 ** rng.uniform(-6, -0.5, 200),
        10 ** rng.uniform(0, 8, 200),
        10 ** rng.uniform(-8, 0, 200),
        strict=True,
    )
    cases += [(q, int(n), p) for q, n, p in draws]
    for q, n, p in cases:
        assert d.binom_isf(q, n, p) == int(stats.binom.isf(q, n, p)), (q, n, p)
    assert d.binom_isf(1e-3, 0, 0.1) == 0 and d.binom_isf(1e-3, 10, 0.0) == 0
