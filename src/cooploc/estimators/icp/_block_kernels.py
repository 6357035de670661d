"""Compiled loops over the agents' copies of the tracks (`gaussian_bp._FeatureCopies`,
numba, imported on use): copying kept copies into a re-indexed block and resetting the
copies an agent did not get, in place, without the (n, F, r) temporaries that NumPy's
fancy indexing and boolean masks make (fresh memory is slow to touch on a loaded
machine). Plain copies and zeros: the values are bitwise those of the NumPy form.

Also for the BPA-L: its messages (19)/(21) row by row (`relative_messages`, one
Cholesky factor of A + R⁻¹ per row instead of three LAPACK solves; the formulas of
`gaussian_bp.relative_message`, equal to round-off, tests/test_icp.py), a
positive-definiteness test (`positive_definite`) and `np.add.at` over rows
(`add_rows_at`: the same additions in the same order, bitwise). The message kernel
calls the Cholesky loops of `cooploc._gaussian_kernels`; numba's on-disk cache tracks
this file only, so after changing those loops delete this module's cache files
(`__pycache__/_block_kernels.*.nbi`, `.nbc`).
"""

from __future__ import annotations

import numba
import numpy as np

from cooploc._gaussian_kernels import cholesky_into, cholesky_solve_into

__all__ = ["add_rows_at", "copy_copies", "positive_definite", "relative_messages", "reset_missing"]


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


@numba.njit(cache=True, nogil=True)
def relative_messages(A: np.ndarray, a: np.ndarray, z: np.ndarray, R_inv: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`gaussian_bp.relative_message` of each row m: with C = A + R⁻¹ = L Lᵀ (Cholesky),
    Λ = A − A C⁻¹ A (symmetrised) and η = R⁻¹ C⁻¹ a + Λ z, which is (I + A R)⁻¹ a + Λ z
    since I + A R = C R. A, R_inv (m, d, d) symmetric, a, z (m, d). Returns Λ, η and
    which C were positive definite (the others are left zero)."""
    m, d = A.shape[0], A.shape[1]
    Lam = np.zeros((m, d, d))
    eta = np.zeros((m, d))
    ok = np.empty(m, dtype=np.bool_)
    C = np.empty((d, d))
    L = np.empty((d, d))
    X = np.empty((d, d))                      # C⁻¹ A, column by column
    col = np.empty(d)
    y = np.empty(d)
    for r in range(m):
        for i in range(d):
            for j in range(d):
                C[i, j] = A[r, i, j] + R_inv[r, i, j]
        ok[r] = cholesky_into(C, L)
        if not ok[r]:
            continue
        for j in range(d):
            for i in range(d):
                col[i] = A[r, i, j]
            cholesky_solve_into(L, col, y)
            for i in range(d):
                X[i, j] = y[i]
        for i in range(d):                    # Λ = A − A C⁻¹ A
            for j in range(d):
                t = 0.0
                for k in range(d):
                    t += A[r, i, k] * X[k, j]
                Lam[r, i, j] = A[r, i, j] - t
        for i in range(d):                    # symmetrise
            for j in range(i):
                s = 0.5 * (Lam[r, i, j] + Lam[r, j, i])
                Lam[r, i, j] = s
                Lam[r, j, i] = s
        cholesky_solve_into(L, a[r], y)       # C⁻¹ a
        for i in range(d):                    # η = R⁻¹ C⁻¹ a + Λ z
            t = 0.0
            for j in range(d):
                t += R_inv[r, i, j] * y[j]
            s = 0.0
            for j in range(d):
                s += Lam[r, i, j] * z[r, j]
            eta[r, i] = t + s
    return Lam, eta, ok


@numba.njit(cache=True, nogil=True)
def positive_definite(A: np.ndarray) -> np.ndarray:
    """Which of the symmetric A (m, d, d) have a Cholesky factor (m,)."""
    m, d = A.shape[0], A.shape[1]
    ok = np.empty(m, dtype=np.bool_)
    L = np.empty((d, d))
    for r in range(m):
        ok[r] = cholesky_into(A[r], L)
    return ok


@numba.njit(cache=True, nogil=True)
def add_rows_at(target: np.ndarray, index: np.ndarray, values: np.ndarray) -> None:
    """target[index[m]] += values[m] for m in order, in place: `np.add.at` on (n, r) and
    (m, r) rows, with the same additions in the same order (bitwise its result)."""
    r = target.shape[1]
    for m in range(index.size):
        i = index[m]
        for c in range(r):
            target[i, c] += values[m, c]
