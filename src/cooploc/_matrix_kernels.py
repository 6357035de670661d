"""Compiled helpers for dense symmetric matrices (`oracle-kf`'s component update).

LAPACK's Cholesky inverse (potri) fills one triangle; copying it onto the other is one
pass in compiled code, where the array forms (index lists of a triangle, or masked
copies) cost several passes and an index array of D²/2 entries per call.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def mirror_lower(a: np.ndarray) -> None:
    """Copy the lower triangle of the square Fortran-ordered `a` onto its upper one, in place.

    Column j of a Fortran-ordered array is contiguous, so the loop reads down the
    columns (a[i, j], i > j) and writes along the rows of the transpose.
    """
    n = a.shape[0]
    for j in range(n):
        for i in range(j + 1, n):
            a[j, i] = a[i, j]


@njit(cache=True, nogil=True)
def congruence_blocks(P: np.ndarray, start: np.ndarray, size: np.ndarray, F: np.ndarray,
                      out: np.ndarray) -> None:
    """out = F P Fᵀ for a symmetric P and a block-diagonal F, F[e] (its top-left
    size[e] × size[e]) the block of entity e, whose state starts at start[e].

    Block (a, b) of the result is F_a P_ab F_bᵀ: 2 d³ operations per block, one read of
    P and one write of out, against the D² d of a dense product and its transposed
    copies. Each block is computed once and written to (a, b) and (b, a), so `out` is
    exactly symmetric.
    """
    n = start.size
    tmp = np.empty((F.shape[1], F.shape[2]))
    for a in range(n):
        sa, da = start[a], size[a]
        for b in range(a, n):
            sb, db = start[b], size[b]
            for i in range(da):                               # tmp = F_a P_ab
                for m in range(db):
                    acc = 0.0
                    for k in range(da):
                        acc += F[a, i, k] * P[sa + k, sb + m]
                    tmp[i, m] = acc
            for i in range(da):                               # (F_a P_ab) F_bᵀ
                for j in range(db):
                    acc = 0.0
                    for m in range(db):
                        acc += tmp[i, m] * F[b, j, m]
                    out[sa + i, sb + j] = acc
                    out[sb + j, sa + i] = acc
