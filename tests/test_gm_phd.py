"""`gm-phd` against Stone Soup's GM-PHD, and its update and merging against the equations.

Stone Soup (dstl) is a test-only dependency (`dev` extra). Its GM-PHD differs from
Vo & Ma 2006 in two places, so the comparison runs where they cannot matter:
`merge_threshold = 0` (Stone Soup caps a merged weight at 1), no cap on the number of
components (Stone Soup rescales the weights it keeps after truncation; Vo & Ma do not)
and p_S = 1 (Stone Soup applies p_S inside its update, also at the first step where we
do not predict). Stone Soup also spreads the weight it prunes (each below T = 1e-5)
evenly over the survivors; the weights are compared with a tolerance of that order, over
the first 4 steps (later, the spread weight lifts different components over T, and the
two mixtures stop having the same components).
"""

from __future__ import annotations

import numpy as np
import pytest
import stonesoup  # noqa: F401  (a test dependency: installed by the dev extra, never skipped)
from scipy.optimize import linear_sum_assignment
from scipy.stats import multivariate_normal

from cooploc.estimators.gm_phd import (
    GMPHD,
    GMPHDParams,
    Mixture,
    extract_count,
    merge_components,
    phd_update,
)
from cooploc.scenarios import get_preset
from cooploc.types import Frame, Recording
from stonesoup_reference import stonesoup_reference

AGREE = 1e-7  # relative: the same equations in a different order of floating-point operations
PRUNED_MASS = 1e-4  # absolute, weights: Stone Soup redistributes pruned weight (< T = 1e-5 each)


@pytest.fixture(scope="module")
def recording(seed: int) -> Recording:
    preset = get_preset("zhang2016-cv")
    return preset.generate(np.random.default_rng([seed, 9]), preset.params.with_overrides({"n_steps": 4}))


def test_matches_stone_soup(recording: Recording) -> None:
    params = GMPHDParams(survival_probability=1.0, merge_threshold=0.0, max_components=100_000)
    reference, _ = stonesoup_reference(recording, params)
    ours = GMPHD(recording.setup, params, np.random.default_rng(0))
    for frame, (w_ref, m_ref) in zip(recording.frames, reference, strict=True):
        ours.step(frame)
        mixture = ours.mixture
        w = np.exp(mixture.log_w)
        assert w.size == w_ref.size, frame.k
        # match components by state (their orders differ), then compare weights and means
        cost = ((mixture.mean[:, None] - m_ref[None]) ** 2).sum(-1)
        rows, cols = linear_sum_assignment(cost)
        np.testing.assert_allclose(mixture.mean[rows], m_ref[cols], rtol=AGREE, atol=AGREE)
        np.testing.assert_allclose(w[rows], w_ref[cols], rtol=0, atol=PRUNED_MASS)


def test_update_weights_follow_vo_ma(rng: np.random.Generator) -> None:
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    prior = Mixture(np.log([0.7, 0.4]), rng.normal(size=(2, 4)), np.stack([np.eye(4), 2 * np.eye(4)]))
    z = rng.normal(size=(3, 2))
    R = np.repeat(0.5 * np.eye(2)[None], 3, 0)
    p_d, kappa = 0.9, 0.05
    out = phd_update(prior, z, R, H, p_d, kappa)
    w = np.exp(out.log_w)
    np.testing.assert_allclose(w[:2], (1 - p_d) * np.array([0.7, 0.4]), rtol=1e-12)
    q = np.array([[multivariate_normal.pdf(zi, H @ m, H @ P @ H.T + 0.5 * np.eye(2)) for zi in z]
                  for m, P in zip(prior.mean, prior.cov, strict=True)])        # (J, M)
    expected = p_d * np.array([0.7, 0.4])[:, None] * q / (kappa + p_d * (np.array([0.7, 0.4]) @ q))
    np.testing.assert_allclose(w[2:], expected.T.ravel(), rtol=1e-10)       # eq. (26), row-major by z


def test_merge_is_moment_matching(rng: np.random.Generator) -> None:
    means = np.array([[0.0, 0, 0, 0], [0.1, 0, 0, 0], [50.0, 0, 0, 0]])
    covs = np.repeat(np.eye(4)[None], 3, 0)
    weights = np.array([0.6, 0.3, 0.5])
    merged = merge_components(Mixture(np.log(weights), means, covs), 1e-5, 4.0, 100)
    assert len(merged) == 2
    heavy = np.argmax(np.exp(merged.log_w))
    w = weights[:2] / weights[:2].sum()
    mean = w @ means[:2]
    spread = means[:2] - mean
    cov = np.eye(4) + np.einsum("g,gi,gj->ij", w, spread, spread)
    np.testing.assert_allclose(np.exp(merged.log_w[heavy]), 0.9, rtol=1e-12)
    np.testing.assert_allclose(merged.mean[heavy], mean, rtol=1e-12)
    np.testing.assert_allclose(merged.cov[heavy], cov, rtol=1e-12)


def test_cap_is_per_label_where_components_are_labelled(rng: np.random.Generator) -> None:
    # 30 vehicles of 3 far-apart components each, J_max = 2: anonymous, the 2 heaviest of
    # all survive; labelled, the 2 heaviest of every vehicle (none is dropped whole)
    means = np.zeros((90, 4))
    means[:, 0] = 100.0 * np.arange(90)
    covs = np.repeat(np.eye(4)[None], 90, 0)
    log_w = np.log(rng.uniform(0.1, 1.0, 90))
    labels = np.repeat(np.arange(30) * 7 + 3, 3)
    anonymous = merge_components(Mixture(log_w, means, covs), 1e-5, 4.0, 2)
    np.testing.assert_array_equal(np.sort(anonymous.log_w), np.sort(log_w)[-2:])
    labelled = merge_components(Mixture(log_w, means, covs, labels), 1e-5, 4.0, 2)
    np.testing.assert_array_equal(np.unique(labelled.labels, return_counts=True)[1], np.full(30, 2))
    for v in np.unique(labels):
        np.testing.assert_array_equal(np.sort(labelled.log_w[labelled.labels == v]),
                                      np.sort(log_w[labels == v])[-2:])


def test_extracts_one_belief_per_vehicle_even_when_targets_merge(recording: Recording) -> None:
    est = GMPHD(recording.setup, GMPHDParams(), np.random.default_rng(0))
    est.step(recording.frames[0])
    # force one component of weight 2 and one of weight 0.4: the heavy one is picked twice
    est.mixture = Mixture(np.log([2.0, 0.4]), np.array([[1.0, 2, 0, 0], [9.0, 9, 0, 0]]),
                          np.repeat(np.eye(4)[None], 2, 0))
    estimate = est._extract(Frame(5, 5.0, np.array([0, 1, 2])))
    np.testing.assert_array_equal(estimate.vehicles.mean[:, 0], [1.0, 1.0, 9.0])
    assert estimate.info["set_valued"] and estimate.info["n_extracted_vo_ma"] == 2
    assert estimate.info["cardinality"] == pytest.approx(2.4)


def test_extraction_covers_two_crossing_pairs(recording: Recording) -> None:
    """Two pairs of vehicles crossing at once (zhang2016-cv run 12, step 50): each pair is
    two components of unequal weight; every pair must get two picks, the lone vehicle one
    (the rule before picked the 1.476 twice and left the right pair one estimate short)."""
    est = GMPHD(recording.setup, GMPHDParams(), np.random.default_rng(0))
    est.step(recording.frames[0])
    weights = [1.476, 1.471, 1.01, 0.543, 0.469]
    positions = [[-75.4, 51.0], [75.5, 49.5], [-1.3, 150.5], [-75.3, 50.7], [74.9, 50.1]]
    means = np.array([[x, y, 0.0, 0.0] for x, y in positions])
    est.mixture = Mixture(np.log(weights), means, np.repeat((0.37 * np.eye(4))[None], 5, 0))
    estimate = est._extract(Frame(50, 50.0, np.arange(5)))
    x = estimate.vehicles.mean[:, 0]
    # two picks at each crossing (x = ±75), one at the lone vehicle (x ≈ 0)
    assert (x < -70).sum() == 2 and (x > 70).sum() == 2 and (np.abs(x) < 5).sum() == 1


def test_extract_count_is_heaviest_first_for_separated_components() -> None:
    """Far-apart components of weight about 1 each: the n heaviest, once each (sorted)."""
    w = np.array([0.7, 1.0, 0.9, 0.2])
    means = np.array([[0.0, 0, 0, 0], [100, 0, 0, 0], [0, 100, 0, 0], [100, 100, 0, 0]])
    mixture = Mixture(np.log(w), means, np.repeat(np.eye(4)[None], 4, 0))
    np.testing.assert_array_equal(extract_count(mixture, 3, np.array([0, 1]), 4.0), [0, 1, 2])
