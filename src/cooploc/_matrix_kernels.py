"""Compiled helpers for dense symmetric matrices (`oracle-kf`'s component update).

Each is one pass in compiled code where the array forms cost several passes, index
arrays of the matrix's size, or a sort: mirroring a triangle (LAPACK's inverses fill
one), the block-diagonal congruence F P Fᵀ of the prediction, copying the blocks of an
index partition out of a matrix and back (`take_lower`, `take_block`,
`place_partition`: runs of consecutive indices, an entity's coordinates, copied as
contiguous stretches), a dense matrix times a sparse one given by its entries, summing
duplicate entries, and checking finiteness and the positive definiteness of diagonal
blocks.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cooploc._gaussian_kernels import cholesky_into

TILE = 32   # rows and columns of a tile of `mirror_lower` (16–64 alike at 640 rows, 128 slower)


@njit(cache=True, nogil=True)
def mirror_lower(a: np.ndarray) -> None:
    """Copy the lower triangle of the square Fortran-ordered `a` onto its upper one, in place.

    Tile by tile, the loop writes down the columns of the upper triangle (a[j, i], j < i,
    contiguous in a Fortran-ordered array) and reads along the rows of the lower one:
    a strided read costs less than a strided write, and within a tile the lines read
    stay in cache. Reading down the columns and writing along the rows instead (the
    previous loop) took 2.6× as long at 640 rows (0.57 against 0.22 ms) and 1.5× at 820
    (0.42 against 0.28 ms); at 476 rows the two were alike.
    """
    n = a.shape[0]
    for j0 in range(0, n, TILE):
        for i0 in range(j0, n, TILE):
            for i in range(max(i0, j0 + 1), min(i0 + TILE, n)):
                for j in range(j0, min(j0 + TILE, i)):
                    a[j, i] = a[i, j]


@njit(cache=True, nogil=True)
def congruence_blocks(P: np.ndarray, start: np.ndarray, size: np.ndarray, F: np.ndarray,
                      out: np.ndarray) -> None:
    """out = F P Fᵀ for a symmetric P and a block-diagonal F, F[e] (its top-left
    size[e] × size[e]) the block of entity e, whose state starts at start[e].

    Two passes along contiguous rows, O(D² d) operations against the D³ of a dense
    product: T = F P on the lower block triangle (block row b times F_b, a row operation
    that vectorizes), then out = F Tᵀ on the upper one (F P Fᵀ = F (F P)ᵀ for a
    symmetric P): row i of block a reads the d_a entries of block column a of each row
    of T (four-dimensional blocks written out, the common case), and the upper triangle
    is mirrored onto the lower, so `out` is exactly symmetric. About 2× faster than
    computing each block F_a P_ab F_bᵀ with its two small products (2.0 → 1.0–1.3 ms for
    163 blocks of 4); the sums are associated differently (relative change ~1e-16).
    """
    n = start.size
    D = P.shape[0]
    T = np.empty((D, D))
    for b in range(n):                       # T = F P, rows of block b up to its last column
        sb, db = start[b], size[b]
        end = sb + db
        for j in range(db):
            row = T[sb + j]
            for c in range(end):
                row[c] = 0.0
            for m in range(db):
                f = F[b, j, m]
                src = P[sb + m]
                for c in range(end):
                    row[c] += f * src[c]
    for a in range(n):                       # out[rows of a, c] = F_a T[c, columns of a], c ≥ start of a
        sa, da = start[a], size[a]
        if da == 4:
            f00, f01, f02, f03 = F[a, 0, 0], F[a, 0, 1], F[a, 0, 2], F[a, 0, 3]
            f10, f11, f12, f13 = F[a, 1, 0], F[a, 1, 1], F[a, 1, 2], F[a, 1, 3]
            f20, f21, f22, f23 = F[a, 2, 0], F[a, 2, 1], F[a, 2, 2], F[a, 2, 3]
            f30, f31, f32, f33 = F[a, 3, 0], F[a, 3, 1], F[a, 3, 2], F[a, 3, 3]
            o0, o1, o2, o3 = out[sa], out[sa + 1], out[sa + 2], out[sa + 3]
            for c in range(sa, D):
                t0, t1, t2, t3 = T[c, sa], T[c, sa + 1], T[c, sa + 2], T[c, sa + 3]
                o0[c] = f00 * t0 + f01 * t1 + f02 * t2 + f03 * t3
                o1[c] = f10 * t0 + f11 * t1 + f12 * t2 + f13 * t3
                o2[c] = f20 * t0 + f21 * t1 + f22 * t2 + f23 * t3
                o3[c] = f30 * t0 + f31 * t1 + f32 * t2 + f33 * t3
        else:
            for i in range(da):
                o = out[sa + i]
                for c in range(sa, D):
                    acc = 0.0
                    for k in range(da):
                        acc += F[a, i, k] * T[c, sa + k]
                    o[c] = acc
    mirror_lower(out.T)                      # out.T is Fortran-ordered: its lower triangle is out's upper



@njit(cache=True, nogil=True)
def _runs(idx: np.ndarray) -> np.ndarray:
    """Where the runs of consecutive values of the ascending `idx` start, and its length
    last: run k is idx[at[k]:at[k + 1]], the values idx[at[k]], idx[at[k]] + 1, …"""
    if idx.size == 0:
        return np.zeros(1, np.int64)
    count = 1
    for k in range(1, idx.size):
        if idx[k] != idx[k - 1] + 1:
            count += 1
    at = np.empty(count + 1, np.int64)
    at[0], m = 0, 1
    for k in range(1, idx.size):
        if idx[k] != idx[k - 1] + 1:
            at[m] = k
            m += 1
    at[count] = idx.size
    return at


@njit(cache=True, nogil=True)
def take_lower(P: np.ndarray, E: np.ndarray, out: np.ndarray) -> None:
    """The lower triangle of P[E][:, E] into the Fortran-ordered `out` (r × r), P symmetric
    and E ascending.

    Column j of `out` is read from row E[j] of P (P[E[i], E[j]] = P[E[j], E[i]]), run by
    run of consecutive indices in E (an entity's coordinates, neighbouring entities): copies
    of contiguous stretches, where NumPy's ``P[np.ix_(E, E)]`` builds index arrays and reads both triangles.
    """
    at = _runs(E)
    for j in range(E.size):
        row = P[E[j]]
        for k in range(at.size - 1):
            first, end = max(at[k], j), at[k + 1]
            shift = E[first] - first
            for i in range(first, end):     # a loop, not a slice: a slice costs ~30 ns to set up
                out[i, j] = row[i + shift]


@njit(cache=True, nogil=True)
def take_block(P: np.ndarray, rows: np.ndarray, cols: np.ndarray, out: np.ndarray) -> None:
    """out = P[rows][:, cols] (C-ordered), `cols` ascending; contiguous copies run by run."""
    at = _runs(cols)
    for i in range(rows.size):
        src, dst = P[rows[i]], out[i]
        for k in range(at.size - 1):
            shift = cols[at[k]] - at[k]
            for m in range(at[k], at[k + 1]):
                dst[m] = src[m + shift]


@njit(cache=True, nogil=True)
def _put_row(dst: np.ndarray, idx: np.ndarray, at: np.ndarray, src: np.ndarray) -> None:
    """dst[idx] = src, run by run of `at` (`_runs(idx)`)."""
    for k in range(at.size - 1):
        shift = idx[at[k]] - at[k]
        for m in range(at[k], at[k + 1]):
            dst[m + shift] = src[m]


@njit(cache=True, nogil=True)
def place_partition(out: np.ndarray, E: np.ndarray, u: np.ndarray, yy: np.ndarray, uy: np.ndarray,
                    uu: np.ndarray) -> None:
    """Fill the symmetric `out` (D × D, C-ordered) from the blocks of a partition of its
    indices into the ascending E and u (together every index once): out[E, E] = yy,
    out[u, E] = uy, out[E, u] = uyᵀ, out[u, u] = uu; row by row, each row of `out`
    written once, run by run of consecutive indices."""
    at_E, at_u = _runs(E), _runs(u)
    uy_T = np.ascontiguousarray(uy.T)
    for i in range(E.size):
        dst = out[E[i]]
        _put_row(dst, E, at_E, yy[i])
        _put_row(dst, u, at_u, uy_T[i])
    for i in range(u.size):
        dst = out[u[i]]
        _put_row(dst, E, at_E, uy[i])
        _put_row(dst, u, at_u, uu[i])


@njit(cache=True, nogil=True)
def sparse_product(A: np.ndarray, i: np.ndarray, j: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A J (C-ordered) for J given by its entries, J[i[k], j[k]] = values[k] (duplicates
    summed, every other entry zero): column j[k] of the product gains values[k] times
    column i[k] of A, built in its transpose so that both are rows."""
    A_T = np.ascontiguousarray(A.T)
    out_T = np.zeros((A.shape[1], A.shape[0]))
    for k in range(values.size):
        src, dst, v = A_T[i[k]], out_T[j[k]], values[k]
        for m in range(src.size):
            dst[m] += v * src[m]
    return np.ascontiguousarray(out_T.T)


@njit(cache=True, nogil=True)
def sum_duplicates(idx: np.ndarray, values: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(the distinct entries of `idx` ascending, the sum of `values` at each), every idx in
    [0, size): each sum in the order of `values`, as ``np.bincount`` adds, in two passes
    over a dense array of `size` (sorting idx, ``np.unique``, took ≈ 1.5× longer at
    25 000 entries of 300 000)."""
    sums = np.zeros(size)
    seen = np.zeros(size, np.bool_)
    count = 0
    for k in range(idx.size):
        sums[idx[k]] += values[k]
        if not seen[idx[k]]:
            seen[idx[k]] = True
            count += 1
    out_idx, out_sums = np.empty(count, np.int64), np.empty(count)
    m = 0
    for p in range(size):
        if seen[p]:
            out_idx[m], out_sums[m] = p, sums[p]
            m += 1
    return out_idx, out_sums


@njit(cache=True, nogil=True)
def all_finite(a: np.ndarray) -> bool:
    """Whether every entry of the 2-d `a` is finite: one pass (x · 0 is NaN exactly where x
    is not), no boolean array of a's size as ``np.isfinite(a).all()`` makes."""
    nonfinite = 0.0
    for i in range(a.shape[0]):
        row = a[i]
        for j in range(row.size):
            nonfinite += row[j] * 0.0
    return nonfinite == 0.0


@njit(cache=True, nogil=True)
def blocks_positive_definite(cov: np.ndarray, start: np.ndarray, dim: int) -> bool:
    """Whether each diagonal block cov[s:s + dim, s:s + dim], s in `start`, is positive
    definite: its Cholesky factorisation (`_gaussian_kernels.cholesky_into`, of the lower
    triangle, as LAPACK's) finds every pivot > 0, NaN not, in place, where a batched
    ``np.linalg.cholesky`` first gathers the blocks. `cholesky_into` lets a NaN through
    (NaN factors); a NaN anywhere in the block's lower triangle reaches a diagonal entry
    of L, so the diagonal is checked as well. (numba caches this function with this file:
    a change of `cholesky_into` reaches a cached build only when this file changes too.)"""
    L = np.empty((dim, dim))
    for s in start:
        if not cholesky_into(cov[s:s + dim, s:s + dim], L):
            return False
        for j in range(dim):
            if not L[j, j] > 0.0:
                return False
    return True
