"""`icp-da-pf`'s compiled message sums against G of eq. (18) built and multiplied in plain NumPy."""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.estimators.icp.particle_bp import _PairLikelihoods
from cooploc.particles import pair_kernel


def _dense_g(kernel, blk_pair: np.ndarray, coef: np.ndarray, missed: np.ndarray) -> np.ndarray:
    """G[q, f, v] = max(Σ_{b ∈ q} coef_b kernel_b[f, v] + missed_q, 1e-300), the definition."""
    G = np.zeros((missed.size, *kernel.values.shape[1:]))
    for b in range(blk_pair.size):                        # the blocks of a pair in their order
        G[blk_pair[b]] += coef[b] * (np.exp(kernel.log_scale[b])[:, None] * kernel.values[b].astype(float))
    return np.maximum(G + missed[:, None, None], 1e-300)


def _case(rng: np.random.Generator, Jf: int, Jv: int, far: bool = False):
    B, d = 7, 4
    blk_pair = np.array([2, 0, 2, 1, 3, 2, 0])             # pairs with 1–3 blocks, out of order
    offset = 40.0 if far else 0.0                          # far: most kernel values underflow to 0
    kernel = pair_kernel(rng.normal(size=(B, d)) + offset, np.repeat(np.eye(d)[None], B, 0) * 2.0,
                         rng.normal(size=(B, Jf, d)), rng.normal(size=(B, Jv, d)))
    coef = rng.uniform(0.1, 3.0, B)
    missed = np.array([0.0, 0.3, 0.0, 0.9])
    return kernel, blk_pair, coef, missed


@pytest.mark.parametrize(("Jf", "Jv", "far"), [(9, 9, False), (13, 21, False), (16, 5, True)])
def test_message_sums_equal_the_dense_products(rng: np.random.Generator, Jf: int, Jv: int, far: bool) -> None:
    kernel, blk_pair, coef, missed = _case(rng, Jf, Jv, far)
    G = _dense_g(kernel, blk_pair, coef, missed)
    pairs = _PairLikelihoods(kernel, blk_pair, coef, missed)
    w_v = rng.uniform(0.0, 1.0, (missed.size, Jv))
    w_f = rng.uniform(0.0, 1.0, (missed.size, Jf))
    # the same float64 G elements; only the order of the J-term sums differs from einsum's
    # (positive terms: a few units in the last place)
    rtol = 1e-13
    np.testing.assert_allclose(pairs.sum_over_vehicles(w_v), np.einsum("qfv,qv->qf", G, w_v), rtol=rtol)
    np.testing.assert_allclose(pairs.sum_over_features(w_f), np.einsum("qfv,qf->qv", G, w_f), rtol=rtol)


def test_message_sums_see_every_element(rng: np.random.Generator) -> None:
    """A unit weight on one particle picks one row or column of G exactly."""
    kernel, blk_pair, coef, missed = _case(rng, 11, 10)
    G = _dense_g(kernel, blk_pair, coef, missed)
    pairs = _PairLikelihoods(kernel, blk_pair, coef, missed)
    for v in (0, 7, 9):                                    # inside the 8-wide sums and in the tail
        w = np.zeros((missed.size, 10))
        w[:, v] = 1.0
        np.testing.assert_array_equal(pairs.sum_over_vehicles(w), G[:, :, v])
    for f in (0, 10):
        w = np.zeros((missed.size, 11))
        w[:, f] = 1.0
        np.testing.assert_array_equal(pairs.sum_over_features(w), G[:, f, :])
