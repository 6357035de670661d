"""`sme-pf` / `sme-ukf`: the symmetric maps, the derived pseudo-measurement noise, the filters.

Oracles: Newton's identities (the sum-of-powers map is invertible), Monte Carlo
estimates of the noise moments (bounds of 6 standard errors of the Monte Carlo mean:
a false alarm has probability ~1e-9 per entry, for any seed), the rigid-motion and
permutation invariance of the topology, and the NumPy reference of the numba kernel.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cooploc.errors import ConfigError
from cooploc.estimators import make_estimator
from cooploc.estimators.sme import (
    PseudoMeasurement,
    SmePFParams,
    SmeUKFParams,
    complex_points_from_power_sums,
    complex_power_sum_moments,
    complex_power_sums,
    gaussian_raw_moments,
    points_from_power_sums,
    power_sum_moments,
    power_sums,
    topology,
    topology_moments,
)
from cooploc.geometry import rotation
from cooploc.particles import systematic_resample
from cooploc.scenarios import get_preset
from cooploc.sensors import GnssPosition
from cooploc.types import Batch, Frame, Recording
from helpers import assert_valid_estimate, with_velocity_fixes

MC_SAMPLES = 100_000
SIGMAS = 6.0  # Monte Carlo bound in standard errors of the sample mean
ROUND_OFF = 1e-9  # relative tolerance of exact identities evaluated in float64


def assert_moments_match(samples: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> None:
    """Sample mean and covariance entries agree with the analytic ones within SIGMAS s.e."""
    n = samples.shape[0]
    se_mean = samples.std(axis=0, ddof=1) / np.sqrt(n)
    assert np.all(np.abs(samples.mean(0) - mean) <= SIGMAS * se_mean + ROUND_OFF * np.abs(mean)), (
        samples.mean(0), mean)
    centred = samples - mean                                       # analytic mean: unbiased products
    products = centred[:, :, None] * centred[:, None, :]
    se_cov = products.std(axis=0, ddof=1) / np.sqrt(n)
    assert np.all(np.abs(products.mean(0) - cov) <= SIGMAS * se_cov + ROUND_OFF * np.abs(cov)), (
        products.mean(0), cov)


def spaced_points(rng: np.random.Generator, n: int, spacing: float = 0.2) -> np.ndarray:
    """n values in [−1, 1] at least `spacing` apart (roots well conditioned)."""
    base = np.linspace(-1, 1, n) if n > 1 else np.zeros(1)
    jitter = rng.uniform(-0.5, 0.5, n) * max(2.0 / max(n - 1, 1) - spacing, 0.0)
    return rng.permutation(base + jitter)


# ----------------------------------------------------------------------------
# the symmetric maps
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 5, 6])
def test_power_sums_recover_the_measurement_set(rng: np.random.Generator, n: int) -> None:
    values = spaced_points(rng, n)
    recovered = points_from_power_sums(power_sums(values, n))
    # well-separated roots of a degree ≤ 6 polynomial: error ~ 1e-12, bound with margin
    np.testing.assert_allclose(recovered, np.sort(values), atol=1e-8)


@given(st.lists(st.floats(-3, 3), min_size=1, max_size=6), st.randoms(use_true_random=False))
@settings(max_examples=50, deadline=None)
def test_symmetric_maps_ignore_the_order(values: list[float], random) -> None:
    points = np.column_stack([values, values[::-1]])
    order = list(range(len(values)))
    random.shuffle(order)
    n = len(values)
    np.testing.assert_allclose(power_sums(points[order, 0], n), power_sums(points[:, 0], n),
                               rtol=ROUND_OFF, atol=ROUND_OFF)
    np.testing.assert_allclose(complex_power_sums(points[order], n), complex_power_sums(points, n),
                               rtol=ROUND_OFF, atol=1e-7)


@given(st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=2, max_size=6),
       st.floats(-np.pi, np.pi), st.floats(-100, 100), st.floats(-100, 100),
       st.randoms(use_true_random=False))
@settings(max_examples=60, deadline=None)
def test_topology_is_invariant_to_radar_pose_and_order(points, yaw, tx, ty, random) -> None:
    p = np.array(points, dtype=float)
    order = list(range(len(p)))
    random.shuffle(order)
    local = ((p - [tx, ty]) @ rotation(yaw))[order]               # z = R(θ)ᵀ (p − t), shuffled
    direct = sum(np.sum((p[i] - p[j]) ** 2) for i in range(len(p)) for j in range(i + 1, len(p)))
    scale = max(direct, 1.0)
    assert abs(topology(p) - direct) <= 1e-9 * scale             # eq. (18) by its double sum
    assert abs(topology(local) - topology(p)) <= 1e-9 * scale


def test_per_axis_sums_lose_the_pairing_and_complex_sums_keep_it() -> None:
    # two sets with the same x multiset and the same y multiset, paired differently
    a = np.array([[0.0, 1.0], [-1.5, 3.0], [2.0, -1.0]])
    b = np.array([[-1.5, 1.0], [0.0, 3.0], [2.0, -1.0]])
    for axis in range(2):
        np.testing.assert_allclose(power_sums(a[:, axis], 3), power_sums(b[:, axis], 3))
    assert topology(a) == pytest.approx(topology(b))              # eq. (18) cannot tell either
    assert np.abs(complex_power_sums(a, 3) - complex_power_sums(b, 3)).max() > 1.0


# ----------------------------------------------------------------------------
# the derived noise moments
# ----------------------------------------------------------------------------


def test_gaussian_raw_moments_match_the_closed_forms() -> None:
    m, s2 = 0.7, 0.3
    mu = gaussian_raw_moments(m, s2, 4)
    expected = [1, m, m**2 + s2, m**3 + 3 * m * s2, m**4 + 6 * m**2 * s2 + 3 * s2**2]
    np.testing.assert_allclose(mu, expected, rtol=ROUND_OFF)


@pytest.mark.parametrize("n", [2, 5])
def test_power_sum_noise_matches_monte_carlo(rng: np.random.Generator, n: int) -> None:
    values = spaced_points(rng, n)
    var = rng.uniform(0.005, 0.02, n)                              # per-row variances differ
    mean, cov = power_sum_moments(values, var, n)
    noisy = values + rng.standard_normal((MC_SAMPLES, n)) * np.sqrt(var)
    assert_moments_match(power_sums(noisy, n), mean, cov)
    bias = mean - power_sums(values, n)
    np.testing.assert_allclose(bias[1], var.sum(), rtol=ROUND_OFF)          # b_2 = Σ σ²
    if n >= 3:
        np.testing.assert_allclose(bias[2], 3 * np.sum(values * var), rtol=1e-7, atol=1e-12)


def test_complex_power_sum_noise_matches_monte_carlo(rng: np.random.Generator) -> None:
    n = 4
    points = rng.uniform(-1, 1, (n, 2))
    var = 0.01
    mean, cov = complex_power_sum_moments(points, var, n)
    noisy = points + rng.standard_normal((MC_SAMPLES, n, 2)) * np.sqrt(var)
    assert_moments_match(complex_power_sums(noisy, n), mean, cov)
    # circular noise: no bias at all
    np.testing.assert_allclose(mean, complex_power_sums(points, n), rtol=ROUND_OFF, atol=ROUND_OFF)


@pytest.mark.parametrize("equal", [True, False])
def test_topology_noise_matches_monte_carlo(rng: np.random.Generator, equal: bool) -> None:
    n = 5
    points = rng.uniform(-1, 1, (n, 2))
    var = np.full(n, 0.01) if equal else rng.uniform(0.005, 0.03, n)
    mean, variance = topology_moments(points, var)
    noisy = points + rng.standard_normal((MC_SAMPLES, n, 2)) * np.sqrt(var)[:, None]
    assert_moments_match(topology(noisy)[:, None], np.array([mean]), np.array([[variance]]))
    if equal:  # the closed form of docs/sme.md (topology, equal d)
        d, spread = var[0], ((points - points.mean(0)) ** 2).sum()
        assert variance == pytest.approx(4 * d**2 * n**2 * (n - 1) + 4 * n**2 * d * spread, rel=1e-12)


@pytest.mark.parametrize("form", ["axes", "complex"])
def test_numba_likelihood_equals_the_numpy_reference(rng: np.random.Generator, form: str) -> None:
    n = 5
    truth = rng.uniform(-1, 1, (n, 2))
    z = truth + 0.05 * rng.standard_normal((n, 2))
    y = complex_power_sums(z, n) if form == "complex" else np.concatenate(
        [power_sums(z[:, 0], n), power_sums(z[:, 1], n)])
    centre, scale = np.array([0.3, -0.2]), 2.0
    model = PseudoMeasurement(centre, scale, form, np.array([0.01, 0.012]), 0.002, y,
                              float(topology(z)), 1e-9)
    particles = centre + scale * (truth + 0.05 * rng.standard_normal((64, n, 2)))  # global frame
    np.testing.assert_allclose(model.log_likelihood(particles), model.log_likelihood_reference(particles),
                               rtol=1e-9, atol=1e-8)


@pytest.mark.parametrize("form", ["axes", "complex"])
def test_exact_density_equals_the_numpy_reference_and_brute_force(rng: np.random.Generator,
                                                                  form: str) -> None:
    import itertools

    n = 4
    truth = rng.uniform(-1, 1, (n, 2))
    var = np.array([0.01, 0.02])
    z = truth + np.sqrt(var) * rng.standard_normal((n, 2))
    y = complex_power_sums(z, n) if form == "complex" else np.concatenate(
        [power_sums(z[:, 0], n), power_sums(z[:, 1], n)])
    model = PseudoMeasurement(np.zeros(2), 1.0, form, var, 0.002, y, float(topology(z)), 1e-9, "exact")
    particles = truth + 0.2 * rng.standard_normal((16, n, 2))
    np.testing.assert_allclose(model.log_likelihood(particles), model.log_likelihood_reference(particles),
                               rtol=1e-9, atol=1e-8)
    # brute force: Σ over the associations of the rows as measured (z, not their recovery),
    # one per axis for eq. 17 per axis; the Jacobian and T are the same for every particle
    def log_pdf(x: np.ndarray, rows: np.ndarray, v: float) -> float:
        return float(np.sum(-0.5 * ((rows - x) ** 2 / v + np.log(2 * np.pi * v))))

    def brute(x: np.ndarray) -> float:
        perms = list(itertools.permutations(range(n)))
        if form == "complex":
            return float(np.logaddexp.reduce([log_pdf(x, z[list(s)], var) for s in perms]))
        return sum(float(np.logaddexp.reduce([log_pdf(x[:, a], z[list(s), a], var[a]) for s in perms]))
                   for a in range(2))

    gps_only = dataclasses.replace(model, y_radar=None)
    difference = gps_only.log_likelihood(particles) - np.array([brute(x) for x in particles])
    np.testing.assert_allclose(difference, difference[0], atol=1e-8)   # a constant: −log |J|


@pytest.mark.parametrize("form", ["axes", "complex"])
def test_exact_density_is_the_gaussian_one_where_the_map_is_linear(rng: np.random.Generator,
                                                                   form: str) -> None:
    # rows well apart, noise tiny against the spacing: the power sums are linear over the
    # noise, y ≈ s(x) + J w, so N(y; s(x), J R Jᵀ) = N(m − x; 0, R) / |J| — the exact density
    # with its Jacobian. Checks the constants (N!, the Vandermonde, the Gaussian's).
    n = 3
    truth = np.stack([spaced_points(rng, n, 0.5), spaced_points(rng, n, 0.5)], -1)
    var = np.full(2, 1e-8)
    z = truth + np.sqrt(var) * rng.standard_normal((n, 2))
    y = complex_power_sums(z, n) if form == "complex" else np.concatenate(
        [power_sums(z[:, 0], n), power_sums(z[:, 1], n)])
    particles = truth + 1e-4 * rng.standard_normal((8, n, 2))
    exact, gaussian = (PseudoMeasurement(np.zeros(2), 1.0, form, var, 1.0, y, None, 0.0, density)
                       .log_likelihood(particles) for density in ("exact", "gaussian"))
    # log densities ~ 40; the Gaussian's second-order terms are ~ σ / spacing ~ 1e-3 of them
    np.testing.assert_allclose(exact, gaussian, atol=0.05)


def test_complex_power_sums_recover_the_points_with_their_pairing(rng: np.random.Generator) -> None:
    n = 5
    points = np.stack([spaced_points(rng, n), spaced_points(rng, n)], -1)
    recovered = complex_points_from_power_sums(complex_power_sums(points, n))
    order = [int(np.argmin(((recovered - p) ** 2).sum(-1))) for p in points]
    # well-separated roots of a degree-5 polynomial: error ~ 1e-12, bound with margin
    np.testing.assert_allclose(recovered[order], points, atol=1e-8)


def test_systematic_resampling_keeps_the_weights(rng: np.random.Generator) -> None:
    w = rng.dirichlet(np.ones(20))
    counts = np.bincount(systematic_resample(np.log(w), rng)[0], minlength=20)   # one belief: row 0
    # systematic resampling: each count is floor or ceil of P w
    P = 20
    assert np.all(np.abs(counts - P * w) < 1.0 + 1e-12)


# ----------------------------------------------------------------------------
# the filters
# ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def short_cv(seed: int) -> Recording:
    preset = get_preset("zhang2016-cv")
    return preset.generate(np.random.default_rng([seed, 5]), preset.params.with_overrides({"n_steps": 12}))


@pytest.mark.parametrize("name, params", [("sme-pf", SmePFParams(n_particles=300)),
                                          ("sme-pf", SmePFParams(n_particles=300, rao_blackwellised=False)),
                                          ("sme-pf", SmePFParams(n_particles=300, proposal="bootstrap")),
                                          ("sme-ukf", SmeUKFParams())])
def test_filters_track_the_vehicles(name: str, params, short_cv: Recording) -> None:
    est = make_estimator(name, short_cv.setup, params, np.random.default_rng(0))
    for frame in short_cv.frames:
        estimate = est.step(frame)
        assert_valid_estimate(estimate, frame, short_cv)
        assert estimate.info["set_valued"] is True
    true = short_cv.truth.vehicle_states[-1][:, :2]
    mean = estimate.vehicles.mean[:, :2]
    from cooploc.metrics import set_errors
    # GPS σ = 0.71 m per axis: a tracking filter is within a few metres of every vehicle
    assert np.nanmax(set_errors(mean, true)) < 5.0


def test_pf_skips_an_update_whose_row_count_is_not_n(short_cv: Recording) -> None:
    frame = short_cv.frames[3]
    gnss = frame.batches["gnss"]
    short = Frame(frame.k, frame.t, frame.vehicles,
                  {"gnss": gnss.select(np.arange(len(gnss) - 1)), "radar": frame.batches["radar"]})
    est = make_estimator("sme-pf", short_cv.setup, SmePFParams(n_particles=200), np.random.default_rng(1))
    for f in short_cv.frames[:3]:
        est.step(f)
    estimate = est.step(short)
    assert estimate.info["skipped"] == ["gnss"]
    assert np.isfinite(estimate.vehicles.mean).all()


@pytest.mark.parametrize("name", ["sme-pf", "sme-ukf"])
def test_radar_rows_of_two_radars_are_not_one_topology(name: str, short_cv: Recording) -> None:
    """N radar rows that come from two radars (sumo-*'s road-side radars, each in its own
    frame) carry no joint topology (eq. 18): the radar pseudo-measurement is skipped."""
    frame = short_cv.frames[3]
    radar = frame.batches["radar"]
    sensor = radar.sensor.copy()
    sensor[: len(radar) // 2] += 1                                   # half the rows: a second radar
    split = Batch(radar.z, radar.cov, sensor, radar.subject)
    params = SmePFParams(n_particles=200) if name == "sme-pf" else SmeUKFParams()
    est = make_estimator(name, short_cv.setup, params, np.random.default_rng(1))
    for f in short_cv.frames[:3]:
        est.step(f)
    one = make_estimator(name, short_cv.setup, params, np.random.default_rng(1))
    for f in short_cv.frames[:3]:
        one.step(f)
    assert "radar" not in one.step(frame).info["skipped"]
    estimate = est.step(Frame(frame.k, frame.t, frame.vehicles, {**frame.batches, "radar": split}))
    assert estimate.info["skipped"] == ["radar"]
    assert np.isfinite(estimate.vehicles.mean).all()


def test_pf_gates_clutter_rows(short_cv: Recording) -> None:
    setup = dataclasses.replace(short_cv.setup, clutter_rate=1.0)
    est = make_estimator("sme-pf", setup, SmePFParams(n_particles=200), np.random.default_rng(1))
    for f in short_cv.frames[:3]:
        est.step(f)
    frame = short_cv.frames[3]
    gnss = frame.batches["gnss"]
    clutter = Batch(np.vstack([gnss.z, [[150.0, 300.0]]]), np.concatenate([gnss.cov, gnss.cov[:1]]),
                    np.full(len(gnss) + 1, -1), np.full(len(gnss) + 1, -1))
    estimate = est.step(Frame(frame.k, frame.t, frame.vehicles,
                              {"gnss": clutter, "radar": frame.batches["radar"]}))
    assert estimate.info["gnss_rows_gated"] == 1 and estimate.info["gnss_rows_used"] == len(gnss)
    assert "gnss" not in estimate.info["skipped"]


def test_joint_cloud_moments_are_the_per_block_weighted_moments(rng: np.random.Generator) -> None:
    # sme-pf's joint particles (P, N, dx) share one weight per particle: each block's
    # marginal is the belief (N_p = P) of `weighted_moments` with those weights
    from cooploc.particles import Particles, marginal_moments, normalize_log_weights, weighted_moments

    samples = rng.normal(size=(500, 3, 4)) * [1.0, 5.0, 0.1, 2.0]
    log_w = rng.normal(size=500) * 2.0 + 7.0                        # unnormalised on purpose
    mean, cov = marginal_moments(samples, log_w)
    normalised, _ = normalize_log_weights(log_w)
    per_block = Particles(samples.transpose(1, 0, 2), np.broadcast_to(normalised, (3, 500)))
    ref_mean, ref_cov = weighted_moments(per_block, min_variance=0.0)
    np.testing.assert_allclose(mean, ref_mean, rtol=ROUND_OFF, atol=ROUND_OFF)
    floor = 1e-9 * np.trace(cov, axis1=1, axis2=2) / 4            # weighted_moments' own floor
    np.testing.assert_allclose(cov + floor[:, None, None] * np.eye(4), ref_cov,
                               rtol=ROUND_OFF, atol=ROUND_OFF)
    np.testing.assert_array_equal(cov, np.swapaxes(cov, -1, -2))


# ----------------------------------------------------------------------------
# the linearized proposal of sme-pf (`proposal="linearized"`)
# ----------------------------------------------------------------------------


def _two_vehicle_model(rng: np.random.Generator, spacing: float) -> tuple[np.ndarray, PseudoMeasurement]:
    """Two vehicles `spacing` m apart, their GPS rows and radar topology as eq. (19) (scaled by 10 m)."""
    truth = np.array([[0.0, 0.0], [spacing, 1.0]])
    rows = truth + rng.normal(scale=np.sqrt(0.5), size=truth.shape)
    radar = truth @ rotation(0.7).T + [30.0, -4.0] + rng.normal(scale=np.sqrt(0.1), size=truth.shape)
    scale = 10.0
    model = PseudoMeasurement(np.zeros(2), scale, "complex", np.full(2, 0.5 / scale**2), 0.1 / scale**2,
                              complex_power_sums(rows / scale, 2), float(topology(radar)) / scale**2, 0.0)
    return truth, model


def test_linearized_proposal_is_the_kalman_posterior_of_its_linear_model(rng: np.random.Generator) -> None:
    # N(x; μ_j, Σ₀) N(y; H x + c, Λ) = N(y; H μ_j + c, S) N(x; μ_j⁺, Σ⁺) for every x and j: the
    # auxiliary filter's second-stage weight is then p(y | x) / N(y; H x + c, Λ) exactly
    from cooploc.estimators.sme.proposal import linearized_proposal
    from cooploc.gaussian import gaussian_logpdf

    truth, model = _two_vehicle_model(rng, 6.0)
    prior_mean = np.concatenate([truth, np.ones((2, 2))], axis=1)[None] + rng.normal(size=(7, 2, 4))
    prior_cov = np.repeat(np.diag([0.3, 0.3, 0.2, 0.2])[None], 2, axis=0)
    proposal = linearized_proposal(prior_mean, prior_cov, rng.normal(size=7), model, [0, 1], iterations=2)
    Sigma0 = np.kron(np.eye(2), prior_cov[0])
    cov_post = proposal.chol @ proposal.chol.T
    x = prior_mean + rng.normal(size=prior_mean.shape)
    lhs = (gaussian_logpdf((x - prior_mean).reshape(7, 8), Sigma0)
           + proposal.linearized_log_likelihood(x))
    rhs = proposal.log_predictive + gaussian_logpdf((x - proposal.mean).reshape(7, 8), cov_post)
    np.testing.assert_allclose(lhs, rhs, atol=1e-7, rtol=1e-9)   # float64 round-off of 8-d solves


def test_auxiliary_update_matches_brute_force_importance_sampling(rng: np.random.Generator) -> None:
    # one update of a Gaussian prior by the nonlinear pseudo-likelihood (two vehicles 2 m
    # apart: the power sums bend over the prior's spread), posterior mean of the positions:
    # the linearized auxiliary update against importance sampling from the prior with 40×
    # more samples. Bound: 6 standard errors of the difference of the two weighted means
    # (the proposal's draws alone, unweighted, miss by 15–30 of them).
    from cooploc.estimators.sme.proposal import linearized_proposal
    from cooploc.particles import normalize_log_weights

    truth, model = _two_vehicle_model(rng, 2.0)
    prior = np.concatenate([truth, np.zeros((2, 2))], axis=1)
    prior_cov = np.repeat(np.diag([2.5, 2.5, 1.0, 1.0])[None], 2, axis=0)
    L = np.linalg.cholesky(prior_cov)

    def weighted_mean(x: np.ndarray, log_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = np.exp(normalize_log_weights(log_w)[0])
        p = x[:, :, :2].reshape(len(x), 4)
        mean = w @ p
        # standard error of a self-normalised estimate: sqrt(Σ w² (p − mean)²)
        return mean, np.sqrt((w[:, None] ** 2 * (p - mean) ** 2).sum(0))

    big = prior + np.einsum("nij,pnj->pni", L, rng.standard_normal((400_000, 2, 4)))
    ref, ref_se = weighted_mean(big, model.log_likelihood(big[:, :, :2]))
    P = 10_000
    proposal = linearized_proposal(np.broadcast_to(prior, (P, 2, 4)), prior_cov, np.zeros(P), model, [0, 1])
    x = proposal.draw(proposal.mean, rng)
    ours, se = weighted_mean(x, model.log_likelihood(x[:, :, :2]) - proposal.linearized_log_likelihood(x))
    assert np.all(np.abs(ours - ref) <= SIGMAS * np.hypot(se, ref_se)), (ours, ref, se, ref_se)


@pytest.mark.slow
@pytest.mark.parametrize("rao_blackwellised", [True, False])
def test_pf_without_topology_matches_the_known_association_kf(seed: int, rao_blackwellised: bool) -> None:
    # two vehicles 40 m and more apart, the topology switched off: the GPS sums of powers
    # then carry what the associated rows carry, so the particle filter's mean must be the
    # Kalman filter's up to Monte Carlo noise. Statistic: mean over steps ≥ 5, runs and
    # state components of |PF mean − KF mean| / KF standard deviation. Measured with 1000
    # particles: ≈ 0.07 (an effective sample of ≈ 100; Rao–Blackwellised ≈ 0.05);
    # the bootstrap proposal with the same particles ≈ 0.14. Bound 0.11.
    from cooploc.estimators.kf_known_da import KFKnownDA, KFKnownDAParams

    preset = get_preset("zhang2016-cv")
    z = []
    for run in range(3):
        rec = preset.generate(np.random.default_rng([seed, 21, run]),
                              preset.params.with_overrides({"n_vehicles": 2, "n_steps": 30}))
        pf = make_estimator("sme-pf", rec.setup, SmePFParams(n_particles=1000, use_radar=False,
                                                             rao_blackwellised=rao_blackwellised),
                            np.random.default_rng([seed, 22, run]))
        kf = KFKnownDA(rec.setup, KFKnownDAParams(), np.random.default_rng(0), truth=rec.truth)
        for frame in rec.frames:
            a, b = pf.step(frame).vehicles, kf.step(frame).vehicles
            if frame.k >= 5:
                z.append(np.abs(a.mean - b.mean) / np.sqrt(np.diagonal(b.cov, axis1=1, axis2=2)))
    assert np.mean(z) < 0.11, np.mean(z)


@pytest.mark.parametrize("name, params", [("sme-pf", SmePFParams(n_particles=200)),
                                          ("sme-ukf", SmeUKFParams())])
def test_rows_of_position_and_velocity_enter_as_their_position(name: str, params,
                                                               short_cv: Recording) -> None:
    """Rows z = [p, v] + w (`sumo-*`) give exactly what their position marginal gives
    (module docstring of `filter_base`); they used to be refused at construction."""
    grown = with_velocity_fixes(short_cv, 7)
    assert grown.frames[0].batches["gnss"].dim == 4
    runs = []
    for rec in (short_cv, grown):
        est = make_estimator(name, rec.setup, params, np.random.default_rng(0))
        runs.append([est.step(frame) for frame in rec.frames])
    for a, b in zip(*runs, strict=True):
        np.testing.assert_array_equal(a.vehicles.mean, b.vehicles.mean)
        np.testing.assert_array_equal(a.vehicles.cov, b.vehicles.cov)


def test_rows_without_the_position_are_refused_by_name(short_cv: Recording) -> None:
    velocity_only = GnssPosition(default_cov=np.eye(2), state_indices=(2, 3))
    setup = dataclasses.replace(short_cv.setup, sensors={**short_cv.setup.sensors, "gnss": velocity_only})
    with pytest.raises(ConfigError, match=r"sme-ukf needs GNSS rows that hold the position \(0, 1\)"):
        make_estimator("sme-ukf", setup, SmeUKFParams(), np.random.default_rng(0))


# ----------------------------------------------------------------------------
# the Rao–Blackwellised (marginalized) particle filter
# ----------------------------------------------------------------------------


def test_linear_substate_is_the_exact_conditional_of_the_positions(rng: np.random.Generator) -> None:
    # oracle: the joint Gaussian of x_0..x_k under x_k = A x_{k−1} + w_k, conditioned by
    # brute force on every position p_0..p_k; the recursion of `marginalized` must give
    # the same mean and covariance of v_k (Schön et al. 2005: the motion of the sampled
    # substate as a measurement of the linear one)
    from cooploc.estimators.sme.marginalized import condition_on_positions, motion_kernel
    from cooploc.motion import ConstantVelocity

    motion = ConstantVelocity(0.25)
    A, Q = motion.transition_matrix(1.0), motion.noise_covariance(1.0)
    pos, lin, dx, steps = [0, 1], [2, 3], 4, 6
    m0 = rng.normal(size=dx)
    B = rng.normal(size=(dx, dx))
    P0 = B @ B.T + np.eye(dx)
    positions = rng.normal(scale=5.0, size=(steps, 2))   # any trajectory: the conditional is exact
    # brute force: stacked mean and covariance of (x_0, ..., x_{steps−1})
    mean = [m0]
    cov = np.zeros((steps * dx, steps * dx))
    cov[:dx, :dx] = P0
    for k in range(1, steps):
        mean.append(A @ mean[-1])
        prev, cur = slice((k - 1) * dx, k * dx), slice(k * dx, (k + 1) * dx)
        cov[cur, :k * dx] = A @ cov[prev, :k * dx]
        cov[:k * dx, cur] = cov[cur, :k * dx].T
        cov[cur, cur] = A @ cov[prev, prev] @ A.T + Q
    mean = np.concatenate(mean)
    observed = np.array([k * dx + i for k in range(steps) for i in pos])
    target = np.array([(steps - 1) * dx + i for i in lin])
    gain = np.linalg.solve(cov[np.ix_(observed, observed)], cov[np.ix_(observed, target)]).T
    want_mean = mean[target] + gain @ (positions.ravel() - mean[observed])
    want_cov = cov[np.ix_(target, target)] - gain @ cov[np.ix_(observed, target)]
    # the recursion, one particle, one vehicle
    block, joint = m0[None, None], P0[None]
    for k in range(steps):
        _, K, C = motion_kernel(joint, pos, lin)
        block = condition_on_positions(block, positions[k][None, None], K, pos, lin)
        joint = A[:, lin] @ C @ A[:, lin].T + Q
        block = block @ A.T if k < steps - 1 else block
    assert np.allclose(block[0, 0, lin], want_mean, rtol=1e-9, atol=1e-9)
    assert np.allclose(C[0], want_cov, rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_rao_blackwellised_pf_is_the_kalman_filter_in_the_linear_case(seed: int) -> None:
    # N = 1: eq. (17) is the GPS row itself (s_1 = u), linear with exact Gaussian noise,
    # and there is no topology (T needs two vehicles): the exact posterior is the Kalman
    # filter's. The Rao–Blackwellised filter's mean and covariance must approach it as the
    # particles grow, the Monte Carlo error falling like P^(−1/2). Statistic: mean over
    # steps ≥ 1 and components of |mean − KF mean| / KF sd and |var − KF var| / KF var.
    # Expected ratio between 16× particles: 1/4; bound 1/2.
    from cooploc.estimators.kf_known_da import KFKnownDA, KFKnownDAParams

    preset = get_preset("zhang2016-cv")
    rec = preset.generate(np.random.default_rng([seed, 31]),
                          preset.params.with_overrides({"n_vehicles": 1, "n_steps": 30}))
    kf = KFKnownDA(rec.setup, KFKnownDAParams(), np.random.default_rng(0), truth=rec.truth)
    ref = [kf.step(frame).vehicles for frame in rec.frames]
    errors = {}
    for P in (250, 4000):
        pf = make_estimator("sme-pf", rec.setup, SmePFParams(n_particles=P, rao_blackwellised=True),
                            np.random.default_rng([seed, 32]))
        z_mean, z_var = [], []
        for frame, b in zip(rec.frames, ref, strict=True):
            a = pf.step(frame).vehicles
            if frame.k >= 1:
                var = np.diagonal(b.cov, axis1=1, axis2=2)
                z_mean.append(np.abs(a.mean - b.mean) / np.sqrt(var))
                z_var.append(np.abs(np.diagonal(a.cov, axis1=1, axis2=2) - var) / var)
        errors[P] = (np.mean(z_mean), np.mean(z_var))
    (m_small, v_small), (m_large, v_large) = errors[250], errors[4000]
    assert m_large < 0.5 * m_small and v_large < 0.5 * v_small, errors
    assert m_large < 0.05 and v_large < 0.05, errors
