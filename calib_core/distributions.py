"""Normal, Student t, chi-square, F and binomial distribution functions for tests and
intervals.

The same functions `scipy.stats` evaluates (its ``norm``, ``t``, ``chi2``, ``f`` and
``binom`` call these `scipy.special` routines), without importing `scipy.stats`: that
import alone takes about a second, more than reading and solving a whole run, and `calib
process` of one run at the lab table must answer in about a second.

Every function takes scalars or arrays (broadcast as NumPy does) and returns a
``numpy.float64`` for scalar input, an array otherwise, as `scipy.stats` does; outside
a distribution's domain the result is NaN, as there.
"""

from __future__ import annotations

import numpy as np
from scipy import special


def norm_pdf(x):
    """Standard normal density at x."""
    x = np.asarray(x, dtype=float)
    return _out(np.exp(-0.5 * x * x) / np.sqrt(2.0 * np.pi))


def norm_cdf(x):
    """P(Z <= x) of a standard normal Z."""
    return _out(special.ndtr(x))


def norm_sf(x):
    """P(Z > x) of a standard normal Z (accurate in the far tail)."""
    return _out(special.ndtr(-np.asarray(x, dtype=float)))


def norm_ppf(q):
    """The x with P(Z <= x) = q."""
    return _out(special.ndtri(q))


def t_sf(x, dof):
    """P(T > x) of Student's t with `dof` degrees of freedom."""
    return _out(special.stdtr(dof, -np.asarray(x, dtype=float)))


def t_ppf(q, dof):
    """The x with P(T <= x) = q, Student's t with `dof` degrees of freedom."""
    return _out(special.stdtrit(dof, q))


def t_isf(q, dof):
    """The x with P(T > x) = q, Student's t with `dof` degrees of freedom."""
    return _out(-special.stdtrit(dof, q))


def chi2_sf(x, dof):
    """P(X > x) of a chi-square variable with `dof` degrees of freedom."""
    return _out(special.chdtrc(dof, x))


def chi2_ppf(q, dof):
    """The x with P(X <= x) = q, chi-square with `dof` degrees of freedom."""
    return _out(2.0 * special.gammaincinv(np.asarray(dof, dtype=float) / 2.0, q))


def f_sf(x, dfn, dfd):
    """P(F > x) of Fisher's F with (dfn, dfd) degrees of freedom."""
    return _out(special.fdtrc(dfn, dfd, x))


def f_ppf(q, dfn, dfd):
    """The x with P(F <= x) = q, Fisher's F with (dfn, dfd) degrees of freedom."""
    return _out(special.fdtri(dfn, dfd, q))


def binom_isf(q: float, n: int, p: float) -> int:
    """The smallest count k with P(X > k) <= q, X ~ Binomial(n, p) (`scipy.stats.binom.isf`).

    From the continuous inverse of the CDF (`scipy.special.bdtrik`), then the exact CDF
    (`bdtr`) on the integers either side of it.
    """
    if n <= 0 or p <= 0.0:
        return 0
    target = 1.0 - q
    k = int(min(max(np.ceil(special.bdtrik(target, n, p)), 0), n))
    while k > 0 and special.bdtr(k - 1, n, p) >= target:
        k -= 1
    while k < n and special.bdtr(k, n, p) < target:
        k += 1
    return k


def _out(value):
    """A numpy.float64 for a 0-d result, the array otherwise."""
    arr = np.asarray(value, dtype=float)
    return arr[()] if arr.ndim == 0 else arr
