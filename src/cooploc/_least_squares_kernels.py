"""The compiled loop of `cooploc.least_squares.selected_inverse` (numba; imported on first use).

Takahashi's recursion for the entries of Σ = (UᵀU)⁻¹ inside the band of the upper
Cholesky factor U, stored like LAPACK's upper banded storage (ab[u + i − j, j] = U[i, j]):

    Σ_ij = (δ_ij / U_ii − Σ_{k>i} U_ik Σ_kj) / U_ii,   j ≥ i, from the last row up.

Every Σ_kj it reads lies inside the band, because the Cholesky factor of a banded
matrix has no fill-in outside it. Cost O(n u²) for n columns and bandwidth u.
"""

from __future__ import annotations

import numba
import numpy as np

from cooploc.types import FloatArray

__all__ = ["banded_inverse"]


@numba.njit(cache=True)
def banded_inverse(U: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """Entries of Σ = (UᵀU)⁻¹ inside the band of U (u + 1, n), in the same storage."""
    u = U.shape[0] - 1
    n = U.shape[1]
    S = np.zeros_like(U)
    for i in range(n - 1, -1, -1):
        last = min(n - 1, i + u)
        d = U[u, i]
        for j in range(last, i - 1, -1):
            acc = 0.0
            for k in range(i + 1, last + 1):
                a, b = (k, j) if k <= j else (j, k)
                if b - a <= u:
                    acc += U[u + i - k, k] * S[u + a - b, b]
            S[u + i - j, j] = ((1.0 / d if j == i else 0.0) - acc) / d
    return S
