"""The compiled loop behind `icp-da-pf`'s pair likelihoods g_ik(f, v), eq. (18) (numba, imported on use).

The blocks of one vehicle–feature pair (one per soft pairing ℓ) are summed into that
pair's J × J matrix in one pass, instead of expanding every block to float64 and
scattering with `np.add.at` (which touched the J² entries of each block four times):

    G[q, f, v] = max(Σ_{b ∈ q} c_b · (s_b[f] · K_b[f, v]) + c0_q, 1e-300)

with K_b the float32 kernel values and s_b the row scales of `particles.PairKernel`,
c_b = P(α = ℓ) / η(α = ℓ) and c0_q the "not detected" mass. The blocks of a pair are
added in their order and every operation is the float64 operation NumPy did, so the
result is bitwise that of the NumPy expression (no fastmath).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["pair_matrices"]


@numba.njit(parallel=True, cache=True)
def pair_matrices(values: np.ndarray, scale: np.ndarray, coef: np.ndarray, starts: np.ndarray,
                  order: np.ndarray, missed: np.ndarray, out: np.ndarray) -> None:
    """out[q, f, v] = max(Σ_b coef[b] (scale[b, f] values[b, f, v]) + missed[q], 1e-300), b over
    order[starts[q]:starts[q + 1]], in that order."""
    Q, J, L = out.shape
    for qf in numba.prange(Q * J):
        q = qf // J
        f = qf - q * J
        row = out[q, f]
        for v in range(L):
            row[v] = 0.0
        for t in range(starts[q], starts[q + 1]):
            b = order[t]
            c = coef[b]
            s = scale[b, f]
            for v in range(L):
                row[v] += c * (s * np.float64(values[b, f, v]))
        m = missed[q]
        for v in range(L):
            row[v] = max(row[v] + m, 1e-300)
