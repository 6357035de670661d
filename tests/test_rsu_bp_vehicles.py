"""The vehicle side of the unknown-feature `rsu-bp` against closed forms and brute force.

- β of a gated row–feature pair (`FeatureTracker._gate`) equals the Monte Carlo average
  of N(z; H f − H x, W) over samples of both Gaussian beliefs (the paper's particle sum,
  eq. (14), with many particles).
- `VehicleMessages.gaussian` weights a message's component by its evidence under the
  belief: for one message with one component and a miss term, the share equals the
  posterior probability of that component, computed here with SciPy; a decimetre row
  whose implied position lies 2 m from a 3 m track is used, not ignored.
- `VehicleMessages.log_mu` equals a per-vehicle loop over the groups; `subset` gives the
  same messages as the full set for the vehicles kept.
- `posterior_samples` (defensive importance sampling with the refined second draw) gives
  the exact Gaussian posterior of a track and precise single-association rows.
"""

from __future__ import annotations

import numpy as np

from cooploc.estimators.rsu_bp import RsuBPParams
from cooploc.estimators.rsu_bp.tracking import FeatureTracker, _Features
from cooploc.estimators.rsu_bp.vehicles import VehicleMessages, posterior_samples
from cooploc.gaussian import Gaussians, kf_update
from cooploc.particles import Particles, weighted_moments
from cooploc.registry import get_preset
from cooploc.types import Batch, StateSet

H = np.eye(4)           # the V2F rows of the city scenes observe position and velocity


def _tracker() -> FeatureTracker:
    """A tracker on the setup of a preset without a feature prior (position-velocity V2F)."""
    preset = get_preset("brambilla-crossroad")
    setup = preset.generate(np.random.default_rng(0), preset.params.with_overrides({"n_steps": 2})).setup
    return FeatureTracker(setup, RsuBPParams(), 0.0)


def test_closed_form_beta_equals_the_particle_average() -> None:
    rng = np.random.default_rng(11)
    tracker = _tracker()
    f_mean, f_cov = np.array([10.0, 5.0, 0.0, 0.0]), np.diag([0.3, 0.2, 0.05, 0.05])
    tracker.features = _Features(np.array([7]), f_mean[None], f_cov[None], np.array([0.9]))
    x_mean, x_cov = np.array([1.0, 2.0, 3.0, 0.5]), np.diag([1.5, 2.0, 0.1, 0.1])
    W = np.diag([0.01, 0.01, 0.02, 0.02])
    z = f_mean - x_mean + np.array([0.8, -0.5, 0.1, 0.05])
    v2f = Batch(z[None], W[None], np.array([3]), np.array([-1]))
    rows, feats, log_beta = tracker._gate(v2f, np.array([0]), (x_mean @ H.T)[None], (H @ x_cov @ H.T)[None])
    assert rows.tolist() == [0] and feats.tolist() == [0]
    # brute force: mean over samples of both beliefs of N(z; H f − H x, W)
    n = 400_000
    f = rng.multivariate_normal(f_mean, f_cov, n)
    x = rng.multivariate_normal(x_mean, x_cov, n)
    r = z - (f - x) @ H.T
    log_w = -0.5 * (4 * np.log(2 * np.pi) + np.linalg.slogdet(W)[1]
                    + np.einsum("ni,ij,nj->n", r, np.linalg.inv(W), r))
    estimate = np.log(np.mean(np.exp(log_w)))
    # the Monte Carlo mean has a relative standard error of ≈ 1 % at this size
    np.testing.assert_allclose(log_beta[0], estimate, atol=0.05)


def _one_message(offset: np.ndarray, cov: np.ndarray, coef: float, miss: float) -> VehicleMessages:
    return VehicleMessages(1, H, np.array([0]), np.array([0]), np.array([0]), offset[None], cov[None],
                           np.array([np.log(coef)]), np.array([np.log(miss)]))


def test_gaussian_shares_are_the_components_posterior_probabilities() -> None:
    from scipy.stats import multivariate_normal

    mean, cov = np.zeros(4), np.diag([9.0, 9.0, 0.04, 0.04])
    C = np.diag([0.01, 0.01, 0.01, 0.01])
    implied = np.array([2.0, -1.0, 0.1, 0.0])           # where the row puts the vehicle: H x = −a
    msg = _one_message(-implied, C, coef=0.5, miss=1e-3)
    got = msg.gaussian(mean[None], cov[None])
    # posterior weight of the component in N(x; x̄, P) (miss + c N(a + H x; 0, C))
    evidence = 0.5 * multivariate_normal(np.zeros(4), C + H @ cov @ H.T).pdf(-implied + mean)
    share = evidence / (evidence + 1e-3)
    assert share > 0.9                                   # the row should dominate here
    lam = np.linalg.inv(cov) + share * H.T @ np.linalg.inv(C) @ H
    eta = np.linalg.inv(cov) @ mean + share * H.T @ np.linalg.inv(C) @ implied
    np.testing.assert_allclose(got.mean[0], np.linalg.solve(lam, eta), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got.cov[0], np.linalg.inv(lam), rtol=1e-9, atol=1e-12)
    assert np.linalg.norm(got.mean[0, :2] - implied[:2]) < 0.1


def test_gaussian_evaluated_at_a_given_point() -> None:
    """With `at` the exact posterior, a lone component's share is ≈ 1 and the result is it."""
    mean, cov = np.zeros(4), np.diag([225.0, 225.0, 0.04, 0.04])
    C = 0.01 * np.eye(4)
    implied = np.array([20.0, -10.0, 0.1, 0.0])
    msg = _one_message(-implied, C, coef=0.5, miss=1e-3)
    exact = kf_update(Gaussians(mean[None], cov[None]), implied[None], H, C[None])
    got = msg.gaussian(mean[None], cov[None], at=exact)
    np.testing.assert_allclose(got.mean, exact.mean, atol=1e-6)


def _random_messages(rng: np.random.Generator) -> VehicleMessages:
    S, G = 3, 5
    group_vehicle = np.array([0, 0, 1, 2, 2])
    group = np.array([0, 0, 1, 2, 2, 2, 3, 4])        # sorted by group, as the tracker makes them
    vehicle = group_vehicle[group]
    P = group.size
    root = rng.normal(size=(P, 4, 4))
    return VehicleMessages(S, H, vehicle, group, group_vehicle, rng.normal(size=(P, 4)),
                           root @ np.swapaxes(root, 1, 2) + np.eye(4), rng.normal(size=P),
                           np.log(rng.uniform(0.01, 0.5, G)))


def test_log_mu_equals_a_loop_over_groups() -> None:
    from cooploc.gaussian import gaussian_logpdf

    rng = np.random.default_rng(3)
    msg = _random_messages(rng)
    samples = rng.normal(size=(3, 40, 4))
    want = np.zeros((3, 40))
    for g in range(msg.log_miss.size):
        pairs = np.flatnonzero(msg.group == g)
        s = msg.group_vehicle[g]
        terms = msg.log_coef[pairs, None] + gaussian_logpdf(msg.offset[pairs, None] + samples[s] @ H.T,
                                                            msg.cov[pairs, None])
        total = np.logaddexp(msg.log_miss[g], np.logaddexp.reduce(terms, axis=0))
        want[s] += total - total.max()
    np.testing.assert_allclose(msg.log_mu(samples), want, rtol=1e-10, atol=1e-10)


def test_subset_keeps_the_messages_of_the_vehicles_kept() -> None:
    rng = np.random.default_rng(4)
    msg = _random_messages(rng)
    samples = rng.normal(size=(3, 40, 4))
    keep = np.array([True, False, True])
    np.testing.assert_array_equal(msg.subset(keep).log_mu(samples[keep]), msg.log_mu(samples)[keep])
    mean, cov = rng.normal(size=(3, 4)), np.broadcast_to(4.0 * np.eye(4), (3, 4, 4))
    np.testing.assert_allclose(msg.subset(keep).gaussian(mean[keep], cov[keep]).mean,
                               msg.gaussian(mean, cov).mean[keep], rtol=1e-12)


def test_posterior_samples_reach_the_exact_posterior() -> None:
    """A 15 m track and three decimetre rows, each of one known, certain feature: the
    posterior is the Kalman update with the three rows; the particles' moments match it."""
    rng = np.random.default_rng(8)
    prior_mean, prior_cov = np.array([0.0, 0.0, 1.0, 0.0]), np.diag([225.0, 225.0, 0.2, 0.2])
    implied = np.array([[12.0, -9.0, 1.1, 0.05], [12.1, -9.05, 1.05, 0.0], [11.95, -8.9, 1.12, 0.02]])
    C = np.broadcast_to(np.diag([0.04, 0.04, 0.01, 0.01]), (3, 4, 4)).copy()
    msg = VehicleMessages(1, H, np.zeros(3, np.int64), np.arange(3), np.zeros(3, np.int64), -implied, C,
                          np.log(np.full(3, 0.99)), np.log(np.full(3, 1e-6)))
    own = StateSet(np.array([5]), prior_mean[None], prior_cov[None])
    samples, log_w = posterior_samples(own, msg, 600, rng)
    exact = Gaussians(prior_mean[None], prior_cov[None])
    for j in range(3):
        exact = kf_update(exact, implied[j][None], H, C[j][None])
    mean, cov = weighted_moments(Particles(samples, log_w))
    sd = np.sqrt(np.diag(exact.cov[0]))
    # 600 weighted particles: the mean within half a posterior standard deviation
    assert (np.abs(mean[0] - exact.mean[0]) < 0.5 * sd).all(), (mean, exact.mean, sd)
    np.testing.assert_allclose(np.sqrt(np.diag(cov[0])), sd, rtol=0.35)
