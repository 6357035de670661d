"""The unknown-feature `rsu-bp`: existence and birth weights against enumeration, robustness.

- One legacy feature, one row: BP is exact, so the existence of the legacy feature and
  of the new potential feature from the row equal the enumeration over the hypotheses
  {detected, missed + row clutter/new, absent + row clutter/new}.
- Two features, two rows: BP's marginals close to the enumeration (loopy BP, not exact).
- Runs on a scene without a feature prior, with empty V2F batches, vehicles entering
  and leaving, misses and clutter: finite estimates, rows attributed to own tracks.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from cooploc.association import bp_association
from cooploc.estimators.rsu_bp import RsuBPParams
from cooploc.estimators.rsu_bp import existence as ex
from cooploc.registry import get_preset, make_estimator


def _enumerate(r: np.ndarray, beta: np.ndarray, p_d: float, p_vis: np.ndarray, clutter: float,
               birth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact P(feature k exists) and P(row m is a new feature) by enumerating every hypothesis.

    A hypothesis gives each feature: absent, missed, or one row (rows used at most once);
    a row no feature takes is clutter (weight λ_c) or a new feature (λ_b).
    """
    K, M = beta.shape
    exists = np.zeros(K)
    new = np.zeros(M)
    total = 0.0
    for states in itertools.product(range(-2, M), repeat=K):     # −2 absent, −1 missed
        taken = [m for m in states if m >= 0]
        if len(taken) != len(set(taken)):
            continue
        w = 1.0
        for k, a in enumerate(states):
            if a == -2:
                w *= 1 - r[k]
            else:
                w *= r[k] * (1 - p_d * p_vis[k]) if a == -1 else r[k] * p_d * beta[k, a]
        free = [m for m in range(M) if m not in taken]
        w *= np.prod([clutter + birth[m] for m in free])
        total += w
        for k, a in enumerate(states):
            exists[k] += w * (a != -2)
        for m in free:
            new[m] += w * birth[m] / (clutter + birth[m])
    return exists / total, new / total


def _bp(r, beta, p_d, p_vis, clutter, birth):
    log_psi, _ = ex.legacy_weights(np.log(beta), r, p_d, p_vis)
    _, log_missed = ex.legacy_weights(np.zeros((r.size, 0)), r, p_d, p_vis)
    log_kappa = ex.row_weights(clutter, np.log(birth))
    marg = bp_association(log_psi, log_missed, log_kappa, 50)
    log_nb = np.logaddexp.reduce(marg.log_nu + np.log(beta), axis=1)
    exists = ex.legacy_existence(r, ex.log_existence_likelihood(log_nb, p_d, p_vis))
    new = ex.new_existence(marg.clutter, np.log(birth), log_kappa)
    return exists, new


@pytest.mark.parametrize("r, beta, p_d, p_vis, clutter, birth", [
    (0.9, 0.3, 0.8, 1.0, 0.05, 0.02),
    (0.5, 0.01, 0.95, 0.7, 0.0, 0.1),
    (0.99, 2.0, 0.99, 1.0, 0.5, 1e-4),
    (0.2, 0.5, 0.5, 0.0, 0.1, 0.1),        # out of range: no miss, but a row still fits
])
def test_one_feature_one_row_is_exact(r, beta, p_d, p_vis, clutter, birth) -> None:
    args = (np.array([r]), np.array([[beta]]), p_d, np.array([p_vis]), clutter, np.array([birth]))
    exact = _enumerate(*args)
    got = _bp(*args)
    np.testing.assert_allclose(got[0], exact[0], rtol=1e-9)
    np.testing.assert_allclose(got[1], exact[1], rtol=1e-9)


def test_two_features_two_rows_close_to_enumeration() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        r = rng.uniform(0.1, 0.99, 2)
        beta = rng.uniform(0.01, 2.0, (2, 2))
        p_vis = rng.uniform(0.5, 1.0, 2)
        birth = rng.uniform(0.01, 0.2, 2)
        exact = _enumerate(r, beta, 0.9, p_vis, 0.05, birth)
        got = _bp(r, beta, 0.9, p_vis, 0.05, birth)
        np.testing.assert_allclose(got[0], exact[0], atol=0.08)
        np.testing.assert_allclose(got[1], exact[1], atol=0.08)


def test_no_clutter_no_feature_makes_every_row_a_new_feature() -> None:
    exists, new = _bp(np.zeros(0), np.zeros((0, 3)), 0.9, np.zeros(0), 0.0, np.full(3, 1e-5))
    assert exists.size == 0
    np.testing.assert_allclose(new, 1.0)


@pytest.mark.parametrize("overrides", [
    {},
    {"detection_probability": 0.7, "clutter_rate": 2.0},
])
def test_unknown_features_run_finite_with_entering_and_leaving_vehicles(overrides: dict) -> None:
    preset = get_preset("brambilla-crossroad")
    params = dataclasses.replace(preset.params, n_steps=12, **overrides)
    rec = preset.generate(np.random.default_rng(0), params)
    assert not len(rec.setup.feature_prior)
    frames = list(rec.frames)
    # vehicles leave and enter; one step has no V2F rows at all
    frames[3] = dataclasses.replace(
        frames[3], vehicles=frames[3].vehicles[2:], links=np.zeros((0, 2), np.int64), batches={
        "gnss": frames[3].batches["gnss"].select(np.flatnonzero(
            np.isin(frames[3].batches["gnss"].subject, frames[3].vehicles[2:]))),
        "v2f": frames[3].batches["v2f"].select(np.zeros(0, dtype=np.int64))})
    est = make_estimator("rsu-bp", rec.setup, RsuBPParams(n_particles=100), np.random.default_rng(1))
    assert est.tracker is not None
    for frame in frames:
        out = est.step(frame)
        assert np.isfinite(out.vehicles.mean).all() and np.isfinite(out.vehicles.cov).all()
        assert np.isfinite(out.features.mean).all()
        assert out.info["v2f_track"].shape == (len(frame.batches["v2f"]),)
    assert len(out.features) > 0
    assert (out.info["feature_existence"] >= 0.5).all()


def test_grouped_gaussian_log_sums_match_numpy() -> None:
    from cooploc.estimators.rsu_bp.vehicles import log_gauss_groups
    from cooploc.gaussian import gaussian_logpdf

    rng = np.random.default_rng(5)
    P, N, A, d = 9, 50, 3, 2
    samples = rng.normal(size=(A, N, 4))
    H = np.eye(4)[:d]
    offset = rng.normal(size=(P, d))
    root = rng.normal(size=(P, d, d))
    cov = root @ np.swapaxes(root, 1, 2) + np.eye(d)
    coef = rng.normal(size=P)
    sample_of = rng.integers(0, A, P)
    group = np.array([3, 0, 0, 2, 3, 3, 0, 5, 2])              # unsorted; groups 1 and 4 empty
    got = log_gauss_groups(offset, cov, coef, sample_of, group, 6, samples, H)
    each = coef[:, None] + gaussian_logpdf(offset[:, None] + samples[sample_of] @ H.T, cov[:, None])
    for g in range(6):
        want = np.logaddexp.reduce(each[group == g], axis=0) if (group == g).any() else np.full(N, -np.inf)
        np.testing.assert_allclose(got[g], want, rtol=1e-10, atol=1e-10)


def test_grouped_log_sums_of_impossible_pairs_are_minus_infinity_not_nan() -> None:
    """A pair whose association has probability 0 (log coefficient −inf) adds nothing: a
    group of only such pairs is −inf, and one with a possible pair equals that pair alone
    (sumo-grid-tlr step 36 had whole NaN messages from −inf − −inf)."""
    from cooploc.estimators.rsu_bp.vehicles import log_gauss_groups

    rng = np.random.default_rng(6)
    samples = rng.normal(size=(1, 20, 4))
    H = np.eye(4)[:2]
    offset = rng.normal(size=(5, 2))
    cov = np.broadcast_to(np.eye(2), (5, 2, 2)).copy()
    coef = np.array([-np.inf, -np.inf, -np.inf, 0.3, -np.inf])
    group = np.array([0, 0, 1, 1, 1])
    got = log_gauss_groups(offset, cov, coef, np.zeros(5, np.int64), group, 2, samples, H)
    assert np.isneginf(got[0]).all()
    alone = log_gauss_groups(offset[3:4], cov[3:4], coef[3:4], np.zeros(1, np.int64), np.zeros(1, np.int64),
                             1, samples, H)
    np.testing.assert_array_equal(got[1], alone[0])
