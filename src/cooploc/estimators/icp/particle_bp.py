"""`icp-da-pf`: ICP with soft BP data association and particle BPA-L with log-likelihood consensus.

Paper: Brambilla et al. 2020 (`papers/003_dd51a52f1e371d91.txt`), §IV-C, eqs. (18),
(23)–(29).

Model: that of `icp-da-lc` (unknown V2F origin, P_D, births). The association (13)–(17)
and the births are those of `icp-da-lc`; instead of the MAP pairing (30), every
pairing with probability at least `min_association` enters the localization likelihood
(18), and the BPA-L runs on particles.

Algorithm per step:

1. (23) vehicle particles s_v: J samples of each agent's Gaussian b_i^(0) (the GNSS-only
   filter). (24) feature particles s_f: J samples of an importance proposal — the
   agent's copy of the track, or a new feature's first detection — widened by
   `proposal_inflation` and `proposal_floor`, drawn with generators every agent seeds
   alike (one per step and feature), so that all agents hold the same particles
   (§IV-C, after eq. 27); the weights divide by the proposal density and multiply by
   the feature prior b_k^(0) (below).
2. (18) per vehicle–feature pair, g(f, v) = P(α = 0) + Σ_ℓ P(α = ℓ) N(z_ℓ; s_f − s_v,
   R_ℓ + h² Σ) / η(α = ℓ): every term divided by the predicted likelihood (13) the
   marginals were computed with, so that the "not detected" term is on the same scale
   (cf. Meyer et al. 2018, Proc. IEEE, eq. 49); the pair kernel is
   `particles.pair_kernel`.
3. BPA-L over particle weights: (25)–(26) m_{i→k}(s_f) ∝ Σ_v w_i^ext(v) g(f, v) from the
   extrinsic vehicle weights; (28)–(29) Σ_i log m_{i→k} by average consensus over the
   vehicles sensing k, then max consensus so that all agree; (27) m_{k→i}(s_v) ∝
   Σ_f w_k^ext(f) g(f, v); b_i ∝ Π_k m_{k→i}, b_k ∝ b_k^(0) Π_i m_{i→k}. It stops when
   no vehicle estimate moved more than the tolerances (agreed by max consensus), or
   after `max_iterations`.
4. The weighted moments of the particle beliefs are the Gaussian beliefs reported and
   shared as the agents' feature copies (no resampling: the next step samples afresh).

Choices the paper leaves open: the proposal of (24) (the paper propagates last step's
particles), the kernel widening h² Σ (h² Silverman's bandwidth times
`kernel_bandwidth`, Silverman 1986 eq. 4.14; Σ the sample covariance of the vehicle
particles plus the feature proposal's before inflation) — without it the V2F noise, far
below the spread of the beliefs, leaves almost no particle pair inside the kernel — and
J (default 500; paper 5000). Every step starts from the GNSS-only filter of each
vehicle (`feedback` is not used).

The feature prior. By default (`feature_memory = False`, as in `icp` and `icp-da-lc`)
b_k^(0) is uniform. With soft pairings that belief is improper: g(f, v) keeps the
constant P(α = 0) wherever the rows are not, so the weights P(α = 0) / proposal grow
in the proposal's tails, the reported moments sit there, and the next proposal
(inflated from them) is wider still. `feature_memory = True` uses the paper's b_k^(0)
(24), last step's belief propagated: the agent's predicted copy, its covariance
widened by `proposal_floor`. It stops that runaway on the crossroad with missed
detections but costs vehicle accuracy in traffic (the Gaussian `icp`'s double counting
of carried beliefs), so it is not the default; the measurements are in docs/icp.md,
"The feature prior of icp-da-pf".

Cost per step: the pair kernel O(B J² d) for B soft pairings, then per BPA-L iteration
O(J²) per vehicle–feature pair and O(N_cons F J) per agent for the consensus
(`benchmarks/icp.py` times it against J). G (18) is never stored: its float32 kernel
blocks (4 B J² bytes, one buffer kept across steps) are what the two products of each
iteration read, through the compiled loops of `_particle_bp_kernels`, which rebuild each
float64 element of G as they go (docs/icp.md, "Cost"). `info` adds `v2f_track` (the MAP
origin of each row), `v2f_discarded` and `births`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cooploc.consensus import GroupConsensus
from cooploc.estimators.base import checked_states
from cooploc.estimators.icp.data_association import ICPDALC, ICPDALCParams
from cooploc.gaussian import Gaussians, from_information, to_information
from cooploc.network import Network
from cooploc.params import Params, param
from cooploc.particles import (
    PairKernel,
    Particles,
    effective_sample_size,
    normalize_log_weights,
    pair_kernel,
    sample_gaussians,
    weighted_moments,
)
from cooploc.registry import register_estimator
from cooploc.types import Batch, Estimate, FloatArray, Frame, IntArray, Setup

__all__ = ["ICPDAPF", "ICPDAPFParams"]


@dataclass(frozen=True)
class ICPDAPFParams(ICPDALCParams):
    """Parameters of `icp-da-pf` (those of `icp-da-lc`, whose `threshold` and `feedback` it
    does not use).

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
    proposal_floor : standard deviations (m, m/s) added to the feature proposal (and to
        the feature prior, see `feature_memory`).
    feature_memory : False (default): a uniform feature prior b_k^(0), as `icp` and
        `icp-da-lc` use by default — with soft pairings it is improper (module
        docstring, "The feature prior"). True: the agent's predicted copy of the feature
        (the paper propagates last step's particles, eq. 24), with `proposal_floor`
        added to its covariance.
    registration : as for `icp-da-lc`, but off by default: the particle version's soft
        pairings (18) divide by η, and it has not been measured with the registered η.
    """

    n_particles: int = param(500, ge=2)
    proposal_inflation: float = param(2.0, ge=1)
    min_association: float = param(1e-3, ge=0, lt=1)
    kernel_bandwidth: float = param(1.0, ge=0)
    proposal_floor: tuple[float, float] = param((1.0, 0.1), length=2, ge=0,
                                                must="be two standard deviations >= 0 (m, m/s)")
    registration: bool = False


@register_estimator
class ICPDAPF(ICPDALC):
    """`icp-da-pf`: BPA-DA, soft-association particle BPA-L with log-likelihood consensus (§IV-C).

    Uses what `icp` uses, with the V2F association inferred.
    """

    name: ClassVar[str] = "icp-da-pf"
    bound: ClassVar[str | None] = "oracle-kf"
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
        self._kernel_buffer: np.ndarray | None = None    # the pair kernel's values, reused every step

    def step(self, frame: Frame) -> Estimate:
        local = self.local.step(frame)                              # b_i^(0), (11) / (23)
        agents, prior = local.vehicles.ids, Gaussians(local.vehicles.mean, local.vehicles.cov)
        network = Network(agents, frame.links)
        joined = ~np.isin(agents, self.features.agents)
        self._predict_tracks(agents)                                # (12) / (24)
        self._hand_over(network, joined)
        v2f = frame.batches.get("v2f")
        info: dict = {"v2f_track": np.full(0 if v2f is None else len(v2f), -1, dtype=np.int64),
                      "v2f_discarded": 0}
        posterior, iterations = prior, 0
        if v2f is not None and len(v2f) and agents.size:
            posterior, iterations = self._particle_step(frame, v2f, prior, network, info)
        else:
            self._share_tracks(network, np.zeros(self.features.block.shape[:2], dtype=bool))
        info.update(network.counters())
        info["bpa_iterations"] = iterations
        vehicles = checked_states(self.name, "vehicle", agents, posterior.mean, posterior.cov)
        return Estimate(vehicles, self._feature_estimates(info), info)

    def _particle_step(self, frame: Frame, v2f: Batch, prior: Gaussians, network: Network,
                       info: dict) -> tuple[Gaussians, int]:
        p = self.params
        da = self._bpa_da(v2f, prior, network)
        n, W = da.mask.shape
        # soft pairings (18): agent i, track k, row w with P(α_ik = w) ≥ min_association
        if da.marginals is not None:
            m = da.marginals
            soft = np.flatnonzero(m.feature >= max(p.min_association, 1e-300))  # (agent, track, row) order
            pair = da.entry_pair[soft]
            pi, pk, pw = da.pair_agent[pair], da.pair_track[pair], da.entry_row[soft]
            p_assoc = m.feature[soft]
            log_eta = da.log_likelihood[soft]
            most = np.zeros((n, W))                                   # max_k P(b_m = k) of each row
            np.maximum.at(most, (da.pair_agent[da.entry_pair], da.entry_row), m.measurement)
            claimed = most >= 0.5
        else:
            pi = pk = pw = np.zeros(0, dtype=np.int64)
            p_assoc = log_eta = np.zeros(0)
            claimed = np.zeros((n, W), dtype=bool)
        candidate = da.mask & ~claimed & (da.p_new >= 0.5)
        births, birth_g, birth_P = self._births(frame.k, network, da.beliefs, v2f, da.row_of, candidate)
        # the MAP origin of each row, for association accuracy
        track = np.full(len(v2f), -1, dtype=np.int64)
        if da.marginals is not None:
            # each row's most probable track (the first in track order among equals)
            meas = da.marginals.measurement
            ea, ek = da.pair_agent[da.entry_pair], da.pair_track[da.entry_pair]
            key = ea * W + da.entry_row
            order = np.lexsort((ek, -meas, key))
            first = order[np.r_[True, key[order[1:]] != key[order[:-1]]]] if order.size else order
            take = first[meas[first] > da.p_new[ea[first], da.entry_row[first]]]
            track[da.row_of[ea[take], da.entry_row[take]]] = self.features.ids[ek[take]]
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
            self._share_tracks(network, np.zeros((n, F), dtype=bool))
            return prior, 0
        pair_key, blk_pair = np.unique(blk_i * F + blk_k, return_inverse=True)
        pair_i, pair_k = pair_key // F, pair_key % F
        # proposals: the agent's copy of the track, or the new feature's first detection
        prop_mean, prop_cov, prior_cov, copied = self._proposals(pair_i, pair_k, ids, births, birth_g,
                                                                 birth_P)
        return self._particle_bpa_l(frame, network, prior, v2f, da.row_of, pair_i, pair_k, blk_pair, blk_w,
                                    blk_p, blk_log_eta, prop_mean, prop_cov, prior_cov, copied, ids)

    def _proposals(self, pair_i: IntArray, pair_k: IntArray, ids: IntArray, births: IntArray,
                   birth_g: FloatArray, birth_P: FloatArray
                   ) -> tuple[FloatArray, FloatArray, FloatArray, np.ndarray]:
        """Per pair (agent, feature): the proposal's mean and covariance; the covariance of
        the feature prior b_k^(0) about the same mean (`feature_memory`), the agent's copy
        widened by the floor, not inflated; and whether the pair has a copy (else it is a
        new feature: its proposal is the first detection, its prior uniform)."""
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
        floor = np.diag(floor)
        return mean, cov * self.params.proposal_inflation**2 + floor, cov + floor, known

    def _particle_bpa_l(self, frame: Frame, network: Network, prior: Gaussians, v2f: Batch,
                        row_of: IntArray, pair_i: IntArray, pair_k: IntArray, blk_pair: IntArray,
                        blk_w: IntArray, blk_p: FloatArray, blk_log_eta: FloatArray, prop_mean: FloatArray,
                        prop_cov: FloatArray, prior_cov: FloatArray, copied: np.ndarray, ids: IntArray
                        ) -> tuple[Gaussians, int]:
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
        log_prop = _proposal_logpdf(S, prop_mean, prop_cov)                               # (P, J)
        # the weights of b_k are b_k^(0) / proposal: b_k^(0) uniform, or with `feature_memory`
        # the agent's predicted copy (`_proposals`) — uniform still for a new feature, whose
        # first detection is certain (its pairing probability is 1)
        if p.feature_memory and copied.any():
            log_prop[copied] -= _proposal_logpdf(S[copied], prop_mean[copied], prior_cov[copied])
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
        self._kernel_buffer = _buffer(self._kernel_buffer, blk_pair.size * J * J)
        kernel = pair_kernel(v2f.z[rows], v2f.cov[rows] + spread, S[blk_pair], X[pair_i[blk_pair]],
                             buffer=self._kernel_buffer)
        G = _PairLikelihoods(kernel, blk_pair, blk_p * np.exp(-blk_log_eta),
                             np.maximum(1.0 - np.bincount(blk_pair, weights=blk_p, minlength=Pn), 0.0))
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
            log_ik = np.log(np.maximum(G.sum_over_vehicles(ext_v), 1e-300))             # (P, J)
            # (28)–(29): Σ_i log m_{i→k} by average consensus, then max consensus (agreement);
            # the members' blocks are the pairs, in the same (agent, feature) order
            q_sum = groups.maximum_members(groups.sum_members(log_ik))
            log_wf = q_sum - log_prop                                   # IS weights of b_k (26)
            # (27): m_{k→i}(s_v) ∝ Σ_f w_k^ext(f) g(f, v)
            ext_f = _softmax(log_wf - log_ik)
            log_kv = np.log(np.maximum(G.sum_over_features(ext_f), 1e-300))
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
        self.features.Lam[pair_i, pair_k], self.features.eta[pair_i, pair_k] = f_Lam, f_eta
        self._share_tracks(network, members)
        return Gaussians(v_mean, v_cov), iterations


class _PairLikelihoods:
    """The pair likelihoods G (P, J_f, J_v) of eq. (18), kept as the kernel's float32 blocks:
    G[q, f, v] = max(Σ_{b ∈ q} coef_b · kernel_b[f, v] + missed_q, 1e-300), with the two
    products the BPA-L needs computed without storing G (`_particle_bp_kernels`)."""

    def __init__(self, kernel: PairKernel, blk_pair: IntArray, coef: FloatArray, missed: FloatArray) -> None:
        self.order = np.argsort(blk_pair, kind="stable")       # a pair's blocks in their order
        self.starts = np.searchsorted(blk_pair[self.order], np.arange(missed.size + 1))
        self.values, self.scale = kernel.values, np.exp(kernel.log_scale)
        self.coef, self.missed = np.ascontiguousarray(coef, dtype=float), np.ascontiguousarray(missed)

    def sum_over_vehicles(self, w: FloatArray) -> FloatArray:
        """Σ_v G[q, f, v] w[q, v], (P, J_f), for w (P, J_v)."""
        from cooploc.estimators.icp._particle_bp_kernels import sum_over_vehicles

        out = np.empty((self.missed.size, self.values.shape[1]))
        sum_over_vehicles(self.values, self.scale, self.coef, self.starts, self.order, self.missed,
                          np.ascontiguousarray(w, dtype=float), out)
        return out

    def sum_over_features(self, w: FloatArray) -> FloatArray:
        """Σ_f w[q, f] G[q, f, v], (P, J_v), for w (P, J_f)."""
        from cooploc.estimators.icp._particle_bp_kernels import sum_over_features

        out = np.empty((self.missed.size, self.values.shape[2]))
        sum_over_features(self.values, self.scale, self.coef, self.starts, self.order, self.missed,
                          np.ascontiguousarray(w, dtype=float), out)
        return out


def _buffer(buffer: np.ndarray | None, size: int) -> np.ndarray:
    """A float32 buffer of at least `size` elements: `buffer` if it is large enough, else a new
    one a quarter larger (the kernel's pages are then touched once per run, not every step)."""
    if buffer is not None and buffer.size >= size:
        return buffer
    return np.empty(size + size // 4, dtype=np.float32)


def _proposal_logpdf(samples: FloatArray, mean: FloatArray, cov: FloatArray) -> FloatArray:
    """log N(s; mean_q, cov_q) of particle sets (P, J, d): one Cholesky factor per set, its
    J particles solved together (`gaussian_logpdf` would factor the covariance J times)."""
    d = mean.shape[1]
    L = np.linalg.cholesky(cov)                                               # (P, d, d)
    white = np.linalg.solve(L, np.swapaxes(samples - mean[:, None, :], 1, 2))  # L⁻¹ r, (P, d, J)
    log_det = 2.0 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
    return -0.5 * ((d * np.log(2.0 * np.pi) + log_det)[:, None] + (white**2).sum(axis=1))


def _sample_cov(samples: FloatArray) -> FloatArray:
    """Unweighted covariance (n, d, d) of particle sets (n, J, d)."""
    centred = samples - samples.mean(axis=1, keepdims=True)
    return np.einsum("njd,nje->nde", centred, centred) / max(samples.shape[1] - 1, 1)


def _softmax(log_w: FloatArray) -> FloatArray:
    """Normalised weights from log-weights along the last axis."""
    return np.exp(normalize_log_weights(log_w)[0])
