"""The compiled loops of `rsu-bp`'s separable pair kernel (`rsu_bp.kernel`; numba, imported on first use).

`separable_rows` fills E = exp(x − max_l x) per (vehicle, feature) and gives β's sums
over the vehicle particles while a row of E is in cache; `separable_columns` gives μ's
sums over the feature particles. Both accumulate in float64 (the stored kernel's sums,
`particles.PairKernel`, are in `cooploc._particle_kernels`). The exponentials are
`cooploc._expf.exp_inplace` (float32, within 2 ulp), compiled into `separable_rows`:
numba's cache of this module is keyed on this file alone, so a change of `_expf.py`
reaches a cached build only once this file changes too.
"""

from __future__ import annotations

import numba
import numpy as np

from cooploc._expf import exp_inplace
from cooploc._particle_kernels import row_min

__all__ = ["separable_columns", "separable_rows"]


@numba.njit(parallel=True, fastmath=True, cache=True)
def separable_rows(A: np.ndarray, C: np.ndarray, blocks: np.ndarray, mask: np.ndarray,
                   w: np.ndarray, compute: bool, E: np.ndarray, r: np.ndarray,
                   sums: np.ndarray) -> None:
    """The row sums of the separable form (`rsu_bp.kernel`), E computed first if `compute`.

    A (G, N_j, d), C (G, d, N_l): whitened particles of each group; blocks, mask (G, M):
    its blocks; w (B, N_l) the blocks' scaled weights. With `compute`, fills
    E[g, j, l] = exp(x_gjl − r[g, j]) (float32, `exp_inplace`), x_gjl = A_gj · C_gl and
    r[g, j] = max_l x_gjl (float64); then sums[b, j] = Σ_l w[b, l] E[g, j, l] (float64)
    for every block b of group g, while E's row is in cache.
    """
    G, Nj, d = A.shape
    Nl = C.shape[2]
    M = blocks.shape[1]
    for g in numba.prange(G):
        neg = np.empty(Nl)
        for j in range(Nj):
            row = E[g, j]
            if compute:
                for l in range(Nl):
                    neg[l] = 0.0
                for e in range(d):
                    ae = A[g, j, e]
                    for l in range(Nl):
                        neg[l] -= ae * C[g, e, l]                 # −x_jl
                top = -row_min(neg)
                r[g, j] = top
                for l in range(Nl):
                    row[l] = np.float32(-neg[l] - top)
                exp_inplace(row)
            for m in range(M):
                if not mask[g, m]:
                    continue
                b = blocks[g, m]
                acc = 0.0
                for l in range(Nl):
                    acc += w[b, l] * np.float64(row[l])
                sums[b, j] = acc


@numba.njit(parallel=True, fastmath=True, cache=True)
def separable_columns(E: np.ndarray, blocks: np.ndarray, mask: np.ndarray, w: np.ndarray,
                      sums: np.ndarray) -> None:
    """sums[b, l] = Σ_j w[b, j] E[g, j, l] (float64) for every block b of every group g."""
    G, Nj, Nl = E.shape
    M = blocks.shape[1]
    for g in numba.prange(G):
        acc = np.zeros((M, Nl))
        for j in range(Nj):
            for m in range(M):
                if not mask[g, m]:
                    continue
                wj = w[blocks[g, m], j]
                if wj == 0.0:
                    continue
                for l in range(Nl):
                    acc[m, l] += wj * np.float64(E[g, j, l])
        for m in range(M):
            if mask[g, m]:
                for l in range(Nl):
                    sums[blocks[g, m], l] = acc[m, l]
