"""The multiple-hypothesis filter of anonymous rows (reproduce.zhang2016_anonymous)."""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.estimators.sme.pseudo_measurement import topology_moments
from cooploc.gaussian import Gaussians, block_diagonal, kf_predict, kf_update
from cooploc.reproduce.zhang2016_anonymous import (
    AnonymousModel,
    gps_update,
    hypothesis_filter,
    permutations,
    recording_inputs,
    set_squared_errors,
    topology_update,
)

NOISE_SIGMAS = 6.0   # Monte Carlo bound in standard errors (false alarm ~1e-9)


def _model(prior_positions: np.ndarray, prior_var: float = 1.0, radar_var: float | None = 0.1
           ) -> AnonymousModel:
    n = prior_positions.shape[0]
    F = np.eye(4)
    F[0, 2] = F[1, 3] = 1.0
    Q = 0.25 * np.array([[1 / 3, 0, 1 / 2, 0], [0, 1 / 3, 0, 1 / 2], [1 / 2, 0, 1, 0], [0, 1 / 2, 0, 1]])
    mean = np.zeros((n, 4))
    mean[:, :2] = prior_positions
    mean[:, 2] = 1.0
    return AnonymousModel(F=F, Q=Q, position=np.array([0, 1]), prior_mean=mean,
                          prior_cov=np.repeat(prior_var * np.eye(4)[None], n, 0), gnss_var=0.5,
                          radar_var=radar_var)


def _prior(model: AnonymousModel) -> Gaussians:
    d = model.n * model.dx
    return Gaussians(model.prior_mean.reshape(1, d), block_diagonal(model.prior_cov)[None])


def test_gps_mixture_matches_importance_sampling(rng: np.random.Generator) -> None:
    # two vehicles 1.5 m apart: both associations weigh. The kept mixture is the exact
    # posterior of the labelled state; brute force: prior draws weighted by the symmetric
    # likelihood ½ Σ_σ N(z_σ; H x, r I), and the probability that the rows came swapped
    model = _model(np.array([[0.0, 0.0], [1.5, 0.0]]))
    rows = np.array([[1.2, 0.3], [0.1, -0.2]])
    children, log_w = gps_update(_prior(model), np.zeros(1), rows, model, permutations(2), keep=2)
    w = np.exp(log_w - np.logaddexp.reduce(log_w))
    mean = w @ children.mean
    draws = model.prior_mean.ravel() + rng.standard_normal((400_000, 8))   # prior cov = I
    p = draws[:, [0, 1, 4, 5]].reshape(-1, 2, 2)
    log_terms = np.stack([-((rows[list(s)] - p) ** 2).sum((1, 2)) / (2 * model.gnss_var)
                          for s in ((0, 1), (1, 0))], axis=1)               # (S, σ)
    weights = np.exp(np.logaddexp.reduce(log_terms, axis=1))
    weights /= weights.sum()
    reference = weights @ draws
    ess = 1.0 / (weights**2).sum()
    se = np.sqrt(weights @ (draws - reference) ** 2 / ess + 1e-12)
    assert np.all(np.abs(mean - reference) <= NOISE_SIGMAS * se), (mean, reference, se)
    # the weight of the swapped association (σ = (1, 0): vehicle 0 got row 1)
    swapped = np.exp(log_terms[:, 1] - np.logaddexp.reduce(log_terms, axis=1))
    p_swap = float(weights @ swapped)
    assert w.size == 2 and 0.05 < p_swap < 0.95
    # the child of σ = (1, 0) has vehicle 0 pulled towards row 1 (x = 0.1), the other towards row 0
    np.testing.assert_allclose(w[np.argmin(children.mean[:, 0])], p_swap,
                               atol=NOISE_SIGMAS * np.sqrt(p_swap * (1 - p_swap) / ess))


def test_far_apart_it_is_the_known_association_kalman_filter(rng: np.random.Generator) -> None:
    # 100 m apart, the wrong associations weigh exp(−10⁴): the filter is a Kalman filter
    # per vehicle given the rows' true origins, to rounding
    model = _model(np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0]]), radar_var=None)
    K = 15
    truth = model.prior_mean[None, :, :2] + np.arange(K)[:, None, None] * np.array([1.0, 0.0])
    rows = truth + np.sqrt(model.gnss_var) * rng.standard_normal(truth.shape)
    shuffled = np.array([r[rng.permutation(3)] for r in rows])
    estimates = hypothesis_filter(model, shuffled, max_hypotheses=8)
    belief = Gaussians(model.prior_mean.copy(), model.prior_cov.copy())
    H = np.eye(2, 4)
    for k in range(K):
        if k:
            belief = kf_predict(belief, model.F, model.Q)
        belief = kf_update(belief, rows[k], H, model.gnss_var * np.eye(2))
        np.testing.assert_allclose(estimates[k], belief.mean[:, :2], atol=1e-9)


def test_topology_row_is_the_kalman_update_of_its_linearization() -> None:
    model = _model(np.array([[0.0, 0.0], [10.0, 0.0], [3.0, 8.0]]))
    prior = _prior(model)
    T = 230.0
    post, log_w = topology_update(prior, np.zeros(1), T, model)
    p = model.prior_mean[:, :2]
    expected, var_T = topology_moments(p, np.full(3, model.radar_var))
    g = np.zeros(12)
    g[[0, 1, 4, 5, 8, 9]] = (6.0 * (p - p.mean(0))).ravel()              # ∇T = 2N (p_i − p̄)
    P = prior.cov[0]
    s = g @ P @ g + var_T
    gain = P @ g / s                                                      # K = P g / s
    np.testing.assert_allclose(post.mean[0], prior.mean[0] + gain * (T - expected), rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(post.cov[0], P - np.outer(gain, gain) * s, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(log_w[0], -0.5 * (np.log(2 * np.pi * s) + (T - expected) ** 2 / s))
    # a radar of variance 1e8 m² tells nothing
    blind = AnonymousModel(**{**model.__dict__, "radar_var": 1e8})
    post, _ = topology_update(prior, np.zeros(1), T, blind)
    np.testing.assert_allclose(post.mean, prior.mean, atol=1e-6)


def test_set_errors_ignore_labels(rng: np.random.Generator) -> None:
    truth = rng.normal(size=(4, 3, 2))
    estimates = truth + 0.1 * rng.normal(size=truth.shape)
    shuffled = np.array([e[rng.permutation(3)] for e in estimates])
    np.testing.assert_allclose(set_squared_errors(shuffled, truth), ((estimates - truth) ** 2).sum((1, 2)))


def test_reads_the_paper_recording(seed: int) -> None:
    from cooploc.scenarios import get_preset

    preset = get_preset("zhang2016-ct4")
    rec = preset.generate(np.random.default_rng([seed, 3]), preset.params.with_overrides({"n_steps": 12}))
    model, gnss, topology = recording_inputs(rec)
    assert gnss.shape == (12, 5, 2) and topology.shape == (12,)
    assert model.gnss_var == pytest.approx(0.5) and model.radar_var == pytest.approx(0.1)
    # T is the radar's, of the true configuration plus noise: within 6 σ of its mean
    p = rec.truth.vehicle_states[:, :, :2]
    mean, var = topology_moments(p, np.full(5, model.radar_var))
    assert np.all(np.abs(topology - mean) <= NOISE_SIGMAS * np.sqrt(var))
    errors = set_squared_errors(hypothesis_filter(model, gnss, topology, 8), p)
    assert np.all(np.isfinite(errors)) and errors.mean() < 5 * 2 * model.gnss_var


def test_topology_without_radar_variance_is_a_clear_error() -> None:
    from cooploc.errors import CooplocError

    model = _model(np.array([[0.0, 0.0], [30.0, 0.0]]), radar_var=None)
    with pytest.raises(CooplocError, match="radar_var"):
        hypothesis_filter(model, np.zeros((1, 2, 2)), np.array([1.0]))
