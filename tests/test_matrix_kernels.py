"""The compiled matrix helpers of `oracle-kf` against their NumPy/SciPy definitions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag

from cooploc._matrix_kernels import (
    all_finite,
    blocks_positive_definite,
    congruence_blocks,
    mirror_lower,
    place_partition,
    sparse_product,
    sum_duplicates,
    take_block,
    take_lower,
)


def index_sets(rng: np.random.Generator, D: int, kind: str) -> np.ndarray:
    """An ascending index set of [0, D): runs of an entity's four coordinates, single
    scattered indices, all of them, or one."""
    if kind == "entities":
        entities = np.flatnonzero(rng.random(D // 4) < 0.7)
        return (4 * entities[:, None] + np.arange(4)).ravel()
    if kind == "scattered":
        return np.sort(rng.choice(D, D // 2, replace=False))
    return np.arange(D) if kind == "all" else np.array([D - 1])


@pytest.mark.parametrize("n", [1, 2, 7, 64, 65, 200])
def test_mirror_lower_copies_the_lower_triangle_up(n: int) -> None:
    a = np.asfortranarray(np.random.default_rng(n).standard_normal((n, n)))
    lower = np.tril(a).copy()
    mirror_lower(a)
    np.testing.assert_array_equal(np.tril(a), lower)
    np.testing.assert_array_equal(a, a.T)


@pytest.mark.parametrize("sizes", [[4], [4, 4, 4], [4, 2, 2, 4, 2], [2, 4, 3, 1], [4, 2] * 30 + [4] * 20])
def test_congruence_blocks_equals_the_dense_product(sizes: list[int]) -> None:
    rng = np.random.default_rng(len(sizes))
    D, dmax = sum(sizes), max(sizes)
    A = rng.standard_normal((D, D))
    P = A @ A.T + np.eye(D)
    blocks = [rng.standard_normal((d, d)) for d in sizes]
    F = np.zeros((len(sizes), dmax, dmax))
    for e, block in enumerate(blocks):
        F[e, :block.shape[0], :block.shape[1]] = block
    start = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    out = np.empty_like(P)
    congruence_blocks(P, start, np.array(sizes, dtype=np.int64), F, out)
    F_dense = block_diag(*blocks)
    np.testing.assert_allclose(out, F_dense @ P @ F_dense.T, rtol=1e-12, atol=1e-12 * np.abs(P).max())
    np.testing.assert_array_equal(out, out.T)   # the upper triangle mirrored


KINDS = ["entities", "scattered", "all", "one"]


@pytest.mark.parametrize("kind", KINDS)
def test_take_lower_and_take_block_are_fancy_indexing(kind: str) -> None:
    rng = np.random.default_rng(KINDS.index(kind))
    D = 60
    A = rng.standard_normal((D, D))
    P = A + A.T
    E = index_sets(rng, D, kind)
    G = np.full((E.size, E.size), np.nan, order="F")
    take_lower(P, E, G)
    np.testing.assert_array_equal(np.tril(G), np.tril(P[np.ix_(E, E)]))
    assert np.isnan(G[np.triu_indices(E.size, 1)]).all()     # the upper triangle untouched
    rows = rng.permutation(D)[:7]
    out = np.empty((rows.size, E.size))
    take_block(P, rows, E, out)
    np.testing.assert_array_equal(out, P[np.ix_(rows, E)])
    none = np.zeros(0, np.int64)
    take_block(P, rows, none, np.empty((rows.size, 0)))         # no columns: nothing to copy
    take_lower(P, none, np.empty((0, 0), order="F"))


@pytest.mark.parametrize("kind", ["entities", "scattered", "one"])
def test_place_partition_inverts_the_blocks_of_a_partition(kind: str) -> None:
    rng = np.random.default_rng(10 + KINDS.index(kind))
    D = 64
    A = rng.standard_normal((D, D))
    P = A + A.T
    E = index_sets(rng, D, kind)
    u = np.setdiff1d(np.arange(D), E)
    out = np.full((D, D), np.nan)
    place_partition(out, E, u, P[np.ix_(E, E)], P[np.ix_(u, E)], P[np.ix_(u, u)])
    np.testing.assert_array_equal(out, P)


def test_sparse_product_sums_duplicate_entries() -> None:
    rng = np.random.default_rng(20)
    r = 30
    i, j = rng.integers(0, r, 200), rng.integers(0, r, 200)     # with repeated (i, j)
    values = rng.standard_normal(200)
    J = np.zeros((r, r))
    np.add.at(J, (i, j), values)
    A = rng.standard_normal((9, r))
    np.testing.assert_allclose(sparse_product(A, i, j, values), A @ J, rtol=1e-13, atol=1e-13)


def test_sum_duplicates_is_unique_and_bincount() -> None:
    rng = np.random.default_rng(21)
    idx = rng.integers(0, 500, 3000)
    values = rng.standard_normal(3000)
    distinct, sums = sum_duplicates(idx, values, 500)
    expected, inverse = np.unique(idx, return_inverse=True)
    np.testing.assert_array_equal(distinct, expected)
    np.testing.assert_array_equal(sums, np.bincount(inverse, values))   # the same order of sums
    empty = sum_duplicates(np.zeros(0, np.int64), np.zeros(0), 10)
    assert empty[0].size == 0 and empty[1].size == 0


@pytest.mark.parametrize("dim", [1, 2, 4])
def test_blocks_positive_definite_agrees_with_numpy_cholesky(dim: int) -> None:
    rng = np.random.default_rng(30 + dim)
    n = 12
    for trial in range(40):
        cov = rng.standard_normal((n * dim, n * dim))
        cov = cov @ cov.T / (n * dim) - (0.9 * rng.random() if trial % 2 else 0.0) * np.eye(n * dim)
        start = np.sort(rng.choice(n, 5, replace=False)) * dim
        blocks = np.stack([cov[s:s + dim, s:s + dim] for s in start])
        try:
            np.linalg.cholesky(blocks)
            expected = True
        except np.linalg.LinAlgError:
            expected = False
        assert blocks_positive_definite(cov, start, dim) == expected
    cov = np.eye(3 * dim)
    cov[dim, dim] = np.nan
    assert not blocks_positive_definite(cov, np.array([0, dim]), dim)


def test_all_finite_is_isfinite_all() -> None:
    a = np.random.default_rng(40).standard_normal((30, 31))
    assert all_finite(a)
    for bad in (np.nan, np.inf, -np.inf):
        b = a.copy()
        b[17, 3] = bad
        assert not all_finite(b)
    assert all_finite(np.zeros((0, 0)))
