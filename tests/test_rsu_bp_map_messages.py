"""`rsu-bp`'s track messages (`feature_messages="tracks"`, `rsu_bp.map_messages`).

- One feature, two vehicles, five steps: the feature's information is the prior plus
  each vehicle's *latest* message, each predicted to now by the Kalman prediction of its
  Gaussian (computed here independently, forward, with `kf_predict`); the accumulated
  sum of all messages (what the fixes do) is a different number, so the test fails if a
  new message is added instead of replacing the vehicle's previous one.
- A message read at its own step is Hᵀ J H, Hᵀ j; an old one says less about the position.
- On `brambilla-crossroad` (no feature prior) the contract suite passes with track
  messages (empty frames, vehicles entering and leaving), and with vehicles made to
  enter, leave and come back (`testing.with_traffic`) the tracker keeps one message per
  (feature, vehicle), drops them with their features, and every belief stays finite.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

from cooploc.estimators.rsu_bp import RsuBP, RsuBPParams
from cooploc.estimators.rsu_bp.map_messages import TrackMessages
from cooploc.gaussian import Gaussians, kf_predict
from cooploc.motion import ConstantVelocity
from cooploc.params import param
from cooploc.testing import check_estimator, preset_recording, with_traffic

DT = 0.5
MOTION = ConstantVelocity(0.05)
# exact linear algebra on 4 × 4 matrices: agreement to rounding
TIGHT = {"rtol": 1e-9, "atol": 1e-12}


def _message(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random message (J, j): information on the feature state at its step."""
    a = rng.normal(size=(4, 4))
    J = a @ a.T + 4.0 * np.eye(4)
    return J, J @ rng.normal(size=4) * 3.0


def _forward(J: np.ndarray, j: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The message as a Gaussian N(J⁻¹ j, J⁻¹), Kalman-predicted `steps` steps, in
    information form: what it says about the feature now."""
    g = Gaussians(np.linalg.solve(J, j)[None], np.linalg.inv(J)[None])
    F, Q = MOTION.transition_matrix(DT), MOTION.noise_covariance(DT)
    for _ in range(steps):
        g = kf_predict(g, F, Q)
    lam = np.linalg.inv(g.cov[0])
    return lam, lam @ g.mean[0]


def test_each_vehicle_counts_with_its_latest_message_only() -> None:
    rng = np.random.default_rng(3)
    store = TrackMessages(np.eye(4), MOTION.transition_matrix(DT), MOTION.noise_covariance(DT))
    prior = np.diag([0.0, 0.0, 0.25, 0.25])
    feature = np.array([5])
    sent = {}                                   # (vehicle, step) → message
    for step, vehicle in [(0, 11), (1, 12), (2, 11), (3, 12)]:
        sent[vehicle, step] = _message(rng)
        store.replace(feature, np.array([vehicle]), step, *(m[None] for m in sent[vehicle, step]))
    # step 4: two rows of vehicle 11 in one batch, one message (their sum)
    (J1, j1), (J2, j2) = _message(rng), _message(rng)
    store.replace(np.array([5, 5]), np.array([11, 11]), 4, np.stack([J1, J2]), np.stack([j1, j2]))
    sent[11, 4] = (J1 + J2, j1 + j2)
    now = 6
    lam, eta = store.beliefs(now, feature, prior)[:2]
    assert len(store) == 2
    # by hand: the prior, vehicle 12's message of step 3 and vehicle 11's of step 4
    expect_lam, expect_eta = prior.copy(), np.zeros(4)
    for vehicle, step in [(12, 3), (11, 4)]:
        m_lam, m_eta = _forward(*sent[vehicle, step], now - step)
        expect_lam += m_lam
        expect_eta += m_eta
    np.testing.assert_allclose(lam[0], expect_lam, **TIGHT)
    np.testing.assert_allclose(eta[0], expect_eta, **TIGHT)
    # accumulating every message (the rule replaced) gives another belief
    accumulated = prior + sum(_forward(*sent[key], now - key[1])[0] for key in sent)
    assert not np.allclose(lam[0], accumulated, rtol=1e-3)


def test_a_message_of_this_step_is_its_information_and_ages() -> None:
    rng = np.random.default_rng(4)
    H = np.eye(4)[:2]                          # a position-only row: information of rank 2
    store = TrackMessages(H, MOTION.transition_matrix(DT), MOTION.noise_covariance(DT))
    a = rng.normal(size=(2, 2))
    J, j = a @ a.T + np.eye(2), rng.normal(size=2)
    store.replace(np.array([0]), np.array([1]), 7, J[None], j[None])
    lam, eta = store.read(7, np.array([0]))
    np.testing.assert_allclose(lam[0], H.T @ J @ H, **TIGHT)
    np.testing.assert_allclose(eta[0], H.T @ j, **TIGHT)
    # 23 steps later: on the position (at zero velocity) it says (J⁻¹ + H Q_b Hᵀ)⁻¹ < J
    older, _ = store.read(30, np.array([0]))
    assert np.linalg.eigvalsh(J - older[0][:2, :2]).min() > 0
    assert np.linalg.eigvalsh(older[0]).min() > -1e-12      # still positive semidefinite
    assert store.find(np.array([0, 0]), np.array([1, 2])).tolist() == [0, -1]


@dataclasses.dataclass(frozen=True)
class _TrackParams(RsuBPParams):
    feature_messages: str = param("tracks", choices=("fixes", "tracks"))


class _RsuBPTracks(RsuBP):
    """rsu-bp with track messages on a preset without a feature prior (not registered)."""

    name: ClassVar[str] = "rsu-bp-tracks"
    default_preset: ClassVar[str] = "brambilla-crossroad"
    Params: ClassVar[type] = _TrackParams


def test_contract_with_track_messages(seed: int) -> None:
    outcome = check_estimator(_RsuBPTracks, seed=seed, slow=False)
    assert any(v == "passed" for v in outcome.values()), outcome


def test_one_message_per_pair_and_finite_beliefs_as_vehicles_come_and_go(seed: int) -> None:
    rec = preset_recording("brambilla-crossroad", [seed, 15], {"n_steps": 40})
    ids = np.sort(rec.truth.vehicle_ids)
    # the second vehicle enters at step 8, the third is away for steps 15–24, the fourth
    # leaves at step 30
    rec = with_traffic(rec, {int(ids[1]): range(8), int(ids[2]): range(15, 25), int(ids[3]): range(30, 40)})
    est = RsuBP(rec.setup, RsuBPParams(feature_messages="tracks", n_particles=100),
                np.random.default_rng(seed))
    seen = set()
    for frame in rec.frames:
        out = est.step(frame)
        seen |= set(np.unique(frame.vehicles).tolist())
        assert np.isfinite(out.vehicles.mean).all() and np.isfinite(out.vehicles.cov).all()
        assert np.isfinite(out.features.mean).all() and np.isfinite(out.features.cov).all()
        store, f = est.tracker.store, est.tracker.features
        keys = set(zip(store.feature.tolist(), store.vehicle.tolist(), strict=True))
        assert len(keys) == len(store)                                  # one per pair
        assert set(store.feature.tolist()) <= set(f.ids.tolist())       # pruned with features
        assert set(store.vehicle.tolist()) <= seen
        assert (np.linalg.eigvalsh(f.cov) > 0).all()
    assert len(est.tracker.store) > 0
    assert int(ids[1]) in est.tracker.store.vehicle and int(ids[3]) in est.tracker.store.vehicle
