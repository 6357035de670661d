"""The compiled loops of `cooploc.particles.pair_kernel` (numba; imported on first use).

For every block b and particle pair (j, l) with whitened u = L⁻¹(z − a) and
v = L⁻¹ c, the exponent of N(z_b; a_{b,j} − c_{b,l}, W_b) is −½‖u_bj + v_bl‖²:

- `kernel_matrix` stores exp(−½ (q_bjl − min_l q_bjl)) in float32 with the row shift
  (the exponentials by `cooploc._expf.exp_inplace`: vectorized, and bit for bit the
  C library's `expf` that ``np.exp`` calls here one element at a time);
- `kernel_sum` returns log Σ_l w_bl exp(log_norm_b − ½ q_bjl) in float64 without
  storing the pairs.

Both run a `prange` loop over (b, j) whose inner loops over l are contiguous.
"""

from __future__ import annotations

import numba
import numpy as np

from cooploc._expf import exp_inplace
from cooploc.types import FloatArray

__all__ = ["kernel_matrix", "kernel_sum"]


@numba.njit(fastmath=True, cache=True, inline="always")
def quadratic_row(u: FloatArray, vt: FloatArray, b: int, j: int, row: np.ndarray) -> None:
    """row[l] = Σ_e (u[b, j, e] + vt[b, e, l])²: contiguous in l, so it vectorises."""
    d, Nl = vt.shape[1], vt.shape[2]
    for l in range(Nl):
        row[l] = 0.0
    for e in range(d):
        ue = u[b, j, e]
        for l in range(Nl):
            t = ue + vt[b, e, l]
            row[l] += t * t


@numba.njit(fastmath=True, cache=True, inline="always")
def row_min(row: np.ndarray) -> float:
    """min_l row[l], in 16 running minima: a single running minimum is a chain of
    dependent compares that does not vectorize (the minimum is the same in any order)."""
    n = row.size
    acc = np.empty(16, dtype=row.dtype)
    acc[:] = row[0]
    top = n - n % 16
    for l in range(0, top, 16):
        for i in range(16):
            v = row[l + i]
            acc[i] = v if v < acc[i] else acc[i]
    m = row[0]
    for i in range(16):
        m = acc[i] if acc[i] < m else m
    for l in range(top, n):
        m = row[l] if row[l] < m else m
    return m


@numba.njit(parallel=True, fastmath=True, cache=True)
def kernel_matrix(u: np.ndarray, vt: np.ndarray, out: np.ndarray, shift: FloatArray) -> None:
    """out[b, j, l] = exp(−½ (q_bjl − min_l q_bjl)) in float32; shift[b, j] = −½ min_l q_bjl."""
    B, Nj = u.shape[0], u.shape[1]
    Nl = vt.shape[2]
    half = np.float32(0.5)
    for bj in numba.prange(B * Nj):
        b = bj // Nj
        j = bj - b * Nj
        row = out[b, j]
        quadratic_row(u, vt, b, j, row)
        q_min = row_min(row)
        shift[b, j] = -0.5 * q_min
        for l in range(Nl):
            row[l] = -half * (row[l] - q_min)
        exp_inplace(row)


@numba.njit(parallel=True, fastmath=True, cache=True)
def kernel_sum(u: FloatArray, vt: FloatArray, log_norm: FloatArray, w: FloatArray,
                out: FloatArray) -> None:
    """out[b, j] = log Σ_l w[b, l] exp(log_norm[b] − ½ q_bjl), in float64, shifted by min q."""
    B, Nj = u.shape[0], u.shape[1]
    Nl = vt.shape[2]
    for bj in numba.prange(B * Nj):
        b = bj // Nj
        j = bj - b * Nj
        row = np.empty(Nl)
        quadratic_row(u, vt, b, j, row)
        q_min = row_min(row)
        acc = 0.0
        for l in range(Nl):
            acc += w[b, l] * np.exp(-0.5 * (row[l] - q_min))
        out[b, j] = log_norm[b] - 0.5 * q_min + np.log(acc)
