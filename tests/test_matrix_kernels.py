"""The compiled matrix helpers of `oracle-kf` against their NumPy/SciPy definitions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag

from cooploc._matrix_kernels import congruence_blocks, mirror_lower


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
