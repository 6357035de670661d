"""Implicit cooperative positioning (ICP), distributed over vehicles — Brambilla et al. 2020.

`icp` is the known-association reference of the paper ("ICP with known DA", its ref.
[40]): Gaussian belief propagation for localization (BPA-L, eqs. 19–22) with the
feature beliefs (20) computed by consensus over the V2V network.

Model (Brambilla §II): vehicle state x_i = [p; v] with the inertial model (1); GNSS of
position and velocity (3); V2F relative position and velocity z = x_k − x_i + n (4).

Algorithm per step t, run by every vehicle i (an agent) on its own data and on what
its neighbours send it through a `Network` (`cooploc.network`):

1. Prediction (11)–(12): i predicts its own belief and applies its GNSS fix (a local
   Kalman filter, `gnss-kf`), giving b_i^(0); it predicts its copy of every feature
   belief it holds, giving b_k^(0). A feature nobody sensed at t−1 has a uniform
   belief (zero information), as the paper resets it (§IV-B).
2. Association: `icp` reads the true origin of each V2F row (`Truth.origin`, the only
   truth it sees); clutter rows are discarded.
3. BPA-L (19)–(22), iterations n = 1…N, all Gaussian and in information form
   (Λ = P⁻¹, η = Λ m), so products of messages are sums:
   - (19) m_{i→k}: i's extrinsic belief B = b_i / m_{k→i} pushed through x_k = x_i + z:
     Λ = (R + B⁻¹)⁻¹, mean z + B⁻¹ b.
   - (20) b_k = b_k^(0) Π_i m_{i→k}: the sum over vehicles Σ_i (Λ_{i→k}, η_{i→k}) is
     computed by every agent with `consensus.GroupConsensus.sum` (average consensus with
     Metropolis weights, N_cons rounds, leader-ratio normalisation), then added to its
     own b_k^(0).
   - (21) m_{k→i}: the feature's extrinsic belief A = b_k / m_{i→k} pushed through
     x_i = x_k − z. A may be singular (a feature only i senses, with a uniform prior):
     Λ = (R + A⁻¹)⁻¹ is evaluated as A − A (A + R⁻¹)⁻¹ A and the mean term as
     (I + A R)⁻¹ a, both finite for singular A (then the message is uniform).
   - (22) b_i = b_i^(0) Π_k m_{k→i}.
   The loop stops when no vehicle or feature estimate moved by more than 10 cm and
   0.1 m/s (paper §V-A) — each agent checks its own estimates and the agents agree by
   max consensus — or after `max_iterations`.
4. The refined b_i is the next step's prior; each agent keeps its consensus copy of
   every feature belief.

The reported feature estimate of each feature is the copy of the agent that holds
the most information about it (`info["feature_source"]`).

Choices the paper leaves open: N_cons (default 20 rounds), the maximum number of
BPA-L iterations (default 10), and how an agent learns the number of vehicles the
consensus average must be multiplied by — here the leader-ratio consensus, which
needs no count.

Cost per step and agent: O(N_iter N_cons F d²) for F features in view, d = 4.
`info` holds `messages` and `bytes` sent over V2V this step, `bpa_iterations`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cooploc.consensus import GroupConsensus
from cooploc.errors import ConfigError
from cooploc.estimators.base import AssociationTruth
from cooploc.estimators.gnss_kf import GnssKF, GnssKFParams
from cooploc.gaussian import Gaussians, from_information, kf_predict, symmetrize, to_information
from cooploc.network import Network
from cooploc.params import Params, require
from cooploc.types import Batch, Estimate, FloatArray, Frame, IntArray, Setup, StateSet

__all__ = ["ICP", "ICPParams", "relative_message"]


@dataclass(frozen=True)
class ICPParams(Params):
    """Parameters of the Gaussian ICP estimators.

    Attributes
    ----------
    consensus_iterations : N_cons, rounds of each consensus run.
    max_iterations : cap on BPA-L iterations per step.
    position_tolerance, velocity_tolerance : BPA-L stops when no estimate moved more
        (m, m/s; paper: 0.1 and 0.1).
    """

    consensus_iterations: int = 20
    max_iterations: int = 10
    position_tolerance: float = 0.1
    velocity_tolerance: float = 0.1
    feature_memory: bool = False
    feedback: bool = False

    @classmethod
    def owner(cls) -> str:
        return "icp"

    def validate(self) -> None:
        o = self.owner()
        require(self.consensus_iterations >= 0, o, "consensus_iterations", self.consensus_iterations,
                "be >= 0")
        require(self.max_iterations >= 1, o, "max_iterations", self.max_iterations, "be >= 1")
        for key in ("position_tolerance", "velocity_tolerance"):
            value = getattr(self, key)
            require(np.isfinite(value) and value > 0, o, key, value, "be > 0")


def relative_message(A: FloatArray, a: FloatArray, z: FloatArray, R: FloatArray
                     ) -> tuple[FloatArray, FloatArray]:
    """Information-form message about y = x + z + n, n ~ N(0, R), from a belief (A, a) of x.

    Λ = (R + A⁻¹)⁻¹ = A − A (A + R⁻¹)⁻¹ A and η = (I + A R)⁻¹ a + Λ z; both are
    defined for a singular (even zero) A, where the message is uniform. Batched over
    the leading dimension: A, R (m, d, d), a, z (m, d).
    """
    d = A.shape[-1]
    R_inv = np.linalg.solve(R, np.broadcast_to(np.eye(d), R.shape))
    Lam = symmetrize(A - A @ np.linalg.solve(A + R_inv, A))
    eta = np.linalg.solve(np.eye(d) + A @ R, a[..., None])[..., 0] + np.einsum("mij,mj->mi", Lam, z)
    return Lam, eta


def _psd(M: FloatArray) -> FloatArray:
    """Nearest PSD matrices (eigenvalues clipped at 0): consensus leaves small errors."""
    w, V = np.linalg.eigh(symmetrize(M))
    return (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2)


class _FeatureCopies:
    """Each agent's copy of every feature belief, information form: Λ (n, F, d, d), η (n, F, d)."""

    def __init__(self, d: int) -> None:
        self.d = d
        self.agents: IntArray = np.zeros(0, dtype=np.int64)
        self.ids: IntArray = np.zeros(0, dtype=np.int64)
        self.Lam = np.zeros((0, 0, d, d))
        self.eta = np.zeros((0, 0, d))

    def reindex(self, agents: IntArray, ids: IntArray) -> None:
        """Rows for `agents`, columns for feature `ids`; new ones start with zero information."""
        Lam = np.zeros((agents.size, ids.size, self.d, self.d))
        eta = np.zeros((agents.size, ids.size, self.d))
        ia = np.flatnonzero(np.isin(agents, self.agents))
        ja = np.searchsorted(self.agents, agents[ia])
        jf = np.flatnonzero(np.isin(ids, self.ids))
        kf = np.searchsorted(self.ids, ids[jf])
        if ia.size and jf.size:
            Lam[np.ix_(ia, jf)] = self.Lam[np.ix_(ja, kf)]
            eta[np.ix_(ia, jf)] = self.eta[np.ix_(ja, kf)]
        self.agents, self.ids, self.Lam, self.eta = agents, ids, Lam, eta

    def known(self) -> np.ndarray:
        """(n, F) which copies hold any information."""
        return np.trace(self.Lam, axis1=-2, axis2=-1) > 0


class ICP:
    """`icp`: Gaussian BPA-L with consensus, known association (Brambilla ref. [40])."""

    name: ClassVar[str] = "icp"
    summary: ClassVar[str] = (
        "implicit cooperative positioning with KNOWN association (reads Truth.origin), "
        "distributed Gaussian BP + consensus — Brambilla 2020's bound"
    )
    Params: ClassVar[type[Params]] = ICPParams
    needs_truth: ClassVar[bool] = True
    default_preset: ClassVar[str] = "brambilla-road"

    def __init__(self, setup: Setup, params: ICPParams, rng: np.random.Generator, *,
                 truth: AssociationTruth | None = None) -> None:
        self.setup, self.params, self.truth = setup, params, truth
        self.local = GnssKF(setup, GnssKFParams(), rng)   # step 1: each vehicle's own filter
        layout = setup.vehicle_layout
        self.d = layout.dim
        self.features = _FeatureCopies(self.d)
        self._position = list(layout.position)
        self._velocity = list(layout.velocity or ())
        sensor = setup.sensors.get("v2f")
        self._H = None if sensor is None else sensor.observation_matrix(self.d)
        if self._H is not None and self._H.shape[0] != self.d:
            raise ConfigError(f"{self.name} needs V2F rows of the full relative state (eq. 4): the "
                              f"v2f sensor measures {self._H.shape[0]} of {self.d} components")

    # -- hooks -----------------------------------------------------------------------------
    def associate(self, frame: Frame, v2f: Batch, prior: Gaussians) -> tuple[IntArray, dict]:
        """The feature id of every V2F row (−1: discard) and diagnostics for `info`."""
        origin = np.asarray(self.truth.origin[frame.k].get("v2f", np.zeros(0, np.int64)))
        return origin.astype(np.int64), {}

    # -- one step --------------------------------------------------------------------------
    def step(self, frame: Frame) -> Estimate:
        local = self.local.step(frame)                       # b_i^(0): prediction + GNSS (11)
        agents, prior = local.vehicles.ids, Gaussians(local.vehicles.mean, local.vehicles.cov)
        network = Network(agents, frame.links)
        self._predict_features(agents)
        v2f = frame.batches.get("v2f")
        rows = np.zeros(0, dtype=np.int64)
        info: dict = {}
        if v2f is not None and len(v2f) and agents.size:
            slot_ids, info = self.associate(frame, v2f, prior)
            rows = np.flatnonzero((slot_ids >= 0) & np.isin(v2f.sensor, agents))
            ids = np.union1d(self.features.ids, slot_ids[rows])
            self.features.reindex(agents, ids)
        posterior, iterations = self._bpa_l(network, agents, prior, v2f, rows,
                                            slot_ids if rows.size else rows)
        if self.params.feedback:
            self.local.vehicles.beliefs = posterior
        self._forget_unseen()
        info.update(network.counters())
        info["bpa_iterations"] = iterations
        return Estimate(StateSet(agents, posterior.mean, posterior.cov), self._feature_estimates(info), info)

    def _predict_features(self, agents: IntArray) -> None:
        """(12): every agent predicts its copies; agents that left drop theirs, new ones start empty."""
        if not self.params.feature_memory:
            self.features.reindex(agents, np.zeros(0, dtype=np.int64))
        self.features.reindex(agents, self.features.ids)
        known = self.features.known()
        if not known.any() or self.setup.feature_motion is None:
            return
        motion = self.setup.feature_motion
        Lam, eta = self.features.Lam[known], self.features.eta[known]
        belief = from_information(Lam + 1e-12 * np.eye(self.d), eta)
        Q = motion.noise_covariance(self.setup.dt, belief.mean)
        predicted = kf_predict(belief, motion.transition_matrix(self.setup.dt), Q)
        self.features.Lam[known], self.features.eta[known] = to_information(predicted)

    def _bpa_l(self, network: Network, agents: IntArray, prior: Gaussians, v2f: Batch | None,
               rows: IntArray, slot_ids: IntArray) -> tuple[Gaussians, int]:
        """BPA-L (19)–(22) until estimates settle; returns the vehicles' posterior and iterations."""
        if rows.size == 0:
            return prior, 0
        p = self.params
        n, F, d = agents.size, self.features.ids.size, self.d
        Lam0, eta0 = to_information(prior)                               # b_i^(0)
        feat_Lam0, feat_eta0 = self.features.Lam.copy(), self.features.eta.copy()  # b_k^(0)
        agent = np.searchsorted(agents, v2f.sensor[rows])
        slot = np.searchsorted(self.features.ids, slot_ids[rows])
        z, R = v2f.z[rows], v2f.cov[rows]
        senses = np.zeros((n, F), dtype=bool)       # the consensus group of each feature
        senses[agent, slot] = True
        feature_groups = GroupConsensus(network, senses, p.consensus_iterations)
        everyone = GroupConsensus(network, None, p.consensus_iterations)
        m = rows.size
        to_vehicle = (np.zeros((m, d, d)), np.zeros((m, d)))            # m_{k→i}, uniform at n = 0
        Lam_v, eta_v = Lam0, eta0
        feat_Lam, feat_eta = feat_Lam0, feat_eta0
        last_v, last_f = prior.mean, self._feature_means(feat_Lam, feat_eta)
        iterations = 0
        for iterations in range(1, p.max_iterations + 1):  # noqa: B007 — reported below
            # (19) vehicle → feature, from i's extrinsic belief
            B = Lam_v[agent] - to_vehicle[0]
            b = eta_v[agent] - to_vehicle[1]
            to_feature = relative_message(B, b, z, R)
            # (20) Σ_i over the vehicles sensing k, by consensus at every agent
            local_Lam = np.zeros((n, F, d, d))
            local_eta = np.zeros((n, F, d))
            np.add.at(local_Lam, (agent, slot), to_feature[0])
            np.add.at(local_eta, (agent, slot), to_feature[1])
            payload = np.concatenate([local_Lam.reshape(n, F, -1), local_eta], axis=2)
            total = feature_groups.sum(payload)
            feat_Lam = feat_Lam0 + total[..., : d * d].reshape(n, F, d, d)
            feat_eta = feat_eta0 + total[..., d * d:]
            # (21) feature → vehicle, from the agent's copy of the feature's extrinsic belief
            A = _psd(feat_Lam[agent, slot] - to_feature[0])
            a = feat_eta[agent, slot] - to_feature[1]
            to_vehicle = relative_message(A, a, -z, R)
            # (22) b_i = b_i^(0) Π_k m_{k→i}
            Lam_v = Lam0.copy()
            eta_v = eta0.copy()
            np.add.at(Lam_v, agent, to_vehicle[0])
            np.add.at(eta_v, agent, to_vehicle[1])
            now_v = np.linalg.solve(Lam_v, eta_v[..., None])[..., 0]
            now_f = self._feature_means(feat_Lam, feat_eta)
            moved = np.maximum(self._moved(now_v, last_v), self._moved(now_f, last_f).max(axis=1, initial=0))
            last_v, last_f = now_v, now_f
            still = everyone.maximum(moved.astype(np.int64))
            if not still.any():
                break
        self.features.Lam, self.features.eta = symmetrize(feat_Lam), feat_eta
        return from_information(Lam_v, eta_v), iterations

    def _moved(self, now: FloatArray, before: FloatArray) -> np.ndarray:
        """Whether an estimate moved more than the tolerances (…, d) → (…,)."""
        p = self.params
        dp = np.linalg.norm(now[..., self._position] - before[..., self._position], axis=-1)
        moved = dp > p.position_tolerance
        if self._velocity:
            dv = np.linalg.norm(now[..., self._velocity] - before[..., self._velocity], axis=-1)
            moved |= dv > p.velocity_tolerance
        return moved

    def _feature_means(self, Lam: FloatArray, eta: FloatArray) -> FloatArray:
        """Means of the copies that hold information (zeros elsewhere)."""
        known = np.trace(Lam, axis1=-2, axis2=-1) > 0
        out = np.zeros(eta.shape)
        if known.any():
            out[known] = np.linalg.solve(Lam[known] + 1e-12 * np.eye(self.d), eta[known][..., None])[..., 0]
        return out

    def _forget_unseen(self) -> None:
        """A feature no agent holds information about is uniform again: drop its column."""
        keep = self.features.known().any(axis=0)
        if not keep.all():
            self.features.reindex(self.features.agents, self.features.ids[keep])

    def _feature_estimates(self, info: dict) -> StateSet:
        copies = self.features
        if copies.ids.size == 0 or copies.agents.size == 0:
            info["feature_source"] = {}
            return StateSet.empty(self.d)
        strength = np.trace(copies.Lam, axis1=-2, axis2=-1)               # (n, F)
        best = strength.argmax(axis=0)
        cols = np.arange(copies.ids.size)
        Lam, eta = copies.Lam[best, cols], copies.eta[best, cols]
        ok = np.linalg.eigvalsh(symmetrize(Lam))[:, 0] > 0                 # only proper beliefs
        info["feature_source"] = {int(f): int(copies.agents[a]) for f, a in
                                  zip(copies.ids[ok], best[ok], strict=True)}
        if not ok.any():
            return StateSet.empty(self.d)
        belief = from_information(Lam[ok], eta[ok])
        return StateSet(copies.ids[ok], belief.mean, belief.cov)
