"""The compiled loops of `cooploc.particles.pair_kernel` (numba; imported on first use).

For every block b and particle pair (j, l) with whitened u = L⁻¹(z − a) and
v = L⁻¹ c, the exponent of N(z_b; a_{b,j} − c_{b,l}, W_b) is −½‖u_bj + v_bl‖²:

- `kernel_matrix` stores exp(−½ (q_bjl − min_l q_bjl)) in float32 with the row shift
  (the exponentials by `cooploc._expf.exp_inplace`: float32, vectorized, within 2 ulp;
  ``np.exp`` would call the C library's scalar `expf` here one element at a time);
- `kernel_sum` returns log Σ_l w_bl exp(log_norm_b − ½ q_bjl) in float64 without
  storing the pairs;
- `row_sums` / `column_sums` are the weighted sums of the stored values over l and over
  j (`PairKernel.log_sum_over_second` / `_first`). Both read the values once and
  accumulate in float64: a float32 matrix–vector product (BLAS) does the same work, but
  its multiplications see the kernel's subnormal values (and weights spanning many
  decades, cast to float32), and each such product takes the processor's slow path; in
  float64 a float32 subnormal is an ordinary number. A zero weight skips its row in
  `column_sums`.

Both run a `prange` loop over (b, j) whose inner loops over l are contiguous.
"""

from __future__ import annotations

import numba
import numpy as np

from cooploc._expf import exp_inplace
from cooploc.types import FloatArray

__all__ = ["column_sums", "kernel_matrix", "kernel_sum", "row_sums"]


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
