"""Compiled Cholesky-based solves on stacks of small symmetric positive definite matrices
(`cooploc.gaussian`; numba, imported on use).

`np.linalg` calls LAPACK once per matrix of a stack, with checks and copies around each
call: on stacks of 2 × 2 and 4 × 4 matrices that overhead, not the arithmetic, is the
cost (≈ 1 µs per matrix; a city step of `icp-da-lc` converts some 10⁵). These loops do
the textbook arithmetic of each matrix in place:

- Cholesky A = L Lᵀ (Golub & Van Loan, Alg. 4.2.1, the column form), reading the
  lower triangle of A as LAPACK's potrf('L') does; a pivot ≤ 0 marks the matrix as not
  positive definite (`ok[i] = False`), where `np.linalg.cholesky` raises, and a NaN
  pivot gives NaN results without failing, as `np.linalg.cholesky` does;
- L⁻¹ by forward substitution, A⁻¹ = L⁻ᵀ L⁻¹ (exactly symmetric: each entry is computed
  once and written to both triangles);
- A⁻¹ b by forward and back substitution;
- log N(r; 0, A) = −½ (d log 2π + 2 Σ log L_jj + |L⁻¹ r|²).

Same formulas as the NumPy/LAPACK forms they replace; the sums run in another order, so
results agree to round-off (relative 1e-13 on random and ill-conditioned stacks,
tests/test_gaussian_kernels.py), not bit for bit. Inputs are C-contiguous float64
stacks (n, d, d) and (n, d); the callers flatten the batch dimensions.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["cholesky_stack", "inverse_and_product", "logpdf_stack", "solve_stack"]

_LOG_2PI = math.log(2.0 * math.pi)


@njit(cache=True, nogil=True)
def cholesky_into(A: np.ndarray, L: np.ndarray) -> bool:
    """L (d, d) ← the lower Cholesky factor of A (its lower triangle read); False where a
    pivot is ≤ 0 (L then partly written). NaN entries give NaN factors, not False."""
    d = A.shape[0]
    for j in range(d):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if s <= 0.0:                          # NaN passes on, as in LAPACK's potrf here
            return False
        ljj = math.sqrt(s)
        L[j, j] = ljj
        for i in range(j + 1, d):
            t = A[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / ljj
        for i in range(j):
            L[i, j] = 0.0
    return True


@njit(cache=True, nogil=True)
def cholesky_solve_into(L: np.ndarray, b: np.ndarray, x: np.ndarray) -> None:
    """x ← (L Lᵀ)⁻¹ b for a Cholesky factor L (d, d), b and x (d,)."""
    d = L.shape[0]
    for i in range(d):                        # L y = b
        t = b[i]
        for k in range(i):
            t -= L[i, k] * x[k]
        x[i] = t / L[i, i]
    for i in range(d - 1, -1, -1):            # Lᵀ x = y
        t = x[i]
        for k in range(i + 1, d):
            t -= L[k, i] * x[k]
        x[i] = t / L[i, i]


@njit(cache=True, nogil=True)
def _inverse_into(L: np.ndarray, W: np.ndarray, out: np.ndarray) -> None:
    """out ← (L Lᵀ)⁻¹ = L⁻ᵀ L⁻¹, W (d, d) scratch for L⁻¹."""
    d = L.shape[0]
    for j in range(d):                        # column j of L⁻¹, forward substitution
        for i in range(j):
            W[i, j] = 0.0
        W[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, d):
            t = 0.0
            for k in range(j, i):
                t -= L[i, k] * W[k, j]
            W[i, j] = t / L[i, i]
    for i in range(d):                        # (L⁻ᵀ L⁻¹)_ij = Σ_k W_ki W_kj, k ≥ max(i, j)
        for j in range(i + 1):
            t = 0.0
            for k in range(i, d):
                t += W[k, i] * W[k, j]
            out[i, j] = t
            out[j, i] = t


@njit(cache=True, nogil=True)
def cholesky_stack(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower Cholesky factors of A (n, d, d) and which matrices were positive definite (n,)."""
    n, d = A.shape[0], A.shape[1]
    L = np.zeros((n, d, d))
    ok = np.empty(n, dtype=np.bool_)
    for m in range(n):
        ok[m] = cholesky_into(A[m], L[m])
    return L, ok


@njit(cache=True, nogil=True)
def inverse_and_product(A: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A⁻¹ (n, d, d), A⁻¹ v (n, d) as the matrix A⁻¹ times v, and which A were positive
    definite (n,): (P, m) ↔ (Λ, η) of `to_information` / `from_information`."""
    n, d = A.shape[0], A.shape[1]
    inv = np.zeros((n, d, d))
    prod = np.zeros((n, d))
    ok = np.empty(n, dtype=np.bool_)
    L = np.empty((d, d))
    W = np.empty((d, d))
    for m in range(n):
        ok[m] = cholesky_into(A[m], L)
        if not ok[m]:
            continue
        _inverse_into(L, W, inv[m])
        for i in range(d):
            t = 0.0
            for j in range(d):
                t += inv[m, i, j] * v[m, j]
            prod[m, i] = t
    return inv, prod, ok


@njit(cache=True, nogil=True)
def solve_stack(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A⁻¹ b (n, d) for positive definite A (n, d, d), by Cholesky, and which A were (n,)."""
    n, d = A.shape[0], A.shape[1]
    x = np.zeros((n, d))
    ok = np.empty(n, dtype=np.bool_)
    L = np.empty((d, d))
    for m in range(n):
        ok[m] = cholesky_into(A[m], L)
        if ok[m]:
            cholesky_solve_into(L, b[m], x[m])
    return x, ok


@njit(cache=True, nogil=True)
def logpdf_stack(r: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """log N(r; 0, A) of residuals r (n, d) and covariances A (n, d, d), and which A were
    positive definite (n,)."""
    n, d = A.shape[0], A.shape[1]
    out = np.zeros(n)
    ok = np.empty(n, dtype=np.bool_)
    L = np.empty((d, d))
    w = np.empty(d)
    for m in range(n):
        ok[m] = cholesky_into(A[m], L)
        if not ok[m]:
            continue
        log_det = 0.0
        q = 0.0
        for i in range(d):
            t = r[m, i]
            for k in range(i):
                t -= L[i, k] * w[k]
            w[i] = t / L[i, i]                # L⁻¹ r
            log_det += math.log(L[i, i])
            q += w[i] * w[i]
        out[m] = -0.5 * (d * _LOG_2PI + 2.0 * log_det + q)
    return out, ok
