"""`icp`: implicit cooperative positioning with known association — Gaussian BPA-L with consensus.

Paper: Brambilla et al. 2020 (`papers/003_dd51a52f1e371d91.txt`). `icp` is its
known-association reference ("ICP with known DA", the paper's ref. [40]): Gaussian
belief propagation for localization (BPA-L, eqs. 19–22), distributed over the
vehicles, with the feature beliefs (20) computed by consensus over the V2V network.
The class also holds what the data-association versions (`icp-da-lc`, `icp-da-pf`)
build on: every agent's copies of the feature beliefs, their prediction and sharing.

Model (§II): vehicle state x_i = [p; v] with the inertial model (1); GNSS of position
and velocity (3); V2F relative position and velocity z = x_k − x_i + n (4).

What runs by default, and what differs from the paper. The paper's prediction
(11)–(12) starts each step from the refined beliefs b^(N) of the step before: the
vehicles' and the features'. By default (`ICPParams.feedback = False`,
`ICPParams.feature_memory = False`) neither is carried over: every step's BPA-L
starts from each vehicle's own GNSS-only Kalman filter (`gnss-kf`) and from a uniform
prior of every feature, so it fuses this step's V2F rows with information independent
of them, and the refined vehicle beliefs are reported, never fed back. Over the run,
the only memory is in the GNSS-only filters and in the predicted feature copies that
the association (13) of the DA versions and the particle proposals of `icp-da-pf` use
(the BPA-L does not). The two switches turn the paper's recursion on (`icp` and
`icp-da-lc`; `icp-da-pf` ignores them):

- `feedback = True`: the refined b_i becomes the belief of i's own filter, so that the
  next step's prediction (11) starts from it;
- `feature_memory = True`: the predicted copy (12) is the feature prior b_k^(0) of (20)
  instead of the uniform one.

Why they are off: a Gaussian BPA-L keeps one belief per variable and no
cross-covariances, so carrying the refined vehicle and feature beliefs into the next
step counts the same V2F geometry again at every step (docs/icp.md, "Why `feedback`
and `feature_memory` are off by default"). The evidence is computed in every run of
`cooploc reproduce brambilla2020`: its report's section "The paper's recursion
(eqs. 11–12)" sets `icp` beside `icp` with both switches on (the "icp-recursion"
rows) on the same runs of the road (3 spacings) and the crossroad (N_f = 20): vehicle
RMSE with a paired 90 % interval, and the mean NEES.

Algorithm per step t, run by every vehicle i (an agent) on its own data and on what
its neighbours send it through a `Network` (`cooploc.network`):

1. Priors. b_i^(0) is i's own Kalman filter (`gnss-kf`): prediction with (1), update
   with its GNSS fix (3). i predicts its copy of every feature belief it holds (12);
   a feature nobody sensed at t−1 has a uniform belief (zero information), as the
   paper resets it (§IV-B). The feature prior b_k^(0) of the BPA-L is uniform by
   default, the predicted copy with `feature_memory` (above).
2. Association: `icp` reads the true origin of each V2F row (`Truth.origin`, the only
   truth it sees); clutter rows are discarded.
3. BPA-L (19)–(22), iterations n = 1…N, all Gaussian and in information form
   (Λ = P⁻¹, η = Λ m), so products of messages are sums:
   - (19) m_{i→k}: i's extrinsic belief B = b_i / m_{k→i} pushed through x_k = x_i + z:
     Λ = (R + B⁻¹)⁻¹, mean z + B⁻¹ b (`relative_message`).
   - (20) b_k = b_k^(0) Π_i m_{i→k}: the sum over vehicles Σ_i (Λ_{i→k}, η_{i→k}) is
     computed by every agent with `consensus.GroupConsensus.sum` (average consensus with
     Metropolis weights, N_cons rounds, leader-ratio normalisation), then added to the
     feature prior b_k^(0).
   - (21) m_{k→i}: the feature's extrinsic belief A = b_k / m_{i→k} pushed through
     x_i = x_k − z. A may be singular (a feature only i senses, with a uniform prior):
     Λ = (R + A⁻¹)⁻¹ is evaluated as A − A (A + R⁻¹)⁻¹ A and the mean term as
     (I + A R)⁻¹ a, both finite for singular A (for A = 0 the message is uniform).
   - (22) b_i = b_i^(0) Π_k m_{k→i}.
   The loop stops when no vehicle or feature estimate moved by more than 10 cm and
   0.1 m/s (paper §V-A) — each agent checks its own estimates and the agents agree by
   max consensus — or after `max_iterations`.
4. The agents within `share_hops` hops of those that sensed a feature get its new
   belief (flooding; one hop by default: every vehicle that can sense it at the next
   step, when R_c ≥ 2 R_s + v T_s, so that the traffic is local, not links × all
   features); the refined b_i is reported. The shared belief keeps the final mean with
   the covariance of the first BPA-L iteration (see "Shared tracks" below). A vehicle
   that joins takes its neighbours' copies before associating (one round).

Shared tracks. The BPA-L runs on a loopy graph (vehicles and features), so after a few
iterations its feature beliefs count the same GNSS fixes many times and are far too
confident; the association (13) of the next step would then reject the right track and
start a duplicate (measurements: docs/icp.md). The belief of the
first iteration is the product of messages computed from the vehicles' independent
priors, so it counts each fix once: its covariance goes with the final mean into the
shared copy.

The reported feature estimate of each feature is the copy of the agent that holds
the most information about it (`info["feature_source"]`).

The association's vehicle beliefs (`icp-da-lc`) start from the GNSS-only b_i^(0), which
each vehicle registers against the tracks it holds (`registration`). The paper's (13)
uses the refined predicted belief (11); its mean helps where a GNSS-only mean is far
off, but a wrong pairing then moves the mean that the next pairing starts from
(docs/icp.md: tried, and worse on sumo-braunschweig-tlr).

Choices the paper leaves open: N_cons (default 20 rounds), the maximum number of
BPA-L iterations (default 10), and how an agent learns the number of vehicles the
consensus average must be multiplied by — here the leader-ratio consensus, which
needs no count.

Cost per step and agent: O(N_iter N_cons F d²) for F features in view, d = 4. Every
agent keeps a copy slot for every track of the network ((n, F) blocks, `_FeatureCopies`),
re-indexed and flooded in place each step (docs/icp.md, "Cost per step").
`info` holds `messages` and `bytes` sent over V2V this step, `bpa_iterations`.
Derivation of the messages for singular beliefs: docs/icp.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cooploc.consensus import GroupConsensus, flood
from cooploc.errors import ConfigError
from cooploc.estimators.base import checked_states
from cooploc.estimators.gnss_kf import GnssKF, GnssKFParams
from cooploc.gaussian import (
    Gaussians,
    from_information,
    kf_predict,
    spd_inverse_and_product,
    symmetrize,
    to_information,
)
from cooploc.network import Network
from cooploc.params import Params, param
from cooploc.registry import register_estimator
from cooploc.types import AssociationTruth, Batch, Estimate, FloatArray, Frame, IntArray, Setup, StateSet

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
    feature_memory : False (default): the feature prior b_k^(0) of (20) is uniform at
        every step, so the BPA-L fuses this step's V2F rows only. True: it is the
        agent's predicted copy of the feature belief (12), as in the paper.
    feedback : False (default): every step starts from each vehicle's own GNSS-only
        filter, and the refined belief is only reported. True: the refined belief
        replaces the filter's, so that the next prediction (11) starts from it, as in
        the paper.
        Why both are off by default: with one Gaussian belief per variable and no
        cross-covariances, carrying the refined beliefs over counts the same V2F
        geometry again at every step (docs/icp.md). Evidence: `cooploc reproduce
        brambilla2020`, report section "The paper's recursion (eqs. 11–12)" (`icp`
        with both on, "icp-recursion", against the default on the same runs: RMSE
        with a paired interval, and NEES).
    share_hops : rounds of flooding that spread each feature's new belief from the
        vehicles that sensed it (step 4). 1 reaches their neighbours, which is every
        vehicle that can sense the feature at the next step when R_c ≥ 2 R_s + v T_s;
        more rounds carry every belief further across the network (N_cons rounds reach
        a whole city, at a cost that grows with links × features).
    """

    consensus_iterations: int = param(20, ge=0)
    max_iterations: int = param(10, ge=1)
    position_tolerance: float = param(0.1, gt=0)
    velocity_tolerance: float = param(0.1, gt=0)
    feature_memory: bool = False
    feedback: bool = False
    share_hops: int = param(1, ge=1)


def relative_message(A: FloatArray, a: FloatArray, z: FloatArray, R: FloatArray,
                     R_inv: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """Information-form message about y = x + z + n, n ~ N(0, R), from a belief (A, a) of x.

    Λ = (R + A⁻¹)⁻¹ = A − A (A + R⁻¹)⁻¹ A and η = (I + A R)⁻¹ a + Λ z; both are
    defined for a singular (even zero) A, where the message is uniform. Batched over
    the leading dimension: A, R (m, d, d), a, z (m, d); `R_inv` (m, d, d) is R⁻¹ if the
    caller has it. A must be symmetric positive semi-definite.

    Computed row by row with one Cholesky factor of C = A + R⁻¹ (compiled,
    `_block_kernels.relative_messages`): (I + A R)⁻¹ = R⁻¹ C⁻¹ since I + A R = C R.
    Rows where round-off left C indefinite take the LAPACK solves of the three factors.
    """
    from cooploc.estimators.icp._block_kernels import relative_messages  # numba, on use

    if R_inv is None:
        R_inv = spd_inverse_and_product(R, np.zeros(R.shape[:-1]))[0]
    A, a = np.ascontiguousarray(A, dtype=float), np.ascontiguousarray(a, dtype=float)
    Lam, eta, ok = relative_messages(A, a, np.ascontiguousarray(z, dtype=float),
                                     np.ascontiguousarray(R_inv, dtype=float))
    if not ok.all():
        bad = np.flatnonzero(~ok)
        Lam[bad], eta[bad] = _relative_message_lapack(A[bad], a[bad], z[bad], R[bad])
    return Lam, eta


def _relative_message_lapack(A: FloatArray, a: FloatArray, z: FloatArray, R: FloatArray
                             ) -> tuple[FloatArray, FloatArray]:
    """`relative_message` by LAPACK solves (LU), for C = A + R⁻¹ that Cholesky rejects."""
    d = A.shape[-1]
    R_inv = np.linalg.solve(R, np.broadcast_to(np.eye(d), R.shape))
    Lam = symmetrize(A - A @ np.linalg.solve(A + R_inv, A))
    eta = np.linalg.solve(np.eye(d) + A @ R, a[..., None])[..., 0] + np.einsum("mij,mj->mi", Lam, z)
    return Lam, eta


def _psd(M: FloatArray) -> FloatArray:
    """Nearest PSD matrices (eigenvalues clipped at 0): consensus leaves small errors.

    A symmetrised M that has a Cholesky factor is kept as it is (clipping would change
    it by round-off only); the others are clipped through their eigendecomposition.
    """
    from cooploc.estimators.icp._block_kernels import positive_definite  # numba, on use

    S = np.ascontiguousarray(symmetrize(M))
    clip = np.flatnonzero(~positive_definite(S))
    if clip.size:
        w, V = np.linalg.eigh(S[clip])
        S[clip] = (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2)
    return S


def _trace(M: FloatArray) -> FloatArray:
    """tr M over the last two axes, summed in order like `np.trace` (bitwise equal), as d
    whole-array additions instead of a reduction over each short diagonal."""
    out = M[..., 0, 0].copy()
    for j in range(1, M.shape[-1]):
        out += M[..., j, j]
    return out


def _solve_positive(A: FloatArray, b: FloatArray) -> FloatArray:
    """A⁻¹ b of symmetric A (m, d, d) and b (m, d): by Cholesky (compiled), by LAPACK's
    LU where round-off left an A indefinite."""
    from cooploc._gaussian_kernels import solve_stack  # numba, on use

    A, b = np.ascontiguousarray(A, dtype=float), np.ascontiguousarray(b, dtype=float)
    x, ok = solve_stack(A, b)
    if not ok.all():
        bad = np.flatnonzero(~ok)
        x[bad] = np.linalg.solve(A[bad], b[bad][..., None])[..., 0]
    return x


class _FeatureCopies:
    """Each agent's copy of every feature belief, information form, in one block per copy:
    `block` (n, F, d² + d) holds Λ (n, F, d, d) and η (n, F, d), which are views of it, so
    that the copies are flooded and reset in place (no (n, F) temporaries per step).
    Re-indexing (agents come and go every step) writes into the memory of the block it
    replaced two re-indexings before when that is large enough: touching fresh memory
    for a city's block cost more than the copy itself."""

    def __init__(self, d: int) -> None:
        self.d = d
        self.agents: IntArray = np.zeros(0, dtype=np.int64)
        self.ids: IntArray = np.zeros(0, dtype=np.int64)
        self.block = np.zeros((0, 0, d * d + d))
        self._spare = np.zeros(0)                    # flat memory for the next re-indexing

    @property
    def Lam(self) -> FloatArray:
        """Λ (n, F, d, d), a view: writing into it writes the copies."""
        n, F, _ = self.block.shape
        return self.block[..., : self.d * self.d].reshape(n, F, self.d, self.d)

    @property
    def eta(self) -> FloatArray:
        """η (n, F, d), a view."""
        return self.block[..., self.d * self.d:]

    def reindex(self, agents: IntArray, ids: IntArray) -> None:
        """Rows for `agents`, columns for feature `ids`; new ones start with zero information."""
        if np.array_equal(agents, self.agents) and np.array_equal(ids, self.ids):
            return
        from cooploc.estimators.icp._block_kernels import copy_copies  # numba, on use

        shape = (agents.size, ids.size, self.block.shape[2])
        size = int(np.prod(shape))
        if self._spare.size < size:                  # room for some growth of the traffic
            self._spare = np.empty(size + size // 4)
        block = self._spare[:size].reshape(shape)
        block.fill(0.0)
        ia = np.flatnonzero(np.isin(agents, self.agents))
        ja = np.searchsorted(self.agents, agents[ia])
        jf = np.flatnonzero(np.isin(ids, self.ids))
        kf = np.searchsorted(self.ids, ids[jf])
        copy_copies(self.block, ja, kf, block, ia, jf)
        self._spare = self.block.base if self.block.base is not None else self.block.reshape(-1)
        self.agents, self.ids, self.block = agents, ids, block

    def known(self) -> np.ndarray:
        """(n, F) which copies hold any information."""
        return _trace(self.Lam) > 0


@register_estimator
class ICP:
    """`icp`: Gaussian BPA-L with consensus, known association (Brambilla ref. [40]).

    Uses: identified GNSS rows and odometry (each vehicle's own filter) and V2F rows of
    the full relative state.

    Knowingly inconsistent: the BPA-L is Gaussian BP on a loopy graph (vehicles and
    features), which counts information shared by several V2F rows more than once, so
    its covariances are over-confident: its time-averaged NEES on brambilla-road lies
    above the χ² band (tests/test_consistency.py bounds it by 3× the χ²₂ mean).
    """

    name: ClassVar[str] = "icp"
    bound: ClassVar[str | None] = "oracle-kf"
    summary: ClassVar[str] = (
        "implicit cooperative positioning with KNOWN association (reads Truth.origin), "
        "distributed Gaussian BP + consensus — Brambilla 2020's bound"
    )
    Params: ClassVar[type[Params]] = ICPParams
    needs_truth: ClassVar[bool] = True
    default_preset: ClassVar[str] = "brambilla-road"
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "gnss": ("gnss-position",), "odometry": ("odometry",), "v2f": ("relative-position",)}
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
        joined = ~np.isin(agents, self.features.agents)
        self._predict_tracks(agents)                         # (12), for association and BPA-L
        self._hand_over(network, joined)
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
        vehicles = checked_states(self.name, "vehicle", agents, posterior.mean, posterior.cov)
        return Estimate(vehicles, self._feature_estimates(info), info)

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

    def _hand_over(self, network: Network, joined: np.ndarray) -> None:
        """Agents that joined this step take their neighbours' copies of the tracks (one round).

        They were not there when the last beliefs were flooded; without the copies, their
        first detections could only start new features (`icp-da-lc`), which no other
        vehicle's detections join. The highest-id neighbour's copy wins, as in the flood.
        """
        copies = self.features
        if not joined.any() or not copies.ids.size or not network.n_edges:
            return
        from cooploc.estimators.icp._block_kernels import reset_missing  # numba, on use

        n, F = copies.block.shape[:2]
        owner = np.broadcast_to(network.agents[:, None], (n, F))
        have, _, _ = flood(network, copies.known(), copies.block, 1, owner, accept=joined, overwrite=True)
        reset_missing(copies.block, have)

    def _bpa_l(self, network: Network, agents: IntArray, prior: Gaussians, v2f: Batch | None,
               rows: IntArray, slot_ids: IntArray) -> tuple[Gaussians, int]:
        """BPA-L (19)–(22) until estimates settle; returns the vehicles' posterior and iterations."""
        if rows.size == 0:
            self._share_tracks(network, np.zeros(self.features.block.shape[:2], dtype=bool))
            return prior, 0
        from cooploc.estimators.icp._block_kernels import add_rows_at  # numba, on use

        p = self.params
        n, F, d = agents.size, self.features.ids.size, self.d
        Lam0, eta0 = to_information(prior)                               # b_i^(0)
        agent = np.searchsorted(agents, v2f.sensor[rows])
        slot = np.searchsorted(self.features.ids, slot_ids[rows])
        z, R = v2f.z[rows], v2f.cov[rows]
        R_inv = spd_inverse_and_product(R, z)[0]                          # R⁻¹ of (19) and (21)
        senses = np.zeros((n, F), dtype=bool)       # the consensus group of each feature
        senses[agent, slot] = True
        feature_groups = GroupConsensus(network, senses, p.consensus_iterations)
        everyone = GroupConsensus(network, None, p.consensus_iterations)
        # only the copies of the agents sensing a feature change: they are kept as rows
        # (agent, feature) of the members' blocks, M of them, not as (n, F) arrays
        ma, mf = np.nonzero(senses)
        member = feature_groups.member_index(agent, slot)               # each row's copy
        if p.feature_memory:                                              # b_k^(0), eq. (12)
            feat_Lam0, feat_eta0 = self.features.Lam[ma, mf], self.features.eta[ma, mf]
        else:                                                             # uniform (module doc)
            feat_Lam0, feat_eta0 = np.zeros((ma.size, d, d)), np.zeros((ma.size, d))
        m = rows.size
        to_vehicle = (np.zeros((m, d, d)), np.zeros((m, d)))            # m_{k→i}, uniform at n = 0
        Lam_v, eta_v = Lam0, eta0
        feat_Lam, feat_eta = feat_Lam0, feat_eta0
        last_v, last_f = prior.mean, self._feature_means(feat_Lam, feat_eta)
        iterations = 0
        for iterations in range(1, p.max_iterations + 1):
            # (19) vehicle → feature, from i's extrinsic belief
            B = Lam_v[agent] - to_vehicle[0]
            b = eta_v[agent] - to_vehicle[1]
            to_feature = relative_message(B, b, z, R, R_inv)
            # (20) Σ_i over the vehicles sensing k, by consensus at every agent
            local = np.zeros((ma.size, d * d + d))                         # [Λ | η] of each copy
            add_rows_at(local, member, np.concatenate([to_feature[0].reshape(m, d * d), to_feature[1]], 1))
            total = feature_groups.sum_members(local)
            feat_Lam = feat_Lam0 + total[:, : d * d].reshape(-1, d, d)
            feat_eta = feat_eta0 + total[:, d * d:]
            if iterations == 1:
                first_Lam = feat_Lam
            # (21) feature → vehicle, from the agent's copy of the feature's extrinsic belief
            A = _psd(feat_Lam[member] - to_feature[0])
            a = feat_eta[member] - to_feature[1]
            to_vehicle = relative_message(A, a, -z, R, R_inv)
            # (22) b_i = b_i^(0) Π_k m_{k→i}
            Lam_v = Lam0.copy()
            eta_v = eta0.copy()
            add_rows_at(Lam_v.reshape(n, d * d), agent, to_vehicle[0].reshape(m, d * d))
            add_rows_at(eta_v, agent, to_vehicle[1])
            now_v = _solve_positive(Lam_v, eta_v)
            now_f = self._feature_means(feat_Lam, feat_eta)
            moved = self._moved(now_v, last_v)
            np.logical_or.at(moved, ma, self._moved(now_f, last_f))    # an agent's copies moved
            last_v, last_f = now_v, now_f
            still = everyone.maximum(moved.astype(np.int64))
            if not still.any():
                break
        shared_Lam = symmetrize(first_Lam)
        self.features.Lam[ma, mf] = shared_Lam
        shared_mean = self._feature_means(feat_Lam, feat_eta)
        self.features.eta[ma, mf] = np.einsum("mij,mj->mi", shared_Lam, shared_mean)
        self._share_tracks(network, senses)
        return from_information(Lam_v, eta_v), iterations

    def _share_tracks(self, network: Network, senses: np.ndarray) -> None:
        """The agents near a feature sensed this step get its new belief; the rest are reset.

        The members of a feature's group (`senses` (n, F)) hold its consensus belief, which
        the caller has written into their copies (the other copies' contents do not
        matter: each is overwritten by a copy it receives, or reset). It is flooded
        (`consensus.flood`, `share_hops` rounds, the highest-id member's copy wins) to the
        agents around, who need it to associate their detections later. A feature that
        nobody in an agent's reach sensed is reset to uniform there (paper §IV-B): its
        column is dropped once no agent holds it.
        """
        from cooploc.estimators.icp._block_kernels import reset_missing  # numba, on use

        copies = self.features
        n, F = copies.block.shape[:2]
        owner = np.broadcast_to(network.agents[:, None], (n, F))
        have, _, _ = flood(network, senses, copies.block, self.params.share_hops, owner, overwrite=True)
        reset_missing(copies.block, have)
        keep = have.any(axis=0)
        if not keep.all():
            copies.reindex(copies.agents, copies.ids[keep])

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
        known = _trace(Lam) > 0
        out = np.zeros(eta.shape)
        if known.any():
            out[known] = _solve_positive(Lam[known] + 1e-12 * np.eye(self.d), eta[known])
        return out

    def _feature_estimates(self, info: dict) -> StateSet:
        copies = self.features
        if copies.ids.size == 0 or copies.agents.size == 0:
            info["feature_source"] = {}
            return StateSet.empty(self.d)
        strength = _trace(copies.Lam)                                      # (n, F)
        best = strength.argmax(axis=0)
        cols = np.arange(copies.ids.size)
        Lam, eta = copies.Lam[best, cols], copies.eta[best, cols]
        ok = np.linalg.eigvalsh(symmetrize(Lam))[:, 0] > 0                 # only proper beliefs
        info["feature_source"] = {int(f): int(copies.agents[a]) for f, a in
                                  zip(copies.ids[ok], best[ok], strict=True)}
        if not ok.any():
            return StateSet.empty(self.d)
        belief = from_information(Lam[ok], eta[ok])
        return checked_states(self.name, "feature", copies.ids[ok], belief.mean, belief.cov)
