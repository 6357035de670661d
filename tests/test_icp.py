"""`icp`: Gaussian BPA-L with consensus, known association (Brambilla 2020 eqs. 19–22).

Independent references:
- one step of BPA-L on a tree (2 vehicles, 1 feature, uniform feature prior) equals the
  exact Gaussian posterior from a dense information-form solve — means and covariances;
  on a loopy graph (2 vehicles, 2 features) the means still equal it (Gaussian BP
  fixed points have exact means; Weiss & Freeman 2001);
- over Monte Carlo runs `icp` never beats `oracle-kf` and beats `gnss-kf`;
- the result does not depend on the order of agents, links or rows.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from cooploc.estimators import get_estimator, make_estimator
from cooploc.estimators.icp import relative_message
from cooploc.estimators.icp.data_association import BIRTH_GATE, BIRTH_ID_BASE, _group_births, _names_known
from cooploc.experiment import ExperimentConfig, run_experiment
from cooploc.gaussian import Gaussians, to_information
from cooploc.results import summarize
from cooploc.types import Frame, Recording
from helpers import assert_valid_estimate, position_errors, preset_recording, run_estimator, with_traffic

# Dense solve vs iterated messages (converged to 1e-12 relative; positions of ~100 m).
EXACT_ATOL = 1e-6


def _first_full_step(recording: Recording) -> int:
    """The first step at which every vehicle senses every feature."""
    n_pairs = len(recording.truth.vehicle_ids) * len(recording.truth.feature_ids)
    return next(f.k for f in recording.frames if len(f.batches["v2f"]) == n_pairs)


def _dense_posterior(prior: Gaussians, frame: Frame, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact joint posterior of vehicles (independent priors) and features (uniform prior)."""
    n, d = prior.mean.shape
    v2f = frame.batches["v2f"]
    feats = np.unique(origin[origin >= 0])
    D = d * (n + feats.size)
    Lam = np.zeros((D, D))
    eta = np.zeros(D)
    L0, e0 = to_information(prior)
    for i in range(n):
        Lam[i * d:(i + 1) * d, i * d:(i + 1) * d] += L0[i]
        eta[i * d:(i + 1) * d] += e0[i]
    for r in np.flatnonzero(origin >= 0):
        i = int(np.searchsorted(frame.vehicles, v2f.sensor[r]))
        k = n + int(np.searchsorted(feats, origin[r]))
        H = np.zeros((d, D))
        H[:, k * d:(k + 1) * d] = np.eye(d)
        H[:, i * d:(i + 1) * d] = -np.eye(d)
        Rinv = np.linalg.inv(v2f.cov[r])
        Lam += H.T @ Rinv @ H
        eta += H.T @ Rinv @ v2f.z[r]
    cov = np.linalg.inv(Lam)
    mean = cov @ eta
    blocks = np.stack([cov[i * d:(i + 1) * d, i * d:(i + 1) * d] for i in range(n)])
    return mean[: n * d].reshape(n, d), blocks


@pytest.mark.parametrize("n_features", [1, 2], ids=["tree", "loopy"])
def test_one_step_equals_dense_posterior(n_features: int) -> None:
    rec = preset_recording("brambilla-road", [3, n_features], {"n_features": n_features})
    k = _first_full_step(rec)
    params = get_estimator("icp").Params(max_iterations=200, position_tolerance=1e-9,
                                         velocity_tolerance=1e-9)
    icp = make_estimator("icp", rec.setup, params, np.random.default_rng(0), rec.truth)
    gnss = make_estimator("gnss-kf", rec.setup, None, np.random.default_rng(0))
    for frame in rec.frames[:k]:
        icp.step(frame)
        gnss.step(frame)
    prior = gnss.step(rec.frames[k]).vehicles   # icp's b_i^(0): the local GNSS filter (no feedback)
    estimate = icp.step(rec.frames[k])
    mean, cov = _dense_posterior(Gaussians(prior.mean, prior.cov), rec.frames[k], rec.truth.origin[k]["v2f"])
    np.testing.assert_allclose(estimate.vehicles.mean, mean, atol=EXACT_ATOL)
    if n_features == 1:  # on a tree BP covariances are exact too
        np.testing.assert_allclose(estimate.vehicles.cov, cov, atol=EXACT_ATOL)
    # and cooperation helped: posterior variance below the prior's
    assert (np.trace(estimate.vehicles.cov, axis1=1, axis2=2) < np.trace(prior.cov, axis1=1, axis2=2)).all()


def test_relative_message_matches_covariance_form(rng: np.random.Generator) -> None:
    d = 4
    A_half = rng.normal(size=(3, d, d))
    A = A_half @ A_half.transpose(0, 2, 1) + np.eye(d)
    R = np.repeat(np.diag([0.04, 0.04, 0.01, 0.01])[None], 3, 0)
    mean = rng.normal(size=(3, d))
    z = rng.normal(size=(3, d))
    a = np.einsum("mij,mj->mi", A, mean)
    Lam, eta = relative_message(A, a, z, R)
    cov = np.linalg.inv(A) + R                      # y = x + z + n
    np.testing.assert_allclose(Lam, np.linalg.inv(cov), rtol=1e-9)
    np.testing.assert_allclose(np.linalg.solve(Lam, eta[..., None])[..., 0], mean + z, rtol=1e-9)
    # a uniform belief sends a uniform message
    Lam0, eta0 = relative_message(np.zeros((1, d, d)), np.zeros((1, d)), z[:1], R[:1])
    assert np.abs(Lam0).max() == 0 and np.abs(eta0).max() == 0


def test_relative_message_compiled_matches_the_lapack_form(rng: np.random.Generator) -> None:
    # the compiled rows (one Cholesky of A + R⁻¹) against the three LAPACK solves they
    # replace, on PSD A from zero through rank-deficient to stiff (κ up to 1e10)
    from cooploc.estimators.icp.gaussian_bp import _relative_message_lapack

    d, m = 4, 400
    half = rng.normal(size=(m, d, d)) * 10.0 ** rng.uniform(-3, 3, (m, 1, d))
    rank = rng.integers(0, d + 1, m)                        # rank 0 (uniform) … d
    half *= np.arange(d)[None, None, :] < rank[:, None, None]          # columns beyond the rank
    A = half @ half.transpose(0, 2, 1)
    R = np.repeat(np.diag([0.04, 0.04, 0.01, 0.01])[None], m, 0) * rng.uniform(0.5, 50.0, (m, 1, 1))
    a = rng.normal(size=(m, d)) * 10.0
    z = rng.normal(size=(m, d))
    Lam, eta = relative_message(A, a, z, R)
    ref_Lam, ref_eta = _relative_message_lapack(A, a, z, R)
    # round-off of either form: ε times κ(A + R⁻¹) times the size of the terms
    scale = np.abs(A).max(axis=(1, 2)) + 1.0 / R[:, -1, -1]
    tol = 1e-14 * np.linalg.cond(A + np.linalg.inv(R)) * scale
    assert (np.abs(Lam - ref_Lam).max(axis=(1, 2)) <= tol).all()
    assert (np.abs(eta - ref_eta).max(axis=1) <= tol * (np.abs(a).max(axis=1) + np.abs(z).max(axis=1))).all()
    assert (Lam == Lam.transpose(0, 2, 1)).all()


def test_relative_message_falls_back_where_cholesky_fails() -> None:
    # A with a negative eigenvalue beyond R⁻¹'s: A + R⁻¹ is indefinite, LU still solves it
    from cooploc.estimators.icp.gaussian_bp import _relative_message_lapack

    A = np.diag([-200.0, 1.0, 1.0, 1.0])[None]
    R = np.eye(4)[None] * 0.01
    a, z = np.ones((1, 4)), np.full((1, 4), 0.5)
    Lam, eta = relative_message(A, a, z, R)
    ref_Lam, ref_eta = _relative_message_lapack(A, a, z, R)
    np.testing.assert_array_equal(Lam, ref_Lam)
    np.testing.assert_array_equal(eta, ref_eta)


def test_psd_keeps_definite_and_clips_the_rest(rng: np.random.Generator) -> None:
    from cooploc.estimators.icp.gaussian_bp import _psd

    d, m = 4, 200
    half = rng.normal(size=(m, d, d))
    M = half @ half.transpose(0, 2, 1)
    M[: m // 2] -= 3.0 * np.eye(d)                           # some indefinite
    M[:10] = 0.0                                             # uniform copies
    w, V = np.linalg.eigh(M)
    clipped = (V * np.maximum(w, 0.0)[..., None, :]) @ V.transpose(0, 2, 1)   # the definition
    out = _psd(M)
    np.testing.assert_allclose(out, clipped, rtol=0, atol=1e-12 * np.abs(M).max())
    definite = w[:, 0] > 1e-6 * w[:, -1]
    np.testing.assert_array_equal(out[definite], M[definite])   # kept as they were
    assert (np.linalg.eigvalsh(out)[:, 0] >= -1e-12 * np.abs(M).max()).all()


def test_row_sums_and_traces_are_bitwise_numpy(rng: np.random.Generator) -> None:
    from cooploc.estimators.icp._block_kernels import add_rows_at
    from cooploc.estimators.icp.gaussian_bp import _trace

    values = rng.normal(size=(500, 20)) * 10.0 ** rng.uniform(-8, 8, (500, 1))
    index = rng.integers(0, 37, 500)
    ref = rng.normal(size=(37, 20))
    out = ref.copy()
    np.add.at(ref, index, values)
    add_rows_at(out, index, values)
    np.testing.assert_array_equal(out, ref)
    M = rng.normal(size=(30, 7, 4, 4)) * 10.0 ** rng.uniform(-8, 8, (30, 7, 4, 4))
    np.testing.assert_array_equal(_trace(M), np.trace(M, axis1=-2, axis2=-1))


def _per_run_rmse(name: str, runs: int, preset: str, **est_params) -> np.ndarray:
    out = []
    for r in range(runs):
        rec = preset_recording(preset, [11, r])
        cls = get_estimator(name)
        params = cls.Params(**est_params) if est_params else None
        estimates = run_estimator(name, rec, seed=r, params=params)
        out.append(np.sqrt(np.nanmean(position_errors(estimates, rec)[rec.frames[0].k + 3:] ** 2)))
    return np.array(out)


@pytest.mark.slow
def test_between_gnss_and_the_oracle() -> None:
    runs = 12
    icp = _per_run_rmse("icp", runs, "brambilla-road")
    oracle = _per_run_rmse("oracle-kf", runs, "brambilla-road")
    gnss = _per_run_rmse("gnss-kf", runs, "brambilla-road")
    # paired one-sided t-tests at 1 %: icp better than GNSS; not better than the oracle
    assert stats.ttest_rel(icp, gnss, alternative="less").pvalue < 0.01
    assert stats.ttest_rel(icp, oracle, alternative="less").pvalue > 0.01


def test_agent_order_does_not_matter() -> None:
    rec = preset_recording("brambilla-crossroad", [5, 0], {"n_steps": 14, "n_features": 10})
    rng = np.random.default_rng(1)
    frames, origins = [], []
    for f, o in zip(rec.frames, rec.truth.origin, strict=True):
        rows = rng.permutation(len(f.batches["v2f"]))
        batches = {**f.batches, "v2f": f.batches["v2f"].select(rows)}
        frames.append(dataclasses.replace(f, vehicles=f.vehicles[::-1], batches=batches,
                                          links=f.links[::-1, ::-1]))
        origins.append({**o, "v2f": o["v2f"][rows]})
    other = Recording(rec.setup, frames, dataclasses.replace(rec.truth, origin=origins))
    for x, y in zip(run_estimator("icp", rec), run_estimator("icp", other), strict=True):
        np.testing.assert_allclose(x.vehicles.mean, y.vehicles.mean, atol=1e-8)
        assert x.info["messages"] == y.info["messages"] and x.info["bytes"] == y.info["bytes"]


def test_messages_are_counted_and_need_links() -> None:
    rec = preset_recording("brambilla-road", [2, 0])
    estimates = run_estimator("icp", rec)
    sensed = [e.info["messages"] for e, f in zip(estimates, rec.frames, strict=True) if len(f.batches["v2f"])]
    assert max(sensed) > 0 and all(e.info["bytes"] >= 0 for e in estimates)
    lonely = Recording(rec.setup, [dataclasses.replace(f, links=np.zeros((0, 2), np.int64))
                                   for f in rec.frames], rec.truth)
    for e in run_estimator("icp", lonely):
        assert e.info["messages"] == 0


def test_traffic_and_paper_variant_stay_finite() -> None:
    rec = preset_recording("brambilla-crossroad", [4, 0], {"n_steps": 20, "n_features": 20})
    traffic = with_traffic(rec, {1: range(0, 6), 4: range(8, 14), 7: range(15, 20)})
    for params in (None, get_estimator("icp").Params(feedback=True, feature_memory=True)):
        for estimate, frame in zip(run_estimator("icp", traffic, params=params), traffic.frames, strict=True):
            assert_valid_estimate(estimate, frame, traffic)


# ----------------------------------------------------------------------------
# data association: icp-da-lc, icp-da-pf
# ----------------------------------------------------------------------------


def test_vehicles_agree_on_feature_ids() -> None:
    rec = preset_recording("brambilla-road", [6, 0], {"feature_spacing": 6.0})
    for estimate, frame in zip(run_estimator("icp-da-lc", rec), rec.frames, strict=True):
        v2f = frame.batches["v2f"]
        track = estimate.info["v2f_track"]
        by_vehicle = [set(track[v2f.sensor == v].tolist()) for v in frame.vehicles]
        for rows_of, tracks_of in zip(frame.vehicles, by_vehicle, strict=True):
            assert len(tracks_of) == int((v2f.sensor == rows_of).sum())   # distinct tracks per vehicle
        if len(v2f) == 4:                                                  # both see both features
            assert by_vehicle[0] == by_vehicle[1]                          # … and name them alike


def test_group_births_one_row_per_vehicle() -> None:
    ids = np.array([10, 11, 20, 30])
    agents = np.array([1, 1, 2, 3])
    g = np.zeros((4, 4))
    g[1, 0] = 0.5                       # 10 and 11 (same vehicle) both close to 20 and 30
    P = np.repeat(np.eye(4)[None], 4, 0)
    names = _group_births(ids, agents, g, P)
    assert names[0] != names[1]         # one vehicle's two rows never merge
    assert names[2] == names[3] and names[2] in (10, 11)
    far = g.copy()
    far[3, 0] = 100.0
    assert _group_births(ids, agents, far, P)[3] == 30   # outside the gate: its own feature


def _group_births_all_pairs(ids, agents, g, P):
    """The grouping by its definition: every pair of the upper triangle, closest first."""
    label = np.arange(ids.size)
    i, j = np.triu_indices(ids.size, 1)
    i, j = i[agents[i] != agents[j]], j[agents[i] != agents[j]]
    diff = g[i] - g[j]
    d2 = np.array([dv @ np.linalg.solve(P[a] + P[b], dv) for a, b, dv in zip(i, j, diff, strict=True)])
    for k in np.argsort(d2, kind="stable"):
        la, lb = label[i[k]], label[j[k]]
        if d2[k] >= BIRTH_GATE or la == lb or set(agents[label == la]) & set(agents[label == lb]):
            continue
        label[label == max(la, lb)] = min(la, lb)
    return ids[label]


def _birth_candidates(seed: int, C: int = 60, n_agents: int = 12):
    """Clusters of candidates from few vehicles, some with wide covariances."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 40, (8, 2))
    g = np.zeros((C, 4))
    g[:, :2] = centres[rng.integers(0, 8, C)] + rng.normal(0, 0.8, (C, 2))
    g[:, 2:] = rng.normal(0, 1, (C, 2))
    A = rng.normal(0, 1, (C, 4, 4)) * rng.choice([0.3, 1.0, 3.0], C)[:, None, None]
    P = A @ A.transpose(0, 2, 1) + 0.05 * np.eye(4)
    owner = np.sort(rng.integers(0, n_agents, C))          # candidates in agent order
    return rng, BIRTH_ID_BASE + np.arange(C), owner, g, P


@pytest.mark.parametrize("seed", range(6))
def test_group_births_equals_the_all_pairs_definition(seed: int) -> None:
    # the k-d tree's reach must find every pair the gate admits
    _, ids, agents, g, P = _birth_candidates(seed)
    np.testing.assert_array_equal(_group_births(ids, agents, g, P),
                                  _group_births_all_pairs(ids, agents, g, P))


@pytest.mark.parametrize("seed", range(4))
def test_names_known_equal_each_agents_own_grouping(seed: int) -> None:
    # each agent knows its own candidates and a random part of the others (some
    # components whole, some in part); a candidate's name is its owner's grouping of them
    rng, ids, owner, g, P = _birth_candidates(seed)
    n = 12
    have = rng.random((n, ids.size)) < rng.choice([0.3, 0.9, 1.0], n)[:, None]
    have[owner, np.arange(ids.size)] = True
    have[4] = have[5] = have[4] | have[5]                   # two agents that know the same
    expected = np.empty(ids.size, dtype=np.int64)
    for c in range(ids.size):
        members = np.flatnonzero(have[owner[c]])
        names = _group_births_all_pairs(ids[members], owner[members], g[members], P[members])
        expected[c] = names[np.searchsorted(members, c)]
    got = _names_known(have, owner, ids, owner, g, P, (0, 1))
    np.testing.assert_array_equal(got, expected)
    assert len(set(got.tolist())) < ids.size                # groups did form


@pytest.mark.slow
def test_well_separated_features_lose_nothing_to_association() -> None:
    config = ExperimentConfig.build("brambilla-road", ["icp", "icp-da-lc"], runs=6, seed=3,
                                    scenario_overrides={"feature_spacing": "6"}, backend="serial")
    summary = summarize(run_experiment(config))["estimators"]
    # our association uses each vehicle's GNSS-only belief (no feedback, module doc of icp):
    # at d_f = 6 m a few pairings still swap (measured 0.956 over these runs)
    assert summary["icp-da-lc"]["association_accuracy"] > 0.9
    assert summary["icp-da-lc"]["discarded_share"] is not None
    # paper §V-A: at d_f = 6 m the ICP-DA methods reach ICP with known association
    np.testing.assert_allclose(summary["icp-da-lc"]["vehicle_rmse_all"], summary["icp"]["vehicle_rmse_all"],
                               rtol=0.05)


def test_particle_version_matches_the_exact_snapshot() -> None:
    rec = preset_recording("brambilla-road", [3, 1], {"n_features": 1})
    k = _first_full_step(rec)
    params = get_estimator("icp-da-pf").Params(n_particles=1500, max_iterations=20)
    pf = make_estimator("icp-da-pf", rec.setup, params, np.random.default_rng(0))
    gnss = make_estimator("gnss-kf", rec.setup, None, np.random.default_rng(0))
    for frame in rec.frames[:k]:
        pf.step(frame)
        gnss.step(frame)
    prior = gnss.step(rec.frames[k]).vehicles
    estimate = pf.step(rec.frames[k])
    mean, _ = _dense_posterior(Gaussians(prior.mean, prior.cov), rec.frames[k], rec.truth.origin[k]["v2f"])
    # Monte Carlo error and the Silverman-widened kernel (≈ 0.2 of the prior spread):
    # within 0.35 of the prior standard deviation (measured 0.22–0.26 on this case)
    sd = np.sqrt(prior.cov[:, 0, 0])
    assert (np.linalg.norm(estimate.vehicles.mean[:, :2] - mean[:, :2], axis=1) < 0.35 * sd).all()
    assert (np.trace(estimate.vehicles.cov[:, :2, :2], axis1=1, axis2=2)
            < np.trace(prior.cov[:, :2, :2], axis1=1, axis2=2)).all()


def _feature_spread(rec: Recording, feature_memory: bool) -> tuple[float, float]:
    """icp-da-pf on `rec`: the largest standard deviation of a reported feature (m) and the
    largest distance of a reported feature from every true one (m), over the run."""
    params = get_estimator("icp-da-pf").Params(n_particles=100, feature_memory=feature_memory)
    widest = farthest = 0.0
    for k, estimate in enumerate(run_estimator("icp-da-pf", rec, params=params)):
        f = estimate.features
        if len(f.ids):
            true = rec.truth.feature_states[k][rec.truth.feature_present[k]][:, :2]
            distance = np.linalg.norm(f.mean[:, None, :2] - true[None], axis=2).min(axis=1)
            farthest = max(farthest, float(distance.max()))
            widest = max(widest, float(np.sqrt(np.linalg.eigvalsh(f.cov[:, :2, :2])[:, -1]).max()))
    return widest, farthest


def test_particle_version_keeps_soft_paired_features_proper() -> None:
    # a feature whose pairings are soft has g(f, v) ≥ P(α = 0) everywhere: under a uniform
    # prior its weights P(α = 0) / proposal sit in the proposal's tails, and each step's
    # proposal, inflated from the last belief, is wider still (module doc of particle_bp,
    # "The feature prior"); the predicted copy as prior (24) keeps it near the rows
    rec = preset_recording("brambilla-crossroad", 0, {"detection_probability": 0.7})
    widest, farthest = _feature_spread(rec, feature_memory=True)
    assert widest < 40.0 and farthest < 50.0           # measured 13.3 and 18.4 m
    widest_uniform, farthest_uniform = _feature_spread(rec, feature_memory=False)
    assert widest_uniform > 10 * widest and farthest_uniform > 10 * farthest   # 5893 and 5587 m


def test_a_vehicle_that_joins_takes_its_neighbours_tracks() -> None:
    rec = preset_recording("brambilla-road", [6, 0], {"feature_spacing": 6.0})
    joiner = int(rec.frames[0].vehicles[1])
    late = with_traffic(rec, {joiner: range(6)}, keep_prior=True)     # it enters at step 6
    est = make_estimator("icp-da-lc", late.setup, None, np.random.default_rng(0))
    for frame in late.frames[:6]:
        est.step(frame)
    assert est.features.ids.size and joiner not in est.features.agents
    before = est.features.ids.copy()
    estimate = est.step(late.frames[6])                    # the joiner's first step
    v2f = late.frames[6].batches["v2f"]
    mine = estimate.info["v2f_track"][v2f.sensor == joiner]
    # its rows went to the tracks the other vehicle already held, not to new features
    assert mine.size == 2 and np.isin(mine, before).all()


@pytest.mark.parametrize("seed", range(12))
def test_ragged_association_equals_the_padded_bp_bitwise(seed: int) -> None:
    """`ragged_bp_association` over the (agent, track, row) entries gives bitwise the
    marginals of `association.bp_association` on the padded (n, F, W) batch — also where
    NumPy sums pairwise: W = 1 (the track axis contiguous, F past 128) and W ≥ 8."""
    from cooploc.association import bp_association
    from cooploc.estimators.icp.ragged_association import ragged_bp_association, ragged_layout

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 6))
    F = int(rng.choice([3, 40, 300]))
    W = int(rng.choice([1, 1, 5, 11]))
    known = rng.random((n, F)) < rng.uniform(0.2, 0.9)
    known[0] = False                                               # an agent holding no track
    n_rows = rng.integers(0, W + 1, n)
    n_rows[-1] = 0 if n > 1 else n_rows[-1]                        # an agent with no row
    mask = np.arange(W)[None] < n_rows[:, None]
    log_l = rng.normal(-3.0, 5.0, (n, F, W))
    log_l[rng.random((n, F, W)) < 0.1] = -np.inf                   # impossible pairings
    log_missed = np.full((n, F), np.log(0.1))
    log_clutter = np.log(1e-2) + rng.normal(0.0, 2.0, (n, W))
    padded = bp_association(log_l, log_missed, log_clutter, 5, feature_mask=known, measurement_mask=mask)
    ai, fk = np.nonzero(known)
    pair, w = np.nonzero(mask[ai])
    pair_start, entry_start = ragged_layout(ai, n_rows)
    ragged = ragged_bp_association(log_l[ai[pair], fk[pair], w], log_missed[ai, fk], log_clutter,
                                   pair_start, entry_start, n_rows, fk, F, 5)
    a, k = ai[pair], fk[pair]
    np.testing.assert_array_equal(ragged.feature, padded.feature[a, k, w])
    np.testing.assert_array_equal(ragged.measurement, padded.measurement[a, w, k])
    np.testing.assert_array_equal(ragged.missed, padded.missed[ai, fk])
    np.testing.assert_array_equal(np.where(mask, ragged.clutter, 0.0), padded.clutter)


def test_pairwise_sum_is_numpys(rng: np.random.Generator) -> None:
    """The kernels' `_pairwise` adds in NumPy's order: bitwise `np.sum` for every length
    (below 8, blocks of 8 up to 128, halves beyond), where a plain loop is not."""
    from cooploc.estimators.icp._ragged_kernels import _pairwise

    plain_differs = False
    for length in [*range(1, 140), 255, 256, 257, 600, 1031]:
        x = rng.random(length) * 10.0 ** rng.integers(-8, 8, length)
        assert _pairwise(x, 0, length) == np.sum(x), length
        plain_differs |= float(np.add.accumulate(x)[-1]) != np.sum(x)
    assert plain_differs                                           # the test can tell the orders apart


def test_block_kernels_equal_the_numpy_indexing(rng: np.random.Generator) -> None:
    """`copy_copies` is `target[np.ix_(rows_to, cols_to)] = source[np.ix_(rows_from, cols_from)]`
    and `reset_missing` is `block[~have] = 0`, bitwise."""
    from cooploc.estimators.icp._block_kernels import copy_copies, reset_missing

    source = rng.normal(size=(7, 9, 5))
    rows_from, cols_from = np.array([6, 0, 3]), np.array([8, 2, 5, 1])
    rows_to, cols_to = np.array([1, 2, 4]), np.array([0, 3, 6, 7])
    target = rng.normal(size=(5, 8, 5))
    expected = target.copy()
    expected[np.ix_(rows_to, cols_to)] = source[np.ix_(rows_from, cols_from)]
    copy_copies(source, rows_from, cols_from, target, rows_to, cols_to)
    np.testing.assert_array_equal(target, expected)
    have = rng.random((5, 8)) < 0.5
    expected[~have] = 0.0
    reset_missing(target, have)
    np.testing.assert_array_equal(target, expected)


def test_reindexed_copies_keep_their_values(rng: np.random.Generator) -> None:
    """Re-indexing the track copies (agents leave and join, tracks come and go) keeps each
    surviving (agent, track) copy and zeroes the new ones, also when it reuses memory."""
    from cooploc.estimators.icp.gaussian_bp import _FeatureCopies

    copies = _FeatureCopies(2)
    layouts = [(np.array([1, 4, 7]), np.array([10, 20])), (np.array([1, 4, 7, 9]), np.array([10, 20, 30])),
               (np.array([4, 9]), np.array([20, 30])), (np.array([2, 4, 9, 11]), np.array([5, 20, 30, 40]))]
    for agents, ids in layouts:
        before = {(int(a), int(f)): copies.block[i, j].copy()
                  for i, a in enumerate(copies.agents) for j, f in enumerate(copies.ids)}
        copies.reindex(agents, ids)
        assert copies.block.shape == (agents.size, ids.size, 6)
        for i, a in enumerate(agents):
            for j, f in enumerate(ids):
                np.testing.assert_array_equal(copies.block[i, j], before.get((int(a), int(f)), np.zeros(6)))
        copies.block[...] = rng.normal(size=copies.block.shape)      # new values for the next layout
        np.testing.assert_array_equal(copies.Lam[..., 1, 0], copies.block[..., 2])   # views of the block
        np.testing.assert_array_equal(copies.eta, copies.block[..., 4:])
