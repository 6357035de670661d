"""The weighted sums of `rsu-bp`'s stored pair kernel, compiled (numba; imported on first use).

`particles.pair_kernel` stores G[b, j, l] = exp(log_scale[b, j]) · values[b, j, l] with
`values` float32 in [0, 1]. β and γ (Fröhle 2018 eqs. (14), (21)) need the sums over
the vehicle particles l, μ (23) the sums over the feature particles j:

    row_sums:    out[b, j] = Σ_l w[b, l] values[b, j, l]
    column_sums: out[b, l] = Σ_j w[b, j] values[b, j, l]

Both read `values` once and accumulate in float64. A float32 matrix–vector product
(BLAS) does the same work, but its multiplications see the kernel's subnormal values
(and μ's weights, which span many decades, cast to float32) and each such product
takes the processor's slow path; in float64 a float32 subnormal is an ordinary number.
The sums differ from the float32 products only by their rounding (the float64 ones are
the more accurate). Weights are ≥ 0; a zero weight skips its row in `column_sums`.
"""

from __future__ import annotations

import numba
import numpy as np

from cooploc._expf import exp_inplace
from cooploc._particle_kernels import row_min

__all__ = ["column_sums", "row_sums", "separable_columns", "separable_rows"]


@numba.njit(parallel=True, fastmath=True, cache=True)
def row_sums(values: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """out[b, j] = Σ_l w[b, l] values[b, j, l]; values (B, N_j, N_l) float32, w (B, N_l)."""
    B, Nj, Nl = values.shape
    for bj in numba.prange(B * Nj):
        b = bj // Nj
        j = bj - b * Nj
        acc = 0.0
        for l in range(Nl):
            acc += w[b, l] * np.float64(values[b, j, l])
        out[b, j] = acc


@numba.njit(parallel=True, fastmath=True, cache=True)
def column_sums(values: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """out[b, l] = Σ_j w[b, j] values[b, j, l]; values (B, N_j, N_l) float32, w (B, N_j)."""
    B, Nj, Nl = values.shape
    for b in numba.prange(B):
        acc = np.zeros(Nl)
        for j in range(Nj):
            wj = w[b, j]
            if wj == 0.0:
                continue
            for l in range(Nl):
                acc[l] += wj * np.float64(values[b, j, l])
        for l in range(Nl):
            out[b, l] = acc[l]


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
