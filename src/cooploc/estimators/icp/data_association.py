"""`icp-da-lc`: ICP with BP data association at each vehicle and MAP pairing (low complexity).

Paper: Brambilla et al. 2020 (`papers/003_dd51a52f1e371d91.txt`), §IV-A/B and §IV-D.

Model: that of `icp` (§II, eqs. 1, 3, 4), with V2F rows of unknown origin: each
vehicle's rows are a set O_i, each feature is detected with probability P_D, and a
row no tracked feature explains starts a new feature.

Algorithm per step, at every agent i, before the Gaussian BPA-L of `icp`:

1. (13) the association likelihood of row ℓ and track k with Gaussian beliefs:
   η(α_ik = ℓ) = N(z_ℓ; m_k − m_i, R_ℓ + P_i + P_k), from i's belief (m_i, P_i) and
   its predicted copy of the track (12). The paper's belief is i's prior b_i^(0); here
   (`registration`, on by default) it is b_i^(0) after i has located itself against
   the tracks it holds from all its rows jointly, without row ℓ itself
   (`cooploc.estimators.icp.registration`), and b_i^(0) where that finds nothing;
2. BPA-DA (14)–(17), P iterations over the tracks i holds (the iterations of
   `association.bp_association`, Williams & Lau), over the (agent, track, row) entries
   only (`ragged_association`: bitwise the padded batch, without its padding); the
   new-feature hypothesis takes the role of clutter, with intensity
   `new_feature_intensity`;
3. (30) a track with b(α = 0) < η_TH is detected and paired with its most probable
   row; a row wanted by two tracks goes to the more probable pairing;
4. births: an unclaimed row whose new-feature probability is at least ½ starts a
   feature; the other unclaimed rows are discarded (`info["v2f_discarded"]`).

Births are agreed without a coordinator: each candidate's global state g = z + m_i
(covariance R + P_i, (m_i, P_i) the belief its (13) used) is flooded `share_hops`
rounds (the vehicles that can see the same new feature are within 2 R_s of each
other, neighbours when R_c ≥ 2 R_s); every agent groups the candidates it knows —
greedily, closest pairs first, only pairs from different vehicles within the χ²(4)
gate `BIRTH_GATE`, at most one row per vehicle in a group — and names each group after
its first member, with an id every agent computes alike (`BIRTH_ID_BASE`). Agents
that know the same candidates form the same groups.

Choices the paper leaves open: the birth rule and its gate, P_D of a tracked feature
(default 0.9; it lets a track out of a vehicle's view be "not detected"), and the
new-feature intensity. The association starts from each vehicle's GNSS-only prior (see
the defaults of `icp`), not the refined belief.

Where this departs from the paper: the registration of step 1. The paper's (13) is
evaluated pair by pair, so the BPA-DA treats a vehicle's rows as independent given
the association although they share x_i; with a wide or biased b_i^(0) (a vehicle
entering GNSS zone C, a GNSS-only filter after a turn) the pairings then need not fit
any one vehicle position, and on `sumo-grid-tlr` (seed 0) the wrong hard pairings this
made — 3 % of the rows, and 37 of the 92 rows of vehicles whose prior was wider than
8.5 m, but stiff — pulled groups of vehicles ~10 m off: vehicle RMSE 2.19 m against
`icp`'s 0.64 m; with the registration 0.64 m (docs/icp.md, "What the association
sees"). `registration = False` gives the paper's (13).

Cost per step and agent: O(P F_i W_i) for the BPA-DA over the F_i tracks agent i holds
and its W_i rows, O(H W K) for the registration (H pivot pairs, at most F_i W_i; W and K
the most rows and held tracks of any agent), O(C log C + pairs within the gate) for
grouping C birth candidates, then that of `icp`. Measured: docs/icp.md, "Cost per step".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cooploc.association import association_weights, gated_pairs, padded_groups, pair_components
from cooploc.consensus import flood
from cooploc.errors import ConfigError
from cooploc.estimators.icp.gaussian_bp import ICP, ICPParams
from cooploc.estimators.icp.ragged_association import RaggedMarginals, ragged_bp_association, ragged_layout
from cooploc.estimators.icp.registration import register_vehicles
from cooploc.gaussian import Gaussians, from_information, gaussian_logpdf
from cooploc.network import Network
from cooploc.params import Params, param
from cooploc.registry import register_estimator
from cooploc.types import Batch, FloatArray, Frame, IntArray, Setup

__all__ = ["BIRTH_GATE", "BIRTH_ID_BASE", "ICPDALC", "ICPDALCParams"]


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
    registration : True (default): each vehicle locates itself against the tracks it
        holds from all its rows jointly before (13), and each row's η uses that belief
        without the row itself (`cooploc.estimators.icp.registration`; the module
        docstring says why). False: (13) with b_i^(0), as the paper.
    """

    da_iterations: int = param(5, ge=1)
    threshold: float = param(0.5, gt=0, le=1)
    detection_probability: float = param(0.9, gt=0, lt=1,
                                         must="lie in (0, 1) (tracks out of view must be missable)")
    new_feature_intensity: float = param(1e-5, gt=0)
    registration: bool = True


@dataclass(frozen=True)
class _Association:
    """BPA-DA output of all agents: rows (n, W) padded by `mask`; the pairs (agent, track)
    of the tracks each agent holds (`pair_agent`, `pair_track`, (P,), in agent then track
    order) and their entries (pair, row slot) (`entry_pair`, `entry_row`, (E,)), stored
    flat (`ragged_association`); the marginals (None when there was nothing to
    associate); each row's new-feature probability (n, W); and the vehicle belief each
    row was associated with."""

    row_of: IntArray
    mask: np.ndarray
    pair_agent: IntArray
    pair_track: IntArray
    entry_pair: IntArray
    entry_row: IntArray
    marginals: RaggedMarginals | None
    p_new: FloatArray
    log_likelihood: FloatArray | None = None      # (E,) log η(α = ℓ) of eq. (13) of each entry
    beliefs: Gaussians | None = None              # (n, W) the vehicle belief of each row's (13)
    registered: np.ndarray | None = None          # (n,) vehicles registered (`registration`)

    def entries(self, values: FloatArray) -> FloatArray:
        """Values of the entries (E,) as (P, W), zero where a pair's agent has no such row."""
        out = np.zeros((self.pair_agent.size, self.mask.shape[1]))
        out[self.entry_pair, self.entry_row] = values
        return out


@register_estimator
class ICPDALC(ICP):
    """`icp-da-lc`: per-vehicle BPA-DA, MAP pairing with threshold, Gaussian BPA-L (Brambilla §IV-D).

    Uses what `icp` uses, with the V2F association inferred. Knowingly inconsistent, as
    `icp` (its Gaussian BPA-L is the same).
    """

    name: ClassVar[str] = "icp-da-lc"
    bound: ClassVar[str | None] = "oracle-kf"
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
        self._sensing_range = float(getattr(setup.sensors.get("v2f"), "max_range", np.inf))

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
            feature = da.entries(m.feature)                                  # (P, W)
            best = feature.argmax(axis=1)
            p_best = feature[np.arange(best.size), best]
            q = np.flatnonzero((m.missed < p.threshold) & (p_best > 0))      # in (agent, track) order
            ai, fk, w, p_q = da.pair_agent[q], da.pair_track[q], best[q], p_best[q]
            order = np.lexsort((-p_q, w, ai))
            ai, fk, w = ai[order], fk[order], w[order]
            first = np.ones(ai.size, dtype=bool)
            first[1:] = (ai[1:] != ai[:-1]) | (w[1:] != w[:-1])
            ai, fk, w = ai[first], fk[first], w[first]
            track[da.row_of[ai, w]] = self.features.ids[fk]
            claimed[ai, w] = True
        candidate = da.mask & ~claimed & (da.p_new >= 0.5)
        discarded = da.mask & ~claimed & ~candidate
        births, _, _ = self._births(frame.k, network, da.beliefs, v2f, da.row_of, candidate)
        track[da.row_of[candidate]] = births
        info = {"v2f_track": track, "v2f_discarded": int(discarded.sum()),
                "births": int(np.unique(births).size),
                "registered": 0 if da.registered is None else int(da.registered.sum())}
        return track, info

    def _bpa_da(self, v2f: Batch, prior: Gaussians, network: Network) -> _Association:
        """BPA-DA (13)–(17) of every agent over the tracks it holds and its own rows: over
        the (agent, track, row) entries only (`ragged_association`)."""
        p = self.params
        n = network.n_agents
        rows = np.flatnonzero(np.isin(v2f.sensor, network.agents))
        owner = np.searchsorted(network.agents, v2f.sensor[rows])
        index, mask = padded_groups(owner, n)                     # (n, W) rows of each agent
        row_of = rows[index]
        copies = self.features
        ai, fk = np.nonzero(copies.known())                        # pairs: the tracks each agent holds
        pair, wi = np.nonzero(mask[ai])                            # entries: each pair × its agent's rows
        W = index.shape[1]
        beliefs = Gaussians(np.repeat(prior.mean[:, None], W, 1), np.repeat(prior.cov[:, None], W, 1))
        if not copies.ids.size or not W:
            return _Association(row_of, mask, ai, fk, pair, wi, None, np.ones(index.shape), beliefs=beliefs)
        tracks = from_information(copies.Lam[ai, fk], copies.eta[ai, fk])
        log_l = self._log_eta(v2f, beliefs, tracks, ai[pair], pair, wi, row_of)
        registered = np.zeros(n, dtype=bool)
        if p.registration:
            # each vehicle locates itself against the tracks it holds (module docstring),
            # these stored (n, K) for the K tracks the busiest agent holds, not all F
            slots, held = padded_groups(ai, n)
            rank = np.arange(ai.size) - np.searchsorted(ai, ai)          # slot of each pair
            held_mean = np.where(held[..., None], tracks.mean[slots], 0.0)
            held_cov = np.where(held[..., None, None], tracks.cov[slots], 0.0)
            held_log_l = np.full((*held.shape, W), -np.inf)
            held_log_l[ai[pair], rank[pair], wi] = log_l
            z = np.where(mask[..., None], v2f.z[row_of], 0.0)
            R = np.where(mask[..., None, None], v2f.cov[row_of], np.eye(self.d))
            reg = register_vehicles(prior, z, R, mask, Gaussians(held_mean, held_cov), held, held_log_l,
                                    p.detection_probability, p.new_feature_intensity, self._position,
                                    self._sensing_range)
            registered = reg.registered
            if registered.any():
                # (13) again where the belief changed: the entries of registered vehicles
                beliefs = reg.beliefs
                redo = np.flatnonzero(registered[ai[pair]])
                log_l[redo] = self._log_eta(v2f, beliefs, tracks, ai[pair[redo]], pair[redo], wi[redo],
                                            row_of)
        # the weights of (14)–(17): entries as one (1, E) block, one miss weight for every pair
        log_psi, log_missed, _ = association_weights(log_l[None], p.detection_probability,
                                                     p.new_feature_intensity)
        log_new = np.full(mask.shape, np.log(p.new_feature_intensity))
        n_rows = mask.sum(axis=1)
        pair_start, entry_start = ragged_layout(ai, n_rows)
        marginals = ragged_bp_association(log_psi[0], np.broadcast_to(log_missed, ai.shape), log_new,
                                          pair_start, entry_start, n_rows, fk, copies.ids.size,
                                          p.da_iterations)
        return _Association(row_of, mask, ai, fk, pair, wi, marginals, marginals.clutter, log_l, beliefs,
                            registered)

    @staticmethod
    def _log_eta(v2f: Batch, beliefs: Gaussians, tracks: Gaussians, a: IntArray, pair: IntArray,
                 wi: IntArray, row_of: IntArray) -> FloatArray:
        """(13): log η(α = ℓ) = log N(z_ℓ; m_k − m_i, R_ℓ + P_i + P_k), Gaussian beliefs, of
        each entry (agent a, track pair, row slot wi) (E,); the track's belief `tracks[pair]`,
        the vehicle belief (m_i, P_i) of each row from `beliefs` (n, W)."""
        rows = row_of[a, wi]
        rel = tracks.mean[pair] - beliefs.mean[a, wi]
        S = v2f.cov[rows] + beliefs.cov[a, wi] + tracks.cov[pair]
        return gaussian_logpdf(v2f.z[rows] - rel, S)

    def _births(self, k: int, network: Network, beliefs: Gaussians, v2f: Batch,
                row_of: IntArray, candidate: np.ndarray) -> tuple[IntArray, FloatArray, FloatArray]:
        """Ids of the new features started by the candidate rows, agreed by flooding, and
        the first detection each id is named after (g, P per candidate row).

        `beliefs` (n, W) is the vehicle belief each row was associated with (`_bpa_da`).
        Each candidate's global state g = z + m_i (covariance R + P_i) is flooded
        `share_hops` rounds to the agents around; every agent then groups the candidates it knows —
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
        g = v2f.z[rows] + beliefs.mean[ai, wi]
        P = v2f.cov[rows] + beliefs.cov[ai, wi]
        C = ids.size
        n = network.n_agents
        have = np.zeros((n, C), dtype=bool)
        have[ai, np.arange(C)] = True
        # each block is a candidate's (g, P); only who knows which is used here, so the
        # flood counts their numbers without keeping (n, C) copies
        have, _, _ = flood(network, have, self.d + self.d * self.d, self.params.share_hops,
                           np.broadcast_to(network.agents[:, None], (n, C)))
        out = _names_known(have, ai, ids, agent_ids, g, P, self._position)
        # ids grow with (agent, row), the order of the candidates: a name is found by search
        lead = np.searchsorted(ids, out)
        return out, g[lead], P[lead]


def _names_known(have: np.ndarray, owner: IntArray, ids: IntArray, agents: IntArray, g: FloatArray,
                 P: FloatArray, position: tuple[int, ...]) -> IntArray:
    """The name of each candidate as its own agent (row `owner` of `have`) groups the
    candidates it knows (`_group_births` over them).

    Greedy grouping never joins candidates of different components of the gate graph
    (pairs within the gate), so an agent that knows a whole component groups it as the
    grouping of all candidates does; only the components it knows in part are grouped
    again, over the part it knows (once per distinct part: agents around share them).
    The same names as grouping each agent's set, for a cost that follows the candidates
    and not agents × candidates.
    """
    i, j, d2 = gated_pairs(g, P, agents, BIRTH_GATE, position)
    component = pair_components(ids.size, i, j)
    size = np.bincount(component)
    out = _greedy_groups(ids, agents, i, j, d2)             # every candidate known
    patterns, which = np.unique(have, axis=0, return_inverse=True)
    which = np.asarray(which).reshape(-1)[owner]              # each candidate's owner's pattern
    regrouped: dict[bytes, IntArray] = {}
    for pattern_index in np.unique(which).tolist():
        mine = np.flatnonzero(which == pattern_index)
        members = np.flatnonzero(patterns[pattern_index])
        known = np.bincount(component[members], minlength=size.size)
        for part in np.unique(component[mine][known[component[mine]] < size[component[mine]]]).tolist():
            subset = members[component[members] == part]     # the part of the component it knows
            key = subset.tobytes()
            if key not in regrouped:
                inside = np.isin(i, subset) & np.isin(j, subset)
                at = np.searchsorted(subset, np.stack([i[inside], j[inside]]))
                regrouped[key] = _greedy_groups(ids[subset], agents[subset], at[0], at[1], d2[inside])
            its = mine[component[mine] == part]
            out[its] = regrouped[key][np.searchsorted(subset, its)]
    return out


def _greedy_groups(ids: IntArray, agents: IntArray, i: IntArray, j: IntArray, d2: FloatArray) -> IntArray:
    """Group ids over the gated pairs (i, j, d²) sorted by (i, j): closest first, a pair
    joins two groups unless they share a vehicle; each group named after its first member."""
    label = np.arange(ids.size)
    order = np.argsort(d2, kind="stable")
    members = {}                                           # of each group of more than one
    vehicles = {}
    for a, b in zip(i[order].tolist(), j[order].tolist(), strict=True):
        la, lb = int(label[a]), int(label[b])
        if la == lb:
            continue
        va = vehicles.get(la, {int(agents[la])})
        vb = vehicles.get(lb, {int(agents[lb])})
        if not va.isdisjoint(vb):
            continue                                       # one row per vehicle and feature
        first, second = min(la, lb), max(la, lb)
        moved = members.pop(second, [second])
        label[moved] = first
        members[first] = members.get(first, [first]) + moved
        vehicles[first] = va | vb
        vehicles.pop(second, None)
    return ids[label]


def _group_births(ids: IntArray, agents: IntArray, g: FloatArray, P: FloatArray,
                  position: tuple[int, ...] = (0, 1)) -> IntArray:
    """Greedy gated grouping of first detections; returns the group id of each candidate.

    Pairs from different vehicles whose gap d² = Δgᵀ (P_i + P_j)⁻¹ Δg is within
    `BIRTH_GATE` are taken closest first (`association.gated_pairs`); a pair joins two
    groups unless they share a vehicle (one row per vehicle and feature).
    """
    return _greedy_groups(ids, agents, *gated_pairs(g, P, agents, BIRTH_GATE, position))
