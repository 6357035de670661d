"""Tests of `cooploc.estimators.factor_graph` (Gulati 2017 factor graphs).

Oracles: numerical derivatives (Jacobians of the topology residuals, of the whole
whitened system and of the GTSAM CustomFactors), a textbook Kalman/RTS smoother (the
graph without topology is linear-Gaussian), GTSAM's own Levenberg–Marquardt on the
same graph (our banded solver must find the same minimum and marginals), and
invariances of the topology (radar pose, row order). The solver alone, on a problem
without graph code: tests/test_least_squares.py.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cooploc.estimators import get_estimator, make_estimator
from cooploc.estimators.factor_graph import (
    NEW,
    OLD,
    FactorGraphParams,
    GraphData,
    GraphProblem,
    ISAM2Params,
    bilinear_topology,
    gtsam_graph,
    radar_topology,
    solve_lm,
    squared_topology,
    topology_jacobians,
)
from cooploc.estimators.factor_graph.estimates import PositionFilter
from cooploc.estimators.factor_graph.graph import velocity_factor_model
from cooploc.geometry import rotation, to_local
from cooploc.scenarios import get_preset
from cooploc.types import Batch, Frame, Recording
from helpers import with_velocity_fixes

# central differences with step 1e-6 on values of O(100) m: truncation O(h²) and
# round-off O(ε |S| / h) ≈ 1e-16 · 1e5 / 1e-6 = 1e-5 relative to the gradient scale
JACOBIAN_RTOL = 1e-5
# two solvers at the same minimum: LM stops at relative cost decrease 1e-5 ⇒ the
# positions agree to far below a millimetre; covariances come from the same Hessian
SOLVER_ATOL_M = 1e-3
COV_RTOL = 1e-4


def numerical_gradient(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    grad = np.zeros(x.shape + np.shape(f(x)))
    for idx in np.ndindex(x.shape):
        e = np.zeros_like(x)
        e[idx] = h
        grad[idx] = (f(x + e) - f(x - e)) / (2 * h)
    return grad


def recording(seed, n: int = 2, steps: int = 40, **overrides) -> Recording:
    preset = get_preset(f"gulati-{n}v")
    params = preset.params.with_overrides({"n_steps": steps, **overrides})
    return preset.generate(np.random.default_rng(seed), params)


def graph(rec: Recording, kind: str, gap_variance: float = 900.0) -> tuple[GraphData, np.ndarray]:
    """The graph of a recording and the filtered initial guess (as the estimator builds it)."""
    name = "fg-topology-old" if kind == OLD else "fg-topology-new"
    est = make_estimator(name, rec.setup, None, np.random.default_rng(0))
    for frame in rec.frames:
        est.step(frame)
    return est.data, np.concatenate(est.initial)


# ----------------------------------------------------------------------------
# Jacobians
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("n", [2, 3, 5])
def test_topology_jacobians_match_numerical_derivatives(n: int, rng: np.random.Generator) -> None:
    p = rng.normal(0, 40, (n, 2))
    q = p + rng.normal(0, 3, (n, 2))
    J_old, none = topology_jacobians(OLD, p[None])
    assert none is None
    scale = np.abs(J_old).max()
    np.testing.assert_allclose(J_old[0], numerical_gradient(squared_topology, p),
                               atol=JACOBIAN_RTOL * scale)
    J_cur, J_prev = topology_jacobians(NEW, p[None], q[None])
    np.testing.assert_allclose(J_cur[0], numerical_gradient(lambda x: bilinear_topology(x, q), p),
                               atol=JACOBIAN_RTOL * scale)
    # q = p_{t−1} + δ, so the derivative in p_{t−1} is the derivative in q
    np.testing.assert_allclose(J_prev[0], numerical_gradient(lambda x: bilinear_topology(p, x), q),
                               atol=JACOBIAN_RTOL * scale)
    # eq. 19: the sum of the two blocks at p_t = q is the gradient of eq. 11
    J_cur, J_prev = topology_jacobians(NEW, q[None], q[None])
    np.testing.assert_allclose(J_cur + J_prev, topology_jacobians(OLD, q[None])[0], rtol=1e-12)


def test_bilinear_form_is_the_polarisation_of_eq_8(rng: np.random.Generator) -> None:
    p, q = rng.normal(0, 30, (2, 4, 2))
    np.testing.assert_allclose(bilinear_topology(p, p), squared_topology(p), rtol=1e-12)
    pairs = sum((p[i] - p[j]) @ (q[i] - q[j]) for i in range(4) for j in range(i + 1, 4))
    np.testing.assert_allclose(bilinear_topology(p, q), pairs, rtol=1e-12)
    np.testing.assert_allclose(bilinear_topology(p, q), bilinear_topology(q, p), rtol=1e-12)


@pytest.mark.parametrize("kind", [OLD, NEW])
@pytest.mark.parametrize("huber", [0.0, 1.5])
def test_system_jacobian_matches_numerical_derivatives(kind: str, huber: float, seed: int) -> None:
    rec = recording([seed, 11], n=3, steps=6)
    data, x0 = graph(rec, kind)
    problem = GraphProblem.of(data, huber)
    x = x0 + np.random.default_rng([seed, 12]).normal(0, 1.0, x0.shape)
    r, J = problem.linearize(x)
    numeric = numerical_gradient(lambda y: problem.linearize(y.reshape(-1, 2), False)[0],
                                 x.ravel())
    dense = J.toarray()
    if huber > 0:
        # IRLS Jacobian: the weight is held fixed (as GTSAM's robust models do); compare
        # the rows whose weight is 1, where both agree
        inside = np.abs(r) < huber * 0.999
        dense, numeric = dense[inside], numeric.T[inside].T
    np.testing.assert_allclose(dense, numeric.T, atol=JACOBIAN_RTOL * np.abs(dense).max())


@pytest.mark.parametrize("kind", [OLD, NEW])
def test_gtsam_custom_factors_match_ours(kind: str, seed: int) -> None:
    """The GTSAM graph (CustomFactor topology) linearises to our whitened system."""
    import gtsam

    rec = recording([seed, 13], n=3, steps=5)
    data, x0 = graph(rec, kind)
    problem = GraphProblem.of(data)
    x = x0 + np.random.default_rng([seed, 14]).normal(0, 0.5, x0.shape)
    ours_r, ours_J = problem.linearize(x)
    values = gtsam.Values()
    for v, p in enumerate(x):
        values.insert(v, p)
    g = gtsam_graph(data)
    # ½‖r‖² is GTSAM's error; the Gauss–Newton Hessian JᵀJ must agree too
    np.testing.assert_allclose(g.error(values), 0.5 * ours_r @ ours_r, rtol=1e-9)
    ordering = gtsam.Ordering()
    for v in range(data.n_vars):
        ordering.push_back(v)
    A, _ = g.linearize(values).hessian(ordering)
    H = (ours_J.T @ ours_J).toarray()
    np.testing.assert_allclose(A, H, rtol=1e-8, atol=1e-10 * np.abs(H).max())


# ----------------------------------------------------------------------------
# topology measurement
# ----------------------------------------------------------------------------


def test_topology_is_invariant_to_radar_pose_and_row_order(rng: np.random.Generator) -> None:
    points = rng.normal(0, 50, (4, 2))
    cov = np.repeat(0.1 * np.eye(2)[None], 4, 0)
    s0, var0 = radar_topology(points, cov)
    for _ in range(5):
        pose = np.r_[rng.uniform(-100, 100, 2), rng.uniform(-np.pi, np.pi)]
        local = to_local(pose, points)[rng.permutation(4)]
        s, var = radar_topology(local, cov)
        np.testing.assert_allclose([s, var], [s0, var0], rtol=1e-10)
    # and the predicted topology of the states: rigid motion + permutation of both args
    q = points + rng.normal(0, 2, points.shape)
    R, t, perm = rotation(0.7), np.array([3.0, -8.0]), rng.permutation(4)
    np.testing.assert_allclose(bilinear_topology((points @ R.T + t)[perm], (q @ R.T + t)[perm]),
                               bilinear_topology(points, q), rtol=1e-10)


def test_topology_noise_is_first_order_propagation(rng: np.random.Generator) -> None:
    """eqs. 14–16: σ_s² = 4N σ_r² s for isotropic noise; checked by sampling."""
    points = rng.normal(0, 30, (3, 2))
    cov = np.repeat(0.1 * np.eye(2)[None], 3, 0)
    s, var = radar_topology(points, cov)
    np.testing.assert_allclose(var, 4 * 3 * 0.1 * s, rtol=1e-12)
    draws = squared_topology(points + rng.normal(0, np.sqrt(0.1), (20000, 3, 2)))
    # first order: relative error of the variance O(σ_r² / spread²) ≈ 1e-4, plus the
    # sampling error of a variance from 20000 draws (≈ 1 %, 5 σ bound)
    np.testing.assert_allclose(draws.var(), var, rtol=5 * np.sqrt(2 / 20000) + 1e-3)


# ----------------------------------------------------------------------------
# solvers
# ----------------------------------------------------------------------------


def kalman_rts(x0, P0, gps, R_gps, odometry, R_odo):
    """Textbook KF + RTS for p_t = p_{t−1} + δ_t + w (Q = R_odo), GPS z = p + v."""
    T = gps.shape[0]
    m, P = np.zeros((T, 2)), np.zeros((T, 2, 2))
    mp, Pp = np.zeros((T, 2)), np.zeros((T, 2, 2))
    mean, cov = x0, P0
    for t in range(T):
        if t > 0:
            mean, cov = mean + odometry[t], cov + R_odo                 # predict
        mp[t], Pp[t] = mean, cov
        K = cov @ np.linalg.inv(cov + R_gps)                             # update (test oracle)
        mean, cov = mean + K @ (gps[t] - mean), (np.eye(2) - K) @ cov
        m[t], P[t] = mean, cov
    ms, Ps = m.copy(), P.copy()
    for t in range(T - 2, -1, -1):                                      # RTS
        G = P[t] @ np.linalg.inv(Pp[t + 1])
        ms[t] = m[t] + G @ (ms[t + 1] - mp[t + 1])
        Ps[t] = P[t] + G @ (Ps[t + 1] - Pp[t + 1]) @ G.T
    return m, P, ms, Ps


@pytest.mark.parametrize("name", ["fg-topology-old", "fg-topology-new"])
def test_lm_without_topology_is_the_rts_smoother(name: str, seed: int) -> None:
    rec = recording([seed, 21], n=2, steps=60)
    # one vehicle, or no radar: no topology factor; the graph is linear-Gaussian
    frames = [Frame(f.k, f.t, f.vehicles, {k: b for k, b in f.batches.items() if k != "radar"})
              for f in rec.frames]
    est = make_estimator(name, rec.setup, None, np.random.default_rng(0))
    filtered = [est.step(f) for f in frames]
    smoothed = est.smooth()
    assert smoothed[0].info["topology"] == 0
    prior = rec.setup.vehicle_prior
    for i in range(2):
        gps = np.array([f.batches["gnss"].z[i] for f in frames])
        odo = np.array([f.batches["odometry"].z[i] if len(f.batches["odometry"]) else np.zeros(2)
                        for f in frames])
        m, P, ms, Ps = kalman_rts(prior.mean[i, :2], prior.cov[i, :2, :2], gps, 9 * np.eye(2),
                                  odo, np.eye(2))
        np.testing.assert_allclose([e.vehicles.mean[i, :2] for e in filtered], m, atol=1e-9)
        np.testing.assert_allclose([e.vehicles.cov[i, :2, :2] for e in filtered], P, atol=1e-9)
        np.testing.assert_allclose([e.vehicles.mean[i, :2] for e in smoothed], ms, atol=1e-6)
        np.testing.assert_allclose([e.vehicles.cov[i, :2, :2] for e in smoothed], Ps, rtol=1e-8)


@pytest.mark.parametrize("kind", [OLD, NEW])
def test_sparse_lm_equals_gtsam_lm(kind: str, seed: int) -> None:
    rec = recording([seed, 31], n=3, steps=40)
    name = "fg-topology-old" if kind == OLD else "fg-topology-new"
    results = {}
    for solver in ("sparse", "gtsam"):
        est = make_estimator(name, rec.setup, get_estimator(name).Params(solver=solver),
                             np.random.default_rng(0))
        for frame in rec.frames:
            est.step(frame)
        results[solver] = est.solve()
    ours, ref = results["sparse"], results["gtsam"]
    np.testing.assert_allclose(ours.x, ref.x, atol=SOLVER_ATOL_M)
    np.testing.assert_allclose(ours.cov, ref.cov, rtol=COV_RTOL, atol=1e-9)
    np.testing.assert_allclose(ours.cost, ref.cost, rtol=1e-6)


def test_banded_selected_inverse_equals_dense_inverse(seed: int) -> None:
    rec = recording([seed, 41], n=4, steps=12)
    data, x0 = graph(rec, NEW)
    problem = GraphProblem.of(data)
    result = solve_lm(problem.linearize, x0)
    _, J = problem.linearize(result.x)
    dense = np.linalg.inv((J.T @ J).toarray())  # oracle: the dense inverse
    blocks = np.array([dense[2 * v:2 * v + 2, 2 * v:2 * v + 2] for v in range(data.n_vars)])
    np.testing.assert_allclose(result.cov, blocks, rtol=1e-8)


# ----------------------------------------------------------------------------
# missed detections, clutter, traffic
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("kind", [OLD, NEW])
def test_topology_left_out_unless_radar_reports_every_vehicle(kind: str, seed: int) -> None:
    rec = recording([seed, 51], n=3, steps=60, detection_probability=0.8, clutter_rate=0.3)
    data, _ = graph(rec, kind)
    n_rows = np.array([len(f.batches["radar"]) for f in rec.frames])
    expected = n_rows == 3
    if kind == NEW:
        expected[0] = False  # no odometry at the first step
    assert data.n_topology == int(expected.sum())
    assert 0 < data.n_topology < 60
    used = np.array([f.topology_s.size for f in data.frames]) > 0
    np.testing.assert_array_equal(used, expected)


def test_clutter_robust_option_bounds_wrong_topologies(seed: int) -> None:
    """With misses *and* clutter, a wrong row can stand in for a missed one; Huber
    bounds its influence. Plain vs robust on the same runs: the robust one is not worse
    on average and both stay finite."""
    errors = {0.0: [], 2.0: []}
    for r in range(3):
        rec = recording([seed, 52, r], n=2, steps=80, detection_probability=0.7,
                        clutter_rate=1.0, clutter_extent=60.0)
        truth = rec.truth.vehicle_states[:, :, :2]
        for huber in errors:
            est = make_estimator("fg-topology-old", rec.setup,
                                 get_estimator("fg-topology-old").Params(huber=huber),
                                 np.random.default_rng(0))
            for frame in rec.frames:
                est.step(frame)
            means = np.array([e.vehicles.mean[:, :2] for e in est.smooth()])
            assert np.isfinite(means).all()
            errors[huber].append(np.mean(np.sum((means - truth) ** 2, axis=-1)))
    assert np.mean(errors[2.0]) <= np.mean(errors[0.0]) * 1.05


def test_traffic_and_gaps_give_a_solvable_graph(seed: int) -> None:
    rec = recording([seed, 61], n=3, steps=30)
    frames = []
    for f in rec.frames:
        if f.k in (5, 6):  # no odometry: gap factors
            f = Frame(f.k, f.t, f.vehicles, {k: b for k, b in f.batches.items() if k != "odometry"})
        if 10 <= f.k < 15:  # vehicle 2 away: no rows of it
            keep = f.vehicles != 2
            batches = {k: (b.select(b.subject != 2) if k != "radar" else Batch.empty(2))
                       for k, b in f.batches.items()}
            f = Frame(f.k, f.t, f.vehicles[keep], batches)
        frames.append(f)
    for name in ("fg-topology-old", "fg-topology-new", "fg-isam2"):
        est = make_estimator(name, rec.setup, None, np.random.default_rng(0))
        out = [est.step(f) for f in frames]
        if hasattr(est, "smooth"):
            out = est.smooth()
        for f, e in zip(frames, out, strict=True):
            np.testing.assert_array_equal(np.sort(e.vehicles.ids), np.sort(f.vehicles))
            assert np.isfinite(e.vehicles.mean).all()


def test_isam2_final_estimate_is_the_batch_solution(seed: int) -> None:
    """iSAM2 solves the same (new-factor) graph: its last filtered estimate is the batch
    smoother's estimate of the last step (up to its relinearisation threshold)."""
    rec = recording([seed, 71], n=2, steps=40)
    isam = make_estimator("fg-isam2", rec.setup, None, np.random.default_rng(0))
    last = [isam.step(f) for f in rec.frames][-1]
    batch = make_estimator("fg-topology-new", rec.setup, None, np.random.default_rng(0))
    for f in rec.frames:
        batch.step(f)
    smoothed = batch.smooth()[-1]
    # relinearize_threshold 0.1 m leaves linearisation points up to 0.1 m stale
    np.testing.assert_allclose(last.vehicles.mean[:, :2], smoothed.vehicles.mean[:, :2], atol=0.05)


@pytest.mark.parametrize("lag", [1, 2])
def test_isam2_fixed_lag_marginal_is_exact_on_the_linearised_graph(lag: int, seed: int) -> None:
    """With relinearisation off, iSAM2 solves the graph linearised where each factor was
    added: a linear-Gaussian problem in which the topology factors couple the vehicles.
    Marginalising the states older than the lag into a linear prior is then exact, so
    every filtered estimate and covariance of the fixed-lag smoother is the full iSAM2's,
    while it holds only the last lag + 1 steps. (A prior built from each kept variable's
    own marginal, without the cross-covariances, misses by 0.3–0.6 m here.)"""
    rec = recording([seed, 73], n=3, steps=30)
    frozen = {"relinearize_threshold": 1e9}
    full = make_estimator("fg-isam2", rec.setup, ISAM2Params(lag=0, **frozen), np.random.default_rng(0))
    lagged = make_estimator("fg-isam2", rec.setup, ISAM2Params(lag=lag, **frozen), np.random.default_rng(0))
    for f in rec.frames:
        a, b = full.step(f), lagged.step(f)
        # the same linear least squares, eliminated in another order: round-off only
        np.testing.assert_allclose(b.vehicles.mean, a.vehicles.mean, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.vehicles.cov, a.vehicles.cov, rtol=0, atol=1e-9)
        assert lagged.isam.getLinearizationPoint().size() <= (lag + 1) * f.vehicles.size
    assert lagged.data.n_topology > 0
    assert full.isam.getLinearizationPoint().size() == 3 * len(rec.frames)


def test_isam2_fixed_lag_is_the_full_isam2_within_linearisation_error(seed: int) -> None:
    """With relinearisation (the default), the marginalised states keep the linearisation
    point they had when they left the window: the estimates differ from the full
    iSAM2's only by that (measured ≤ 0.03 m at lag 2 on three seeds)."""
    rec = recording([seed, 79], n=3, steps=30)
    full = make_estimator("fg-isam2", rec.setup, ISAM2Params(lag=0), np.random.default_rng(0))
    lagged = make_estimator("fg-isam2", rec.setup, ISAM2Params(lag=2), np.random.default_rng(0))
    for f in rec.frames:
        a, b = full.step(f), lagged.step(f)
        assert np.isfinite(b.vehicles.mean).all() and np.isfinite(b.vehicles.cov).all()
        # relinearize_threshold 0.1 m: linearisation points up to 0.1 m stale in either
        np.testing.assert_allclose(b.vehicles.mean, a.vehicles.mean, rtol=0, atol=0.1)


def test_isam2_holds_only_the_latest_frame_of_factors(seed: int) -> None:
    """Each frame's factors go to GTSAM once, so fg-isam2's graph data keeps only the frames
    of its window, lag + 1 (memory flat over a long run); keeping every frame changes no
    estimate."""
    rec = recording([seed, 83], n=3, steps=25)
    lean = make_estimator("fg-isam2", rec.setup, None, np.random.default_rng(0))
    kept = make_estimator("fg-isam2", rec.setup, None, np.random.default_rng(0))
    kept.data.keep_frames = None
    for f in rec.frames:
        a, b = lean.step(f), kept.step(f)
        np.testing.assert_array_equal(a.vehicles.mean, b.vehicles.mean)
        np.testing.assert_array_equal(a.vehicles.cov, b.vehicles.cov)
    assert len(lean.data.frames) == lean.params.lag + 1 < len(kept.data.frames) == len(rec.frames)
    assert lean.data.n_topology == kept.data.n_topology > 0


def test_isam2_lag_is_validated() -> None:
    from cooploc.errors import ConfigError, CooplocError

    for bad in (-1, 1.5, True):
        with pytest.raises(ConfigError, match="lag") as info:
            ISAM2Params(lag=bad)
        assert isinstance(info.value, CooplocError)


def test_params_are_validated() -> None:
    from cooploc.errors import ConfigError

    with pytest.raises(ConfigError, match="solver"):
        FactorGraphParams(solver="ceres")
    with pytest.raises(ConfigError, match="gap_variance"):
        dataclasses.replace(FactorGraphParams(), gap_variance=-1.0)
    with pytest.raises(ConfigError, match="topology_odometry_noise"):
        FactorGraphParams(topology_odometry_noise="sometimes")


def test_topology_odometry_noise_option(seed: int) -> None:
    """σ_s² gains N σ_o² s (∂B/∂δ^i = N(p^i − p̄)) beside the radar's 4N σ_r² s:
    (4 · 0.1 + 1) / (4 · 0.1) = 3.5 with the paper's variances; old factor unchanged."""
    rec = recording([seed, 81], n=3, steps=10)
    sigmas = {}
    for kind in (OLD, NEW):
        for flag in (False, True):
            data = GraphData(rec.setup, kind, 900.0, odometry_noise=flag)
            for frame in rec.frames:
                data.add_frame(frame)
            sigmas[kind, flag] = np.concatenate([f.topology_sigma for f in data.frames])
    np.testing.assert_allclose((sigmas[NEW, True] / sigmas[NEW, False]) ** 2, 3.5, rtol=1e-12)
    np.testing.assert_array_equal(sigmas[OLD, True], sigmas[OLD, False])


@pytest.mark.parametrize("kind", [OLD, NEW])
def test_robust_lm_equals_gtsam_huber(kind: str, seed: int) -> None:
    """Huber topology factors (misses and clutter): our IRLS LM minimises the same Huber
    cost as GTSAM's LM with `noiseModel.Robust` + `mEstimator.Huber`."""
    rec = recording([seed, 91], n=2, steps=40, detection_probability=0.7, clutter_rate=1.0,
                    clutter_extent=60.0)
    name = "fg-topology-old" if kind == OLD else "fg-topology-new"
    results = {}
    for solver in ("sparse", "gtsam"):
        params = get_estimator(name).Params(solver=solver, huber=2.0, relative_tolerance=1e-10,
                                            absolute_tolerance=1e-10)
        est = make_estimator(name, rec.setup, params, np.random.default_rng(0))
        for frame in rec.frames:
            est.step(frame)
        results[solver] = est.solve()
    ours, ref = results["sparse"], results["gtsam"]
    # both converged tightly: the Huber cost is strictly convex near its minimum here
    np.testing.assert_allclose(ours.cost, ref.cost, rtol=1e-6)
    np.testing.assert_allclose(ours.x, ref.x, atol=SOLVER_ATOL_M)


def test_run_one_scores_the_smoothed_estimates() -> None:
    """experiment.run_one calls `smooth()` after the last step and scores its output."""
    from cooploc.experiment import ExperimentConfig, run_generators, run_one
    from cooploc.metrics import evaluate

    config = ExperimentConfig.build("gulati-2v", ["fg-topology-new"],
                                    scenario_overrides={"n_steps": 20}, runs=1, backend="serial")
    errors = run_one(config, 0).errors["fg-topology-new"]
    scenario_rng, rngs = run_generators(config.seed, 0, ["fg-topology-new"])
    rec = get_preset("gulati-2v").generate(scenario_rng, config.scenario_params)
    est = make_estimator("fg-topology-new", rec.setup, None, rngs["fg-topology-new"])
    filtered = [est.step(f) for f in rec.frames]
    np.testing.assert_array_equal(errors.err_pos, evaluate(rec, est.smooth()).err_pos)
    assert not np.array_equal(errors.err_pos, evaluate(rec, filtered).err_pos)


def test_gps_factor_takes_the_position_of_position_and_velocity_rows(seed: int) -> None:
    """Rows z = [p, v] + w (`sumo-*`) enter the GPS factor (eqs. 6–7) as their position
    marginal: every factor graph gives what it gives on the rows of the position alone
    (it used to crash at step 0 concatenating 2- and 4-column rows)."""
    rec = recording([seed, 81], n=3, steps=12)
    grown = with_velocity_fixes(rec, [seed, 82])
    assert grown.frames[0].batches["gnss"].dim == 4
    for name in ("fg-topology-old", "fg-topology-new", "fg-isam2"):
        runs = []
        for r in (rec, grown):
            est = make_estimator(name, r.setup, None, np.random.default_rng(0))
            out = [est.step(f) for f in r.frames]
            runs.append(est.smooth() if hasattr(est, "smooth") else out)
        for a, b in zip(*runs, strict=True):
            np.testing.assert_array_equal(a.vehicles.mean, b.vehicles.mean, err_msg=name)
            np.testing.assert_array_equal(a.vehicles.cov, b.vehicles.cov, err_msg=name)


def _with_gnss(setup, state_indices, cov):
    from cooploc.sensors import GnssPosition

    sensors = dict(setup.sensors)
    sensors["gnss"] = GnssPosition(default_cov=cov, state_indices=state_indices)
    return dataclasses.replace(setup, sensors=sensors)


def test_velocity_factor_is_the_motion_models_conditional_displacement(rng: np.random.Generator) -> None:
    """The GNSS velocity factor (graph.py) is E[p_t − p_{t−1} | v_{t−1}, v_t] of the setup's
    motion model: analytically (constant velocity) the trapezoid T (v_{t−1} + v_t)/2 with
    q T³/12 I; by moments over draws of the model, a residual of zero mean, that
    covariance, and uncorrelated with both velocities (what makes it the conditional)."""
    rec = recording([1, 90], steps=3)
    setup = _with_gnss(rec.setup, (0, 1, 2, 3), np.diag([9.0, 9.0, 0.04, 0.04]))
    part, A, G, Q_c = velocity_factor_model(setup)
    T, q = setup.dt, setup.vehicle_motion.noise_density
    np.testing.assert_array_equal(part, [2, 3])
    np.testing.assert_allclose(A, T / 2 * np.eye(2), rtol=1e-12)
    np.testing.assert_allclose(G, T / 2 * np.eye(2), rtol=1e-12)
    np.testing.assert_allclose(Q_c, q * T**3 / 12 * np.eye(2), rtol=1e-12)
    n = 200_000
    F, Q = setup.vehicle_motion.transition_matrix(T), setup.vehicle_motion.noise_covariance(T)
    before = rng.normal(0.0, 5.0, (n, 4))
    after = before @ F.T + rng.multivariate_normal(np.zeros(4), Q, n)
    e = after[:, :2] - before[:, :2] - before[:, 2:] @ A.T - after[:, 2:] @ G.T
    # 5 σ of a mean and of sample (co)variances over n draws (failure probability ~1e-6)
    tol = 5 * np.sqrt(Q_c[0, 0] / n)
    np.testing.assert_allclose(e.mean(0), 0.0, atol=tol)
    np.testing.assert_allclose(np.cov(e.T), Q_c, atol=5 * np.sqrt(2 / n) * Q_c[0, 0])
    for v in (before[:, 2:], after[:, 2:]):
        cross = (e - e.mean(0)).T @ (v - v.mean(0)) / n
        np.testing.assert_allclose(cross, 0.0, atol=5 * np.sqrt(Q_c[0, 0] * v.var(0).max() / n))
    assert velocity_factor_model(rec.setup) is None  # Gulati's GPS: positions only


def test_velocity_factors_enter_only_with_uncorrelated_velocity_rows(seed: int) -> None:
    """Rows [p, v] with independent noise add one velocity factor per continuing vehicle
    and step (none at the first step, none with `gnss_velocity=False`), each equal to the
    factor built by hand. The filter's estimate of the last step (odometry and velocity
    fused) is the graph's solution there, as filter and smoother agree at the end."""
    rec = recording([seed, 91], n=3, steps=6)
    grown = with_velocity_fixes(rec, [seed, 92])
    frames = []
    for f in grown.frames:  # the same rows with the position–velocity cross terms removed
        g = f.batches["gnss"]
        cov = g.cov.copy()
        cov[:, :2, 2:] = cov[:, 2:, :2] = 0.0
        batches = {k: b for k, b in f.batches.items() if k != "radar"}  # linear-Gaussian graph
        batches["gnss"] = Batch(g.z, cov, g.sensor, g.subject)
        frames.append(dataclasses.replace(f, batches=batches))
    setup = _with_gnss(rec.setup, (0, 1, 2, 3), frames[0].batches["gnss"].cov[0])
    on, off = GraphData(setup, NEW, 900.0), GraphData(setup, NEW, 900.0, gnss_velocity=False)
    _, A, G, Q_c = velocity_factor_model(setup)
    for k, f in enumerate(frames):
        a, b = on.add_frame(f), off.add_frame(f)
        n = f.vehicles.size
        assert a.between_a.size == b.between_a.size + (n if k else 0)
        if k:
            g, h = frames[k - 1].batches["gnss"], f.batches["gnss"]
            i = np.argsort(g.subject)
            j = np.argsort(h.subject)
            z = g.z[i][:, 2:] @ A.T + h.z[j][:, 2:] @ G.T
            cov = Q_c + 2 * (A @ g.cov[i][:, 2:, 2:] @ A.T + G @ h.cov[j][:, 2:, 2:] @ G.T)
            np.testing.assert_allclose(a.between_z[-n:], z, rtol=1e-12)
            np.testing.assert_allclose(a.between_cov[-n:], cov, rtol=1e-12)
    belief = None
    filt = PositionFilter()
    for f in on.frames:
        belief = filt.step(f)
    result = solve_lm(GraphProblem.of(on).linearize, np.zeros((on.n_vars, 2)))
    last = on.frames[-1].vars
    np.testing.assert_allclose(belief.mean, result.x[last], atol=1e-6)
    np.testing.assert_allclose(belief.cov, result.cov[last], rtol=1e-6)
