"""Compiled loops over the agents' copies of the tracks (`gaussian_bp._FeatureCopies`,
numba, imported on use): copying kept copies into a re-indexed block and resetting the
copies an agent did not get, in place, without the (n, F, r) temporaries that NumPy's
fancy indexing and boolean masks make (fresh memory is slow to touch on a loaded
machine). Plain copies and zeros: the values are bitwise those of the NumPy form.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["copy_copies", "reset_missing"]


@numba.njit(cache=True)
def copy_copies(source: np.ndarray, rows_from: np.ndarray, cols_from: np.ndarray, target: np.ndarray,
                rows_to: np.ndarray, cols_to: np.ndarray) -> None:
    """target[rows_to[a], cols_to[f]] = source[rows_from[a], cols_from[f]] for every a, f
    (`target[np.ix_(rows_to, cols_to)] = source[np.ix_(rows_from, cols_from)]`)."""
    r = source.shape[2]
    for a in range(rows_to.size):
        i, j = rows_from[a], rows_to[a]
        for f in range(cols_to.size):
            k, m = cols_from[f], cols_to[f]
            for c in range(r):
                target[j, m, c] = source[i, k, c]


@numba.njit(cache=True)
def reset_missing(block: np.ndarray, have: np.ndarray) -> None:
    """block[~have] = 0 for a block (n, F, r) and a mask (n, F)."""
    n, F, r = block.shape
    for i in range(n):
        for f in range(F):
            if not have[i, f]:
                for c in range(r):
                    block[i, f, c] = 0.0
