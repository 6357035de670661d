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

from cooploc.association import (
    AssociationMarginals,
    association_weights,
    bp_association,
    padded_groups,
)
from cooploc.consensus import GroupConsensus, flood
from cooploc.errors import ConfigError
from cooploc.estimators.gnss_kf import GnssKF, GnssKFParams
from cooploc.gaussian import (
    Gaussians,
    from_information,
    gaussian_logpdf,
    kf_predict,
    symmetrize,
    to_information,
)
from cooploc.network import Network
from cooploc.params import Params, param
from cooploc.particles import (
    Particles,
    effective_sample_size,
    normalize_log_weights,
    pair_kernel,
    sample_gaussians,
    weighted_moments,
)
from cooploc.registry import register_estimator
from cooploc.types import AssociationTruth, Batch, Estimate, FloatArray, Frame, IntArray, Setup, StateSet

__all__ = ["ICP", "ICPDALC", "ICPDAPF", "ICPDALCParams", "ICPDAPFParams", "ICPParams", "relative_message"]


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

    consensus_iterations: int = param(20, ge=0)
    max_iterations: int = param(10, ge=1)
    position_tolerance: float = param(0.1, gt=0)
    velocity_tolerance: float = param(0.1, gt=0)
    feature_memory: bool = False
    feedback: bool = False


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


@register_estimator
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
    #: whether `info["v2f_track"]` names the estimator's own feature tracks (DA versions)
    names_tracks: ClassVar[bool] = False

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
    def associate(self, frame: Frame, v2f: Batch, prior: Gaussians, network: Network
                  ) -> tuple[IntArray, dict]:
        """The feature (track) id of every V2F row (−1: discard) and diagnostics for `info`."""
        origin = np.asarray(self.truth.origin[frame.k].get("v2f", np.zeros(0, np.int64)))
        return origin.astype(np.int64), {}

    # -- one step --------------------------------------------------------------------------
    def step(self, frame: Frame) -> Estimate:
        local = self.local.step(frame)                       # b_i^(0): prediction + GNSS (11)
        agents, prior = local.vehicles.ids, Gaussians(local.vehicles.mean, local.vehicles.cov)
        network = Network(agents, frame.links)
        self._predict_tracks(agents)                         # (12), for association and BPA-L
        v2f = frame.batches.get("v2f")
        info: dict = {}
        track = np.full(0 if v2f is None else len(v2f), -1, dtype=np.int64)
        if v2f is not None and len(v2f) and agents.size:
            track, info = self.associate(frame, v2f, prior, network)
        elif self.names_tracks:
            info = {"v2f_track": track, "v2f_discarded": 0, "births": 0}
        rows = np.flatnonzero((track >= 0) & np.isin(v2f.sensor, agents)) if track.size else track
        if rows.size:
            self.features.reindex(agents, np.union1d(self.features.ids, track[rows]))
        posterior, iterations = self._bpa_l(network, agents, prior, v2f, rows, track)
        if self.params.feedback:
            self.local.vehicles.beliefs = posterior
        info.update(network.counters())
        info["bpa_iterations"] = iterations
        return Estimate(StateSet(agents, posterior.mean, posterior.cov), self._feature_estimates(info), info)

    def _predict_tracks(self, agents: IntArray) -> None:
        """(12): every agent predicts its copies; agents that left drop theirs, new ones start empty."""
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
            self._share_tracks(network, self.features.Lam, self.features.eta,
                               np.zeros(self.features.Lam.shape[:2], dtype=bool))
            return prior, 0
        p = self.params
        n, F, d = agents.size, self.features.ids.size, self.d
        Lam0, eta0 = to_information(prior)                               # b_i^(0)
        if p.feature_memory:                                              # b_k^(0), eq. (12)
            feat_Lam0, feat_eta0 = self.features.Lam.copy(), self.features.eta.copy()
        else:                                                             # uniform (module doc)
            feat_Lam0, feat_eta0 = np.zeros((n, F, d, d)), np.zeros((n, F, d))
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
        self._share_tracks(network, symmetrize(feat_Lam), feat_eta, senses)
        return from_information(Lam_v, eta_v), iterations

    def _share_tracks(self, network: Network, Lam: FloatArray, eta: FloatArray, senses: np.ndarray) -> None:
        """Every agent gets the new belief of every feature sensed this step; the rest are reset.

        The members of a feature's group hold its consensus belief; it is flooded
        (`consensus.flood`, N_cons rounds, the highest-id member's copy wins) to the other
        agents, who need it to associate their detections later. A feature that nobody
        in an agent's reach sensed is reset to uniform there (paper §IV-B): its column
        is dropped once no agent holds it.
        """
        n, F, d = Lam.shape[0], Lam.shape[1], self.d
        payload = np.concatenate([Lam.reshape(n, F, d * d), eta], axis=2)
        owner = np.broadcast_to(network.agents[:, None], (n, F))
        have, payload, _ = flood(network, senses, payload, self.params.consensus_iterations, owner)
        self.features.Lam = np.where(have[..., None, None], payload[..., : d * d].reshape(n, F, d, d), 0.0)
        self.features.eta = np.where(have[..., None], payload[..., d * d:], 0.0)
        keep = have.any(axis=0)
        if not keep.all():
            self.features.reindex(self.features.agents, self.features.ids[keep])

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


# ----------------------------------------------------------------------------------------
# ICP-DA-LC: BPA-DA at each vehicle, MAP pairing (30), Gaussian BPA-L
# ----------------------------------------------------------------------------------------

#: New features get ids BIRTH_ID_BASE + (k << 32) + (agent id << 12) + row of the first
#: detection (step k, that agent's row index): unique, and the same at every agent.
BIRTH_ID_BASE = 1 << 40
#: χ²(4) 99.9 % gate for merging first detections of one new feature by several vehicles.
BIRTH_GATE = 18.47


@dataclass(frozen=True)
class ICPDALCParams(ICPParams):
    """Parameters of `icp-da-lc` (those of `icp` plus the association).

    Attributes
    ----------
    da_iterations : P, BPA-DA iterations (14)–(16).
    threshold : η_TH of (30): feature k is detected (paired with its most probable
        measurement) when b(α = 0) < η_TH; 1 pairs every feature that can be.
    detection_probability : P_D of a tracked feature in the association model; it is
        what lets a track that is out of a vehicle's view be "not detected".
    new_feature_intensity : λ c of a V2F row that starts a new feature (units of the
        V2F likelihood, 1/(m² (m/s)²) for position-velocity rows): the "clutter"
        hypothesis of the BPA-DA. A row whose new-feature probability is at least
        ½ and that no feature claims starts a new feature; other unclaimed rows are
        discarded (counted in `info["v2f_discarded"]`).
    """

    da_iterations: int = param(5, ge=1)
    threshold: float = param(0.5, gt=0, le=1)
    detection_probability: float = param(0.9, gt=0, lt=1,
                                         must="lie in (0, 1) (tracks out of view must be missable)")
    new_feature_intensity: float = param(1e-5, gt=0)


@dataclass(frozen=True)
class _Association:
    """BPA-DA output of all agents: rows (n, W) padded by `mask`, tracks held (n, F),
    marginals (None when there was nothing to associate) and each row's new-feature
    probability (n, W)."""

    row_of: IntArray
    mask: np.ndarray
    known: np.ndarray
    marginals: AssociationMarginals | None
    p_new: FloatArray
    log_likelihood: FloatArray | None = None      # (n, F, W) log η(α = ℓ) of eq. (13)


@register_estimator
class ICPDALC(ICP):
    """`icp-da-lc`: per-vehicle BPA-DA, MAP pairing with threshold, Gaussian BPA-L (Brambilla §IV-D)."""

    name: ClassVar[str] = "icp-da-lc"
    summary: ClassVar[str] = (
        "implicit cooperative positioning with BP data association at each vehicle, MAP "
        "pairing and distributed Gaussian BP + consensus (low complexity)"
    )
    Params: ClassVar[type[Params]] = ICPDALCParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "brambilla-road"
    names_tracks: ClassVar[bool] = True

    def __init__(self, setup: Setup, params: ICPDALCParams, rng: np.random.Generator) -> None:
        super().__init__(setup, params, rng)

    def associate(self, frame: Frame, v2f: Batch, prior: Gaussians, network: Network
                  ) -> tuple[IntArray, dict]:
        """(13)–(17) and (30) at every agent, then agreement on new features."""
        p = self.params
        da = self._bpa_da(v2f, prior, network)
        track = np.full(len(v2f), -1, dtype=np.int64)
        claimed = np.zeros(da.mask.shape, dtype=bool)
        if da.marginals is not None:
            # (30): a detected track (b(α = 0) < η_TH) takes its most probable row; a row
            # wanted by two tracks goes to the more probable pairing
            m = da.marginals
            best = m.feature.argmax(axis=2)                                  # (n, F)
            p_best = np.take_along_axis(m.feature, best[..., None], 2)[..., 0]
            detected = da.known & (m.missed < p.threshold) & (p_best > 0)
            ai, fk = np.nonzero(detected)
            order = np.lexsort((-p_best[ai, fk], best[ai, fk], ai))
            ai, fk = ai[order], fk[order]
            first = np.ones(ai.size, dtype=bool)
            first[1:] = (ai[1:] != ai[:-1]) | (best[ai[1:], fk[1:]] != best[ai[:-1], fk[:-1]])
            ai, fk = ai[first], fk[first]
            w = best[ai, fk]
            track[da.row_of[ai, w]] = self.features.ids[fk]
            claimed[ai, w] = True
        candidate = da.mask & ~claimed & (da.p_new >= 0.5)
        discarded = da.mask & ~claimed & ~candidate
        births, _, _ = self._births(frame.k, network, prior, v2f, da.row_of, candidate)
        track[da.row_of[candidate]] = births
        info = {"v2f_track": track, "v2f_discarded": int(discarded.sum()),
                "births": int(np.unique(births).size)}
        return track, info

    def _bpa_da(self, v2f: Batch, prior: Gaussians, network: Network) -> _Association:
        """BPA-DA (13)–(17) of every agent over the tracks it holds, batched over agents."""
        p = self.params
        n = network.n_agents
        rows = np.flatnonzero(np.isin(v2f.sensor, network.agents))
        owner = np.searchsorted(network.agents, v2f.sensor[rows])
        index, mask = padded_groups(owner, n)                     # (n, W) rows of each agent
        row_of = rows[index]
        copies = self.features
        known = copies.known()                                     # (n, F) tracks each agent holds
        if not copies.ids.size or not index.shape[1]:
            return _Association(row_of, mask, known, None, np.ones(index.shape))
        # (13): η(α = ℓ) = N(z_ℓ; m_k − m_i, R_ℓ + P_i + P_k), Gaussian beliefs
        tracks = from_information(np.where(known[..., None, None], copies.Lam, np.eye(self.d)),
                                  np.where(known[..., None], copies.eta, 0.0))
        z, R = v2f.z[row_of], v2f.cov[row_of]                      # (n, W, d), (n, W, d, d)
        rel = tracks.mean - prior.mean[:, None, :]                 # (n, F, d)
        S = R[:, None] + prior.cov[:, None, None] + tracks.cov[:, :, None]
        log_l = gaussian_logpdf(z[:, None] - rel[:, :, None], S)   # (n, F, W)
        log_psi, log_missed, log_new = association_weights(log_l, p.detection_probability,
                                                           p.new_feature_intensity)
        marginals = bp_association(log_psi, log_missed, log_new, p.da_iterations,       # (14)–(17)
                                   feature_mask=known, measurement_mask=mask)
        return _Association(row_of, mask, known, marginals, marginals.clutter, log_l)

    def _births(self, k: int, network: Network, prior: Gaussians, v2f: Batch,
                row_of: IntArray, candidate: np.ndarray) -> tuple[IntArray, FloatArray, FloatArray]:
        """Ids of the new features started by the candidate rows, agreed by flooding, and
        the first detection each id is named after (g, P per candidate row).

        Each candidate's global state g = z + m_i (covariance R + P_i) is flooded to
        every agent (N_cons rounds); every agent then groups the candidates it knows —
        greedily, closest pairs first, only pairs from different vehicles within the
        χ²(4) gate, at most one row per vehicle in a group — and names each group after
        its first member. Agents that know the same candidates form the same groups.
        """
        ai, wi = np.nonzero(candidate)                       # in agent order, then row order
        if ai.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros((0, self.d)), np.zeros((0, self.d, self.d))
        rows = row_of[ai, wi]
        agent_ids = network.agents[ai]
        if (agent_ids >= 1 << 20).any() or (wi >= 1 << 12).any() or k >= 1 << 20:
            raise ConfigError(f"{self.name}: ids for new features need agent ids < 2^20, "
                              "< 4096 V2F rows per vehicle and < 2^20 steps")
        ids = BIRTH_ID_BASE + (np.int64(k) << 32) + (agent_ids << 12) + wi
        g = v2f.z[rows] + prior.mean[ai]
        P = v2f.cov[rows] + prior.cov[ai]
        C = ids.size
        n = network.n_agents
        have = np.zeros((n, C), dtype=bool)
        have[ai, np.arange(C)] = True
        payload = np.zeros((n, C, self.d + self.d * self.d))
        payload[ai, np.arange(C)] = np.concatenate([g, P.reshape(C, -1)], axis=1)
        have, _, _ = flood(network, have, payload, self.params.consensus_iterations,
                           np.broadcast_to(network.agents[:, None], (n, C)))
        # agents that know the same candidates compute the same grouping once
        out = np.empty(C, dtype=np.int64)
        patterns, which = np.unique(have, axis=0, return_inverse=True)
        which = np.asarray(which).reshape(-1)
        for pattern_index, pattern in enumerate(patterns):   # few distinct patterns per step
            members = np.flatnonzero(pattern)
            names = _group_births(ids[members], agent_ids[members], g[members], P[members])
            mine = np.flatnonzero(pattern & (which[ai] == pattern_index))
            out[mine] = names[np.searchsorted(members, mine)]
        # ids grow with (agent, row), the order of the candidates: a name is found by search
        lead = np.searchsorted(ids, out)
        return out, g[lead], P[lead]


def _group_births(ids: IntArray, agents: IntArray, g: FloatArray, P: FloatArray) -> IntArray:
    """Greedy gated grouping of first detections; returns the group id of each candidate."""
    C = ids.size
    label = np.arange(C)
    if C > 1:
        i, j = np.triu_indices(C, 1)
        ok = agents[i] != agents[j]
        i, j = i[ok], j[ok]
        diff = g[i] - g[j]
        d2 = np.einsum("pi,pi->p", diff, np.linalg.solve(P[i] + P[j], diff[..., None])[..., 0])
        keep = d2 < BIRTH_GATE
        i, j, d2 = i[keep], j[keep], d2[keep]
        for a, b in zip(i[np.argsort(d2, kind="stable")], j[np.argsort(d2, kind="stable")], strict=True):
            la, lb = label[a], label[b]
            if la == lb or np.isin(agents[label == la], agents[label == lb]).any():
                continue                                     # one row per vehicle and feature
            label[label == max(la, lb)] = min(la, lb)
    return ids[label]


# ----------------------------------------------------------------------------------------
# ICP-DA-PF: soft association (18) and particle BPA-L (23)–(29)
# ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ICPDAPFParams(ICPDALCParams):
    """Parameters of `icp-da-pf` (those of `icp-da-lc`, whose `threshold` it does not use).

    Attributes
    ----------
    n_particles : J_v = J_f, particles per vehicle and per feature (paper: 5000; the
        pair kernel costs J² per vehicle–feature pair, see the module doc).
    proposal_inflation : feature particles are drawn from the feature's last belief
        with its standard deviations times this factor (an importance proposal; the
        weights correct for it).
    min_association : soft pairings (18) with a smaller probability are left out.
    kernel_bandwidth : multiplier of Silverman's bandwidth with which the pair kernel is
        widened (0: the bare V2F noise, as the paper).
    proposal_floor : standard deviations (m, m/s) added to the feature proposal.
    """

    n_particles: int = param(500, ge=2)
    proposal_inflation: float = param(2.0, ge=1)
    min_association: float = param(1e-3, ge=0, lt=1)
    kernel_bandwidth: float = param(1.0, ge=0)
    proposal_floor: tuple[float, float] = param((1.0, 0.1), length=2, ge=0,
                                                must="be two standard deviations >= 0 (m, m/s)")


@register_estimator
class ICPDAPF(ICPDALC):
    """`icp-da-pf`: BPA-DA, soft-association particle BPA-L with log-likelihood consensus (§IV-C)."""

    name: ClassVar[str] = "icp-da-pf"
    summary: ClassVar[str] = (
        "implicit cooperative positioning with BP data association and particle BP: "
        "log-likelihood average + max consensus on feature particle weights"
    )
    Params: ClassVar[type[Params]] = ICPDAPFParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "brambilla-road"

    def __init__(self, setup: Setup, params: ICPDAPFParams, rng: np.random.Generator) -> None:
        super().__init__(setup, params, rng)
        self._rng = rng
        # the agents' synchronised generators: one seed every agent knows, so that all of
        # them draw the same particles for a feature (paper §IV-C, after eq. (27))
        self._shared_seed = int(rng.integers(2**62))

    def step(self, frame: Frame) -> Estimate:
        local = self.local.step(frame)                              # b_i^(0), (11) / (23)
        agents, prior = local.vehicles.ids, Gaussians(local.vehicles.mean, local.vehicles.cov)
        network = Network(agents, frame.links)
        self._predict_tracks(agents)                                # (12) / (24)
        v2f = frame.batches.get("v2f")
        info: dict = {"v2f_track": np.full(0 if v2f is None else len(v2f), -1, dtype=np.int64),
                      "v2f_discarded": 0}
        posterior, iterations = prior, 0
        if v2f is not None and len(v2f) and agents.size:
            posterior, iterations = self._particle_step(frame, v2f, prior, network, info)
        else:
            self._share_tracks(network, self.features.Lam, self.features.eta,
                               np.zeros(self.features.Lam.shape[:2], dtype=bool))
        info.update(network.counters())
        info["bpa_iterations"] = iterations
        return Estimate(StateSet(agents, posterior.mean, posterior.cov), self._feature_estimates(info), info)

    def _particle_step(self, frame: Frame, v2f: Batch, prior: Gaussians, network: Network,
                       info: dict) -> tuple[Gaussians, int]:
        p = self.params
        da = self._bpa_da(v2f, prior, network)
        n, W = da.mask.shape
        F = self.features.ids.size
        # soft pairings (18): agent i, track k, row w with P(α_ik = w) ≥ min_association
        if da.marginals is not None:
            feat_p = np.where(da.known[..., None] & da.mask[:, None, :], da.marginals.feature, 0.0)
            pi, pk, pw = np.nonzero(feat_p >= max(p.min_association, 1e-300))
            p_assoc = feat_p[pi, pk, pw]
            log_eta = da.log_likelihood[pi, pk, pw]
            claimed = da.marginals.measurement.max(axis=2, initial=0.0) >= 0.5
        else:
            pi = pk = pw = np.zeros(0, dtype=np.int64)
            p_assoc = log_eta = np.zeros(0)
            claimed = np.zeros((n, W), dtype=bool)
        candidate = da.mask & ~claimed & (da.p_new >= 0.5)
        births, birth_g, birth_P = self._births(frame.k, network, prior, v2f, da.row_of, candidate)
        # the MAP origin of each row, for association accuracy
        track = np.full(len(v2f), -1, dtype=np.int64)
        if da.marginals is not None:
            meas = da.marginals.measurement                        # (n, W, F)
            best = meas.argmax(axis=2) if F else np.zeros((n, W), dtype=np.int64)
            p_best = np.take_along_axis(meas, best[..., None], 2)[..., 0] if F else np.zeros((n, W))
            take = da.mask & (p_best > da.p_new)
            track[da.row_of[take]] = self.features.ids[best[take]]
        track[da.row_of[candidate]] = births
        info["v2f_track"] = track
        info["v2f_discarded"] = int((da.mask & ~claimed & ~candidate & ~(track[da.row_of] >= 0)).sum())
        info["births"] = int(np.unique(births).size)
        # the pairs (i, k) of the BP graph: existing tracks with soft rows, plus births
        ci, cw = np.nonzero(candidate)
        new_ids = np.unique(births)
        ids = np.union1d(self.features.ids, new_ids)
        old_col = np.searchsorted(ids, self.features.ids)
        self.features.reindex(network.agents, ids)
        F = ids.size
        blk_i = np.concatenate([pi, ci])
        blk_k = np.concatenate([old_col[pk], np.searchsorted(ids, births)])
        blk_w = np.concatenate([pw, cw])
        blk_p = np.concatenate([p_assoc, np.ones(ci.size)])
        blk_log_eta = np.concatenate([log_eta, np.zeros(ci.size)])
        if blk_i.size == 0:
            self._share_tracks(network, self.features.Lam, self.features.eta, np.zeros((n, F), dtype=bool))
            return prior, 0
        pair_key, blk_pair = np.unique(blk_i * F + blk_k, return_inverse=True)
        pair_i, pair_k = pair_key // F, pair_key % F
        # proposals: the agent's copy of the track, or the new feature's first detection
        prop_mean, prop_cov = self._proposals(pair_i, pair_k, ids, births, birth_g, birth_P)
        return self._particle_bpa_l(frame, network, prior, v2f, da.row_of, pair_i, pair_k, blk_pair, blk_w,
                                    blk_p, blk_log_eta, prop_mean, prop_cov, ids)

    def _proposals(self, pair_i: IntArray, pair_k: IntArray, ids: IntArray, births: IntArray,
                   birth_g: FloatArray, birth_P: FloatArray) -> tuple[FloatArray, FloatArray]:
        d = self.d
        mean = np.zeros((pair_i.size, d))
        cov = np.repeat(np.eye(d)[None], pair_i.size, 0)
        known = np.trace(self.features.Lam[pair_i, pair_k], axis1=1, axis2=2) > 0
        if known.any():
            belief = from_information(self.features.Lam[pair_i[known], pair_k[known]],
                                      self.features.eta[pair_i[known], pair_k[known]])
            mean[known], cov[known] = belief.mean, belief.cov
        if (~known).any():
            b = np.searchsorted(births, ids[pair_k[~known]]) if births.size else np.zeros(0, np.int64)
            order = np.argsort(births, kind="stable")
            src = order[np.minimum(b, max(births.size - 1, 0))]
            mean[~known], cov[~known] = birth_g[src], birth_P[src]
        # never narrower than `proposal_floor`: a feature belief that collapsed on few
        # particles must not starve the next step's proposal
        floor = np.zeros(d)
        floor[self._position] = self.params.proposal_floor[0] ** 2
        floor[self._velocity] = self.params.proposal_floor[1] ** 2
        return mean, cov * self.params.proposal_inflation**2 + np.diag(floor)

    def _particle_bpa_l(self, frame: Frame, network: Network, prior: Gaussians, v2f: Batch,
                        row_of: IntArray, pair_i: IntArray, pair_k: IntArray, blk_pair: IntArray,
                        blk_w: IntArray, blk_p: FloatArray, blk_log_eta: FloatArray, prop_mean: FloatArray,
                        prop_cov: FloatArray, ids: IntArray) -> tuple[Gaussians, int]:
        p = self.params
        J, d = p.n_particles, self.d
        n, F, Pn = network.n_agents, ids.size, pair_i.size
        # (23) vehicle particles: each agent samples its own belief b_i^(0)
        X = sample_gaussians(prior.mean, prior.cov, J, self._rng).samples             # (n, J, d)
        # (24) feature particles: synchronised generators, one per (step, feature)
        S = np.empty((Pn, J, d))
        for q in range(Pn):   # a few pairs per agent; each draw is vectorised over particles
            gen = np.random.default_rng([self._shared_seed, frame.k, int(ids[pair_k[q]]) & ((1 << 62) - 1)])
            S[q] = sample_gaussians(prop_mean[q:q + 1], prop_cov[q:q + 1], J, gen).samples[0]
        log_prop = gaussian_logpdf(S - prop_mean[:, None, :], prop_cov[:, None])         # (P, J)
        # g_ik(f, v) = P(α = 0) + Σ_ℓ P(α = ℓ) N(z_ℓ; s_f − s_v, R_ℓ) / η(α = ℓ), eq. (18) per
        # pair; dividing by the predicted likelihood (13) the marginals were computed with
        # makes every term a likelihood ratio, so that the "not detected" term (eq. 10's 1)
        # is on the same scale (cf. Meyer et al. 2018, Proc. IEEE, eq. 49)
        rows = row_of[pair_i[blk_pair], blk_w]
        # regularised kernel: each particle set stands for a smooth density (Silverman
        # bandwidth h² Σ, Silverman 1986 eq. 4.14) — without it the V2F noise, far below the
        # spread of the beliefs, leaves almost no particle pair inside the kernel
        h2 = p.kernel_bandwidth * (4.0 / ((d + 2) * J)) ** (2.0 / (d + 4))
        spread = h2 * (_sample_cov(X)[pair_i[blk_pair]] + prop_cov[blk_pair] / p.proposal_inflation**2)
        kernel = pair_kernel(v2f.z[rows], v2f.cov[rows] + spread, S[blk_pair], X[pair_i[blk_pair]]).dense()
        G = np.zeros((Pn, J, J))
        np.add.at(G, blk_pair, (blk_p * np.exp(-blk_log_eta))[:, None, None] * kernel)
        G += np.maximum(1.0 - np.bincount(blk_pair, weights=blk_p, minlength=Pn), 0.0)[:, None, None]
        G = np.maximum(G, 1e-300)
        members = np.zeros((n, F), dtype=bool)
        members[pair_i, pair_k] = True
        groups = GroupConsensus(network, members, p.consensus_iterations)
        everyone = GroupConsensus(network, None, p.consensus_iterations)
        log_wv = np.zeros((n, J))                                        # b_i over its particles
        log_kv = np.zeros((Pn, J))                                       # m_{k→i}(s_v)
        last_v = prior.mean
        iterations = 0
        for iterations in range(1, p.max_iterations + 1):  # noqa: B007 — reported below
            # (25)–(26): m_{i→k}(s_f) ∝ Σ_v w_i^ext(v) g(f, v), the extrinsic vehicle weights
            ext_v = _softmax(log_wv[pair_i] - log_kv)
            log_ik = np.log(np.maximum(np.einsum("qfv,qv->qf", G, ext_v), 1e-300))      # (P, J)
            # (28)–(29): Σ_i log m_{i→k} by average consensus, then max consensus (agreement)
            payload = np.zeros((n, F, J))
            payload[pair_i, pair_k] = log_ik
            q_sum = groups.maximum(groups.sum(payload))
            log_wf = q_sum[pair_i, pair_k] - log_prop                   # uniform prior, IS weights
            # (27): m_{k→i}(s_v) ∝ Σ_f w_k^ext(f) g(f, v)
            ext_f = _softmax(log_wf - log_ik)
            log_kv = np.log(np.maximum(np.einsum("qfv,qf->qv", G, ext_f), 1e-300))
            log_kv -= log_kv.max(axis=1, keepdims=True)
            log_wv = np.zeros((n, J))
            np.add.at(log_wv, pair_i, log_kv)
            now_v = np.einsum("nj,njd->nd", _softmax(log_wv), X)
            moved = self._moved(now_v, last_v)
            last_v = now_v
            if not everyone.maximum(moved.astype(np.int64)).any():
                break
        vehicles = Particles(X, normalize_log_weights(log_wv)[0])
        features = Particles(S, normalize_log_weights(log_wf)[0])
        info_ess = effective_sample_size(vehicles.log_weights)
        self._last_ess = (float(info_ess.min(initial=J)), float(effective_sample_size(features.log_weights)
                                                               .min(initial=J)))
        v_mean, v_cov = weighted_moments(vehicles)
        f_mean, f_cov = weighted_moments(features)
        f_Lam, f_eta = to_information(Gaussians(f_mean, f_cov))
        Lam = np.zeros((n, F, d, d))
        eta = np.zeros((n, F, d))
        Lam[pair_i, pair_k], eta[pair_i, pair_k] = f_Lam, f_eta
        self._share_tracks(network, Lam, eta, members)
        return Gaussians(v_mean, v_cov), iterations


def _sample_cov(samples: FloatArray) -> FloatArray:
    """Unweighted covariance (n, d, d) of particle sets (n, J, d)."""
    centred = samples - samples.mean(axis=1, keepdims=True)
    return np.einsum("njd,nje->nde", centred, centred) / max(samples.shape[1] - 1, 1)


def _softmax(log_w: FloatArray) -> FloatArray:
    """Normalised weights from log-weights along the last axis."""
    return np.exp(normalize_log_weights(log_w)[0])
