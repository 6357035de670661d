"""Loopy-BP data association against exact marginals by brute-force enumeration.

References: `exact_marginals` enumerates every admissible association (independent
of the BP code path); on a tree (one feature, or one measurement) BP is exact; on
loopy graphs it is an approximation, checked on well-separated cases (where loopy BP
is accurate) and for validity everywhere.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cooploc.association import (
    FLOOR,
    association_weights,
    bp_association,
    decide,
    enumerate_associations,
    exact_marginals,
    padded_groups,
)
from cooploc.errors import InvalidInputError

# BP on a tree after enough iterations equals the exact marginals up to round-off
TREE_ATOL = 1e-9
# the floors on missed/clutter weights perturb marginals by about FLOOR (relative)
FLOOR_ATOL = 1e3 * FLOOR


def random_case(rng: np.random.Generator, K: int, M: int, p_d: float = 0.8,
                clutter: float = 0.3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    log_lik = rng.normal(0.0, 2.0, size=(K, M))
    return association_weights(log_lik, p_d, clutter * np.exp(rng.normal(size=M)))


def test_enumeration_counts_every_association() -> None:
    # Σ_n C(K, n) M! / (M − n)! admissible associations of K features and M measurements
    for K, M in [(0, 3), (2, 0), (2, 3), (3, 3), (4, 2)]:
        expected = sum(math.comb(K, n) * math.perm(M, n) for n in range(min(K, M) + 1))
        hyp = enumerate_associations(K, M)
        assert hyp.shape == (expected, K)
        for a in hyp:  # no measurement used twice
            used = a[a >= 0]
            assert used.size == np.unique(used).size


def test_exact_marginals_of_a_hand_computed_case() -> None:
    # K = 1, M = 1: hypotheses {detected: ψ1}, {missed: ψ0 κ} → P(detected) = ψ1 / (ψ1 + ψ0 κ)
    psi1, psi0, kappa = 2.0, 0.5, 0.3
    exact = exact_marginals(np.log([[psi1]]), np.log([psi0]), np.log([kappa]))
    assert exact.feature[0, 0] == pytest.approx(psi1 / (psi1 + psi0 * kappa), rel=1e-12)
    bp = bp_association(np.log([[psi1]]), np.log([psi0]), np.log([kappa]), n_iterations=3)
    assert bp.feature[0, 0] == pytest.approx(exact.feature[0, 0], rel=1e-12)


@pytest.mark.parametrize(("K", "M"), [(1, 1), (1, 4), (4, 1), (1, 3), (3, 1)])
def test_bp_is_exact_on_trees(K: int, M: int, rng: np.random.Generator) -> None:
    for _ in range(20):
        log_psi, log_missed, log_clutter = random_case(rng, K, M)
        bp = bp_association(log_psi, log_missed, log_clutter, n_iterations=10)
        exact = exact_marginals(log_psi, log_missed, log_clutter)
        for part in ("feature", "missed", "measurement", "clutter"):
            np.testing.assert_allclose(getattr(bp, part), getattr(exact, part), atol=TREE_ATOL,
                                       err_msg=part)


@pytest.mark.parametrize(("p_d", "clutter"), [(1.0, 0.0), (0.9, 0.0), (1.0, 0.5), (0.7, 2.0)])
def test_bp_close_to_exact_when_well_separated(p_d: float, clutter: float,
                                               rng: np.random.Generator) -> None:
    # each feature has one clearly best measurement (likelihood ratio ≥ e^6): loopy BP
    # is then accurate to a few 1e-3
    K = M = 4
    for _ in range(10):
        perm = rng.permutation(M)
        log_lik = rng.normal(-6.0, 1.0, size=(K, M))
        log_lik[np.arange(K), perm] = rng.normal(4.0, 0.5, size=K)
        terms = association_weights(log_lik, p_d, clutter)
        bp = bp_association(*terms, n_iterations=20)
        exact = exact_marginals(*terms)
        np.testing.assert_allclose(bp.feature, exact.feature, atol=5e-3 + FLOOR_ATOL)
        np.testing.assert_allclose(bp.clutter, exact.clutter, atol=5e-3 + FLOOR_ATOL)
        np.testing.assert_array_equal(decide(bp), np.argsort(perm))  # measurement → feature


def test_one_to_one_case_is_a_valid_assignment(rng: np.random.Generator) -> None:
    # the paper's case: P_D = 1, no clutter, M = K — every feature takes one measurement;
    # loopy BP sharpens towards the most probable permutation, which it must find
    K = M = 3
    for _ in range(10):
        perm = rng.permutation(M)
        log_lik = rng.normal(0.0, 1.0, size=(K, M))
        log_lik[np.arange(K), perm] += 3.0
        terms = association_weights(log_lik, 1.0, 0.0)
        bp = bp_association(*terms, n_iterations=5)
        exact = exact_marginals(*terms)
        np.testing.assert_allclose(bp.missed, 0.0, atol=FLOOR_ATOL)
        np.testing.assert_allclose(bp.clutter, 0.0, atol=FLOOR_ATOL)
        np.testing.assert_allclose(bp.feature.sum(axis=1), 1.0, atol=FLOOR_ATOL)
        np.testing.assert_array_equal(decide(bp, 0.0, one_to_one=True),
                                      decide(exact, 0.0, one_to_one=True))


def test_loopy_bp_error_is_moderate_on_random_cases(rng: np.random.Generator) -> None:
    # dense 3×3 cases with P_D = 0.9: loopy BP is an approximation; its mean absolute
    # error over 50 cases stays between 0.05 and 0.08 over 100 seeds we tried; ignoring
    # the exclusion constraint (marginals ∝ ψ) gives ≈ 0.16, so 0.12 separates the two
    errors = []
    for _ in range(50):
        terms = association_weights(rng.normal(0.0, 1.5, size=(3, 3)), 0.9, 0.1)
        bp = bp_association(*terms, n_iterations=5)
        errors.append(np.abs(bp.feature - exact_marginals(*terms).feature).mean())
    assert np.mean(errors) < 0.12


def test_batch_with_padding_equals_one_by_one(rng: np.random.Generator) -> None:
    sizes = [(3, 2), (3, 4), (3, 0), (3, 1)]
    K, M = 3, max(m for _, m in sizes)
    log_psi = np.full((len(sizes), K, M), -np.inf)
    log_missed = np.zeros((len(sizes), K))
    log_clutter = np.full((len(sizes), M), -np.inf)
    mask = np.zeros((len(sizes), M), bool)
    singles = []
    for b, (_, m) in enumerate(sizes):
        lp, lm, lc = random_case(rng, K, m)
        log_psi[b, :, :m], log_missed[b], log_clutter[b, :m], mask[b, :m] = lp, lm, lc, True
        singles.append(bp_association(lp, lm, lc, n_iterations=5))
    batch = bp_association(log_psi, log_missed, log_clutter, n_iterations=5, measurement_mask=mask)
    for b, (_, m) in enumerate(sizes):
        np.testing.assert_allclose(batch.feature[b, :, :m], singles[b].feature, atol=1e-12)
        np.testing.assert_allclose(batch.missed[b], singles[b].missed, atol=1e-12)
        np.testing.assert_allclose(batch.clutter[b, :m], singles[b].clutter, atol=1e-12)
        assert (batch.feature[b, :, m:] == 0).all() and (batch.clutter[b, m:] == 0).all()


def test_log_nu_is_in_the_callers_scale(rng: np.random.Generator) -> None:
    # multiplying every likelihood of measurement m by c_m divides ν_{m→k} by c_m
    lp, lm, lc = random_case(rng, 3, 4)
    shift = rng.normal(size=4)
    # (at the fixed point: the start ν ≡ 1 is itself scale-dependent)
    a = bp_association(lp, lm, lc, n_iterations=1000, tol=1e-14)
    b = bp_association(lp + shift, lm, lc + shift, n_iterations=1000, tol=1e-14)
    np.testing.assert_allclose(b.log_nu, a.log_nu - shift, atol=1e-8)
    np.testing.assert_allclose(b.feature, a.feature, atol=1e-9)


def test_unexplainable_measurement_is_clutter() -> None:
    lp = np.array([[0.0, -np.inf]])
    out = bp_association(lp, np.array([np.log(0.1)]), np.array([-np.inf, -np.inf]))
    assert out.clutter[1] == pytest.approx(1.0)
    assert np.isfinite(out.feature).all() and np.isfinite(out.measurement).all()


def test_decide_threshold_and_one_to_one() -> None:
    lp = np.log(np.array([[10.0, 9.0], [1e-3, 1e-3]]))
    out = bp_association(lp, np.log([0.1, 0.1]), np.log([0.01, 0.01]), n_iterations=20)
    greedy = decide(out, threshold=0.0)
    assert greedy.shape == (2,)
    strict = decide(out, threshold=1.0)
    assert (strict == -1).all()
    one = decide(out, threshold=0.0, one_to_one=True)
    used = one[one >= 0]
    assert used.size == np.unique(used).size


def test_padded_groups() -> None:
    index, mask = padded_groups([2, 0, 2, 1, 0], 4)
    assert index.shape == mask.shape == (4, 2)
    assert index[0][mask[0]].tolist() == [1, 4]
    assert index[2][mask[2]].tolist() == [0, 2]
    assert not mask[3].any()
    with pytest.raises(InvalidInputError, match="group"):
        padded_groups([5], 2)


def test_bad_input_is_named() -> None:
    with pytest.raises(InvalidInputError, match="log_missed"):
        bp_association(np.zeros((2, 3)), np.zeros(3), np.zeros(3))
    with pytest.raises(InvalidInputError, match="n_iterations"):
        bp_association(np.zeros((2, 3)), np.zeros(2), np.zeros(3), n_iterations=0)
    with pytest.raises(InvalidInputError, match="detection_probability"):
        association_weights(np.zeros((2, 3)), 1.5, 0.0)
    with pytest.raises(InvalidInputError, match="log_psi"):
        bp_association(np.full((2, 3), np.nan), np.zeros(2), np.zeros(3))


@settings(max_examples=60, deadline=None)
@given(
    K=st.integers(0, 4), M=st.integers(0, 4), p_d=st.floats(0.05, 1.0),
    clutter=st.floats(0.0, 5.0), seed=st.integers(0, 2**32 - 1), iters=st.integers(1, 8),
    scale=st.floats(0.0, 30.0),
)
def test_marginals_are_valid_probabilities(K: int, M: int, p_d: float, clutter: float, seed: int,
                                           iters: int, scale: float) -> None:
    rng = np.random.default_rng(seed)
    log_lik = rng.normal(0.0, scale, size=(K, M))
    log_lik[rng.random((K, M)) < 0.2] = -np.inf                 # impossible pairs
    out = bp_association(*association_weights(log_lik, p_d, clutter), n_iterations=iters)
    for part in ("feature", "missed", "measurement", "clutter"):
        value = getattr(out, part)
        assert np.isfinite(value).all(), part
        assert ((value >= 0) & (value <= 1 + 1e-12)).all(), part
    np.testing.assert_allclose(out.feature.sum(axis=1) + out.missed, 1.0, atol=1e-9)
    np.testing.assert_allclose(out.measurement.sum(axis=1) + out.clutter, 1.0, atol=1e-9)
    assert (out.feature[~np.isfinite(log_lik)] == 0).all()


@settings(max_examples=30, deadline=None)
@given(K=st.integers(1, 3), M=st.integers(1, 3), seed=st.integers(0, 2**32 - 1))
def test_converged_bp_is_self_consistent(K: int, M: int, seed: int) -> None:
    # at a BP fixed point the feature-side and measurement-side marginals agree
    rng = np.random.default_rng(seed)
    out = bp_association(*random_case(rng, K, M), n_iterations=500, tol=1e-13)
    np.testing.assert_allclose(out.feature, out.measurement.T, atol=1e-6)
