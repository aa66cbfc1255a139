"""The n-sigma rule's scan of a chunk of samples, compiled.

`calib_core.streamed.SigmaClipFill` asks of every sample whether it lies within
n_sigma * std of the record's mean; NumPy answers with five passes over the chunk (subtract,
absolute value, compare, negate, nonzero) and a temporary each. This loop reads each value
once and keeps only the indices of the few outside. Compiled by Numba (`cache=True`: once
per installation), as `calib_core.second_differences`.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, boundscheck=False)
def outside(x: np.ndarray, mean: float, limit: float) -> np.ndarray:
    """Indices (ascending) of the samples x (n,) with ``not |x - mean| <= limit``: further
    than `limit` from `mean`, or NaN (the same arithmetic as NumPy's subtract and abs)."""
    found = np.empty(x.size, dtype=np.int64)
    k = 0
    for i in range(x.size):
        if not abs(x[i] - mean) <= limit:
            found[k] = i
            k += 1
    return found[:k].copy()
