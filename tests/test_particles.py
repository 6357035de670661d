"""Particle building blocks against independent references.

- the pair kernel against `scipy.stats.multivariate_normal` in a direct double loop and
  against the plain NumPy broadcast;
- systematic resampling: exact counts (each particle appears ⌊N w⌋ or ⌈N w⌉ times);
- moments against NumPy's weighted `np.cov`; ESS analytic values.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp
from scipy.stats import multivariate_normal

from cooploc.errors import InvalidInputError
from cooploc.particles import (
    Particles,
    effective_sample_size,
    normalize_log_weights,
    pair_kernel,
    pair_kernel_log_sum,
    pair_kernel_numpy,
    propagate_linear,
    resample,
    sample_gaussians,
    shrinkage_move,
    systematic_resample,
    weighted_moments,
)
from helpers import assert_covariance_close

# float32 kernel values (24-bit mantissa, sums of ≤ 10 terms): relative 1e-5
FLOAT32_RTOL = 1e-5
# float64 paths: round-off only
FLOAT64_RTOL = 1e-10


def kernel_case(rng: np.random.Generator, B: int = 3, Nj: int = 5, Nl: int = 7, d: int = 2):
    z = rng.normal(size=(B, d))
    A = rng.normal(size=(B, d, d))
    cov = A @ A.transpose(0, 2, 1) + 0.5 * np.eye(d)
    return z, cov, rng.normal(size=(B, Nj, d)), rng.normal(size=(B, Nl, d))


def direct_kernel(z, cov, a, c) -> np.ndarray:
    B, Nj, Nl = a.shape[0], a.shape[1], c.shape[1]
    out = np.empty((B, Nj, Nl))
    for b in range(B):
        for j in range(Nj):
            for l in range(Nl):
                out[b, j, l] = multivariate_normal(a[b, j] - c[b, l], cov[b]).pdf(z[b])
    return out


@pytest.mark.parametrize("d", [1, 2, 3])
def test_pair_kernel_matches_a_direct_double_loop(d: int, rng: np.random.Generator) -> None:
    z, cov, a, c = kernel_case(rng, d=d)
    ref = direct_kernel(z, cov, a, c)
    np.testing.assert_allclose(pair_kernel(z, cov, a, c).dense(), ref, rtol=FLOAT32_RTOL)
    np.testing.assert_allclose(pair_kernel_numpy(z, cov, a, c), ref, rtol=FLOAT64_RTOL)


def test_kernel_sums_both_ways(rng: np.random.Generator) -> None:
    z, cov, a, c = kernel_case(rng)
    ref = direct_kernel(z, cov, a, c)
    wl, wj = rng.random((3, 7)), rng.random((3, 5))
    G = pair_kernel(z, cov, a, c)
    np.testing.assert_allclose(np.exp(G.log_sum_over_second(wl)), np.einsum("bjl,bl->bj", ref, wl),
                               rtol=FLOAT32_RTOL)
    np.testing.assert_allclose(np.exp(G.log_sum_over_first(wj)), np.einsum("bjl,bj->bl", ref, wj),
                               rtol=FLOAT32_RTOL)
    # the fused float64 sum, and the swapped call for the other axis
    np.testing.assert_allclose(np.exp(pair_kernel_log_sum(z, cov, a, c, wl)),
                               np.einsum("bjl,bl->bj", ref, wl), rtol=FLOAT64_RTOL)
    np.testing.assert_allclose(np.exp(pair_kernel_log_sum(-z, cov, c, a, wj)),
                               np.einsum("bjl,bj->bl", ref, wj), rtol=FLOAT64_RTOL)


def test_kernel_keeps_range_far_in_the_tail(rng: np.random.Generator) -> None:
    # every pair 40σ away: float32 exp would underflow, the row scale keeps the value
    z, cov = np.zeros((1, 2)), np.eye(2)[None]
    a = np.full((1, 3, 2), 40.0) + rng.normal(0, 0.1, (1, 3, 2))
    c = rng.normal(0, 0.1, (1, 4, 2))
    log_pairs = np.array([[multivariate_normal(a[0, j] - c[0, l], cov[0]).logpdf(z[0])
                           for l in range(4)] for j in range(3)])
    ref = logsumexp(log_pairs, axis=1)[None]
    np.testing.assert_allclose(pair_kernel(z, cov, a, c).log_sum_over_second(np.ones((1, 4))), ref,
                               rtol=1e-6)


@pytest.mark.parametrize("offset", [5e5, 5.7e6])
def test_kernel_is_as_precise_far_from_the_origin(offset: float, rng: np.random.Generator) -> None:
    """UTM / ECEF magnitudes: translating both particle sets changes no kernel value.

    The reference is the same kernel near the origin (translation cancels in a − c); the
    stored kernel keeps its float32 tolerance, the fused sum its float64 one.
    """
    z, cov, a, c = kernel_case(rng)
    shift = np.array([offset, -0.7 * offset])
    near = direct_kernel(z, cov, a, c)
    far = pair_kernel(z, cov, a + shift, c + shift).dense()
    np.testing.assert_allclose(far, near, rtol=FLOAT32_RTOL)
    w = rng.random((3, 7))
    np.testing.assert_allclose(pair_kernel_log_sum(z, cov, a + shift, c + shift, w),
                               np.log(np.einsum("bjl,bl->bj", near, w)), rtol=FLOAT64_RTOL, atol=1e-9)


def test_kernel_rejects_bad_shapes() -> None:
    with pytest.raises(InvalidInputError, match="pair kernel"):
        pair_kernel(np.zeros((2, 2)), np.eye(2)[None], np.zeros((2, 3, 2)), np.zeros((2, 3, 2)))


def test_empty_kernel() -> None:
    G = pair_kernel(np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros((0, 5, 2)), np.zeros((0, 5, 2)))
    assert G.values.shape == (0, 5, 5)


@settings(max_examples=50, deadline=None)
@given(n=st.integers(1, 4), N=st.integers(1, 40), seed=st.integers(0, 2**32 - 1))
def test_systematic_resampling_counts(n: int, N: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    lw, _ = normalize_log_weights(rng.normal(0, 3, size=(n, N)))
    idx = systematic_resample(lw, rng)
    assert idx.shape == (n, N) and idx.min() >= 0 and idx.max() < N
    counts = np.stack([np.bincount(i, minlength=N) for i in idx])
    expected = N * np.exp(lw)
    # systematic resampling gives every particle ⌊N w⌋ or ⌈N w⌉ copies
    assert (counts >= np.floor(expected - 1e-9)).all() and (counts <= np.ceil(expected + 1e-9)).all()


def test_resample_gives_equal_weights_and_keeps_the_rest(rng: np.random.Generator) -> None:
    p = Particles(rng.normal(size=(2, 50, 3)), normalize_log_weights(rng.normal(size=(2, 50)))[0])
    out = resample(p, rng, which=np.array([True, False]))
    np.testing.assert_allclose(out.log_weights[0], -np.log(50))
    np.testing.assert_array_equal(out.samples[1], p.samples[1])
    np.testing.assert_array_equal(out.log_weights[1], p.log_weights[1])


def test_shrinkage_move_keeps_moments_and_restores_diversity(rng: np.random.Generator) -> None:
    # a collapsed belief: 20 000 copies of 4 distinct states (velocity-like spread)
    base = rng.normal(size=(4, 3)) * np.array([1.0, 2.0, 0.5])
    copies = base[rng.integers(0, 4, 20_000)]
    p = Particles(np.stack([copies, copies]), np.full((2, 20_000), -np.log(20_000)))
    out = shrinkage_move(p, rng, which=np.array([True, False]))
    assert np.unique(out.samples[0], axis=0).shape[0] == 20_000      # diversity back
    np.testing.assert_array_equal(out.samples[1], p.samples[1])       # not selected
    np.testing.assert_array_equal(out.log_weights, p.log_weights)
    mean, cov = weighted_moments(Particles(p.samples[:1], p.log_weights[:1]))
    new_mean, new_cov = weighted_moments(Particles(out.samples[:1], out.log_weights[:1]))
    # the move keeps mean and covariance in expectation (Monte Carlo tolerance)
    scale = np.sqrt(np.diag(cov[0]))
    np.testing.assert_allclose(new_mean[0], mean[0], atol=0.05 * scale.max())
    np.testing.assert_allclose(new_cov[0], cov[0], atol=0.05 * np.outer(scale, scale).max())


def test_normalize_and_ess() -> None:
    with np.errstate(divide="ignore"):
        log_zero_row, log_one_hot = np.log([0.0, 0.0, 0.0]), np.log([1.0, 0, 0, 0])
    lw, total = normalize_log_weights(np.stack([np.log([1.0, 1.0, 2.0]), log_zero_row]))
    np.testing.assert_allclose(np.exp(lw[0]), [0.25, 0.25, 0.5])
    assert total[0] == pytest.approx(np.log(4.0))
    # all-zero weights come back uniform with total −inf, never NaN
    lw2, total2 = normalize_log_weights(np.full((1, 4), -np.inf))
    np.testing.assert_allclose(np.exp(lw2), 0.25)
    assert total2[0] == -np.inf
    np.testing.assert_allclose(effective_sample_size(np.stack([np.log([0.25] * 4), log_one_hot])),
                               [4.0, 1.0])


def test_weighted_moments_match_numpy(rng: np.random.Generator) -> None:
    x = rng.normal(size=(1, 200, 3))
    w = rng.random(200)
    p = Particles(x, np.log(w / w.sum())[None])
    mean, cov = weighted_moments(p, min_variance=0.0)
    np.testing.assert_allclose(mean[0], np.average(x[0], axis=0, weights=w), rtol=1e-12)
    np.testing.assert_allclose(cov[0], np.cov(x[0].T, aweights=w, bias=True), rtol=1e-6)


def test_degenerate_belief_still_has_a_positive_definite_covariance() -> None:
    x = np.repeat(np.array([[[1.0, 2.0]]]), 10, axis=1)
    lw = np.full((1, 10), -np.inf)
    lw[0, 3] = 0.0
    _, cov = weighted_moments(Particles(x, lw))
    assert (np.linalg.eigvalsh(cov) > 0).all()


def test_sampling_and_propagation(rng: np.random.Generator) -> None:
    mean, cov = np.array([[1.0, -1.0]]), np.array([[[2.0, 0.5], [0.5, 1.0]]])
    p = sample_gaussians(mean, cov, 20000, rng)
    assert_covariance_close(p.samples[0], cov[0], mean[0])
    F, Q = np.array([[1.0, 0.5], [0.0, 1.0]]), np.diag([0.1, 0.2])
    q = propagate_linear(p, F, Q, rng)
    assert_covariance_close(q.samples[0], F @ cov[0] @ F.T + Q, F @ mean[0])


def test_particles_validate_shapes() -> None:
    with pytest.raises(InvalidInputError, match="Particles"):
        Particles(np.zeros((2, 3)), np.zeros((2, 3)))
