"""The phase of a rate record and the sums of squared second differences of it, the Allan
variance's inner loops, compiled.

The overlapping Allan variance at cluster size m sums, over every k,
``((theta[k+2m] - theta[k+m]) - (theta[k+m] - theta[k]))**2``: N terms per cluster size,
some 10^9 for a day at 1 kHz over six channels and 25 octave sizes. NumPy needs three
passes over memory and a temporary per term; this loop reads each value once and keeps
nothing, several times faster. No library offers it for chunks of a stream (allantools
works on one array), so it is written here, compiled by Numba (`cache=True`: once per
installation).

Summation: each block of BLOCK terms is summed by the compiler's vectorised reduction
(``fastmath={"reassoc"}``: the order within a block is the processor's vector width),
the blocks' sums added in order; the error stays within (BLOCK + N / BLOCK) eps of the sum.
"""

from __future__ import annotations

import numba
import numpy as np

BLOCK = 4096  # terms per vectorised partial sum


@numba.njit(cache=True, nogil=True, boundscheck=False, fastmath={"reassoc"})
def _block_sum(new: np.ndarray, mid: np.ndarray, old: np.ndarray) -> float:
    s = 0.0
    for j in range(new.size):
        d = (new[j] - mid[j]) - (mid[j] - old[j])
        s += d * d
    return s


@numba.njit(cache=True, nogil=True, boundscheck=False)
def runs_sum(new: np.ndarray, mid: np.ndarray, old: np.ndarray) -> float:
    """Sum of ((new - mid) - (mid - old))**2 over three runs of equal length (n,): the
    phase at k + 2m, k + m and k."""
    total = 0.0
    for s in range(0, new.size, BLOCK):
        e = min(s + BLOCK, new.size)
        total += _block_sum(new[s:e], mid[s:e], old[s:e])
    return total


@numba.njit(cache=True, nogil=True, boundscheck=False)
def span_sums(
    span: np.ndarray, m: np.ndarray, first: np.ndarray, out: np.ndarray, origin: int
) -> None:
    """Add to out[i] the sum over k >= first[i] of the squared second difference at
    cluster size m[i] (ascending) of the phase run `span` (theta_0 .. theta_{n-1} of it),
    for every k + 2 m[i] < n.

    Block by block of the newest point j = k + 2 m, every cluster size in turn: the run
    at j - 2 m of one size is the run at j - m of the next, read once from memory for
    both (the sizes' lagged runs are beyond the processor's cache). The blocks start at
    row `origin` (<= every first[i] + 2 m[i]), so each size's sum is the same whichever
    other sizes are summed in the same call.
    """
    n = span.size
    for s in range(origin, n, BLOCK):
        e = min(s + BLOCK, n)
        for i in range(m.size):
            lag = m[i]
            j0 = max(s, first[i] + 2 * lag)
            if e > j0:
                out[i] += _block_sum(
                    span[j0:e], span[j0 - lag : e - lag], span[j0 - 2 * lag : e - 2 * lag]
                )


@numba.njit(cache=True, nogil=True, boundscheck=False)
def phase(x: np.ndarray, offset: float, start: float, out: np.ndarray) -> None:
    """out[i] = start + the sum over j <= i of (x[j] - offset): the phase of the rate
    samples x (n,) continued from `start`, in one pass (NumPy's subtract and cumsum take
    two, the cumsum unvectorised)."""
    acc = start
    for i in range(x.size):
        acc += x[i] - offset
        out[i] = acc
