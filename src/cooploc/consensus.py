"""Average and max consensus over the V2V graph (Brambilla 2020 §IV-C, eq. 29).

Every agent i starts from a value x_i (any shape, the same for all agents) and
repeats, synchronously with its neighbours N_i, for N_cons rounds:

- average consensus with Metropolis–Hastings weights (Xiao, Boyd & Lall 2005):

      x_i ← x_i + Σ_{j ∈ N_i} w_ij (x_j − x_i),   w_ij = 1 / (1 + max(d_i, d_j)),

  where d_i is i's degree. The weights are symmetric and doubly stochastic, so on a
  connected graph every x_i converges to the exact mean of the initial values, at a
  geometric rate set by the second-largest eigenvalue modulus of the weight matrix.
  On a complete graph one round is exact. Each agent learns its neighbours' degrees
  in one extra round (counted).
- max consensus: x_i ← max(x_i, max_{j ∈ N_i} x_j), exact after as many rounds as
  the graph's diameter.

Groups. A feature is sensed by a few vehicles near it; only they hold terms of the
BP product (20) for it. Every function takes an optional `members` mask (n, F): value
block f (values (n, F, ...)) is agreed only among its members, over the links whose
both ends are members — F consensus problems in one vectorised run. Vehicles that
sense the same feature are within 2 R_s of each other, so with R_c ≥ 2 R_s (both
Brambilla scenarios) each group is a complete graph and one round is exact; the
whole-network graph, by contrast, can be a long chain that N_cons rounds do not mix.

`network_sum` turns the average into the sum Σ_i x_i that the BP products need
(eqs. 20, 26–29): the members agree on a leader by max consensus on their ids, then
run average consensus on [x_i, 1{i = leader}] jointly; the ratio of the two averages
is Σ_i x_i / 1 — the sum over the agent's connected group, exact when both runs have
converged, with no agent knowing how many members there are. Before the leader's
indicator reaches an agent the ratio is undefined; the agent then uses its own
value, the only sum it can vouch for.

`flood` spreads blocks of data (a feature's belief, a new feature's first detection)
from the agents that hold them to every agent within N rounds — max consensus on
(priority, block): an agent takes a received copy when it has none or the copy's
`priority` (e.g. its originator's id) is higher than its own, and forwards a block in
the round after its copy changed. With enough rounds every agent of a component ends
with the copy of highest priority, whatever the order of processing.

`GroupConsensus` is built once per step and membership: it finds the active (link,
group) pairs, learns the Metropolis weights (one round) and, for sums, the leader of
every group (max consensus, once), then serves any number of average / max / sum
runs — a BP iteration per run — at O(N_cons P · payload) for P active pairs.

A run stops early at a fixed point (a round in which every agent receives only what it
holds): the remaining rounds would repeat it exactly, so the result is bitwise that of
all N_cons rounds. The agents, who cannot see that every other agent is at the fixed
point, still send those rounds, so they are counted (`Network.count`).

All traffic is counted by the `Network` (`exchange_blocks`, `deliver`, `count`): an
average round is computed by one compiled pass over the active pairs
(`cooploc._consensus_kernels`), bitwise the array form, and counted as delivered.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from cooploc.errors import InvalidInputError
from cooploc.network import Network, sorted_distinct
from cooploc.types import FloatArray, IntArray

__all__ = ["GroupConsensus", "average_consensus", "flood", "max_consensus", "network_sum"]

_Mask = npt.NDArray[np.bool_]


class GroupConsensus:
    """Consensus among the members of each group over the links between members.

    Parameters
    ----------
    network : the step's V2V network.
    members : (n, G) which agents take part in each group; None: one group of all agents.
    n_iterations : N_cons, rounds per run.
    """

    def __init__(self, network: Network, members: _Mask | None, n_iterations: int) -> None:
        _check_iterations(n_iterations)
        self.network = network
        self.n_iterations = int(n_iterations)
        n = network.n_agents
        self.grouped = members is not None
        self.members = np.ones((n, 1), dtype=bool) if members is None else np.asarray(members, dtype=bool)
        if self.members.shape[0] != n:
            raise InvalidInputError(
                f"consensus members must have one row per agent ({n}), got shape {self.members.shape}"
            )
        G = self.members.shape[1]
        # the runs work on the members' blocks only, (M, r) in (agent, group) order
        self._member_slots = np.flatnonzero(self.members.reshape(-1))
        if members is None:
            # one group of all: every link, in the network's order (by receiver already)
            self.edges = np.arange(network.n_edges)
            self.blocks = np.zeros(network.n_edges, dtype=np.int64)
            self.slot = self._to = network.target
            self._from = network.source
            self._n_messages = network.n_edges
        else:
            self.edges, self.blocks = self._active_pairs(G)
            self.slot = network.target[self.edges] * G + self.blocks                # receiver (agent, group)
            order = np.argsort(self.slot, kind="stable")
            self.edges, self.blocks, self.slot = self.edges[order], self.blocks[order], self.slot[order]
            self._to = np.searchsorted(self._member_slots, self.slot)              # receiver's block
            self._from = np.searchsorted(self._member_slots, network.source[self.edges] * G + self.blocks)
            self._n_messages = sorted_distinct(self.edges).size
        self._weights: FloatArray | None = None
        self._leader: np.ndarray | None = None

    def _active_pairs(self, G: int) -> tuple[np.ndarray, np.ndarray]:
        """(edge, group) pairs whose two ends are members, edge-major then by group — without
        the (E, G) mask: each edge is tried against its target's groups only."""
        net, slots = self.network, self._member_slots
        agent_of, group_of = slots // G, slots % G
        first = np.searchsorted(agent_of, np.arange(net.n_agents + 1))          # each agent's groups
        count = np.diff(first)[net.target]
        edge = np.repeat(np.arange(net.n_edges), count)
        offset = np.arange(edge.size) - np.repeat(np.cumsum(count) - count, count)
        group = group_of[first[net.target[edge]] + offset]
        key = net.source[edge] * G + group
        found = np.minimum(np.searchsorted(slots, key), max(slots.size - 1, 0))
        both = slots[found] == key if slots.size else np.zeros(0, dtype=bool)
        return edge[both], group[both]

    @property
    def active(self) -> bool:
        return self.edges.size > 0 and self.n_iterations > 0

    def weights(self) -> FloatArray:
        """(P,) Metropolis–Hastings weight of each active pair, from one round of degree exchange."""
        if self._weights is None:
            degree = np.bincount(self._to, minlength=self._member_slots.size).astype(float)
            received = self._exchange(degree)                                          # d_j
            self._weights = 1.0 / (1.0 + np.maximum(degree[self._to], received))
        return self._weights

    def average(self, values: npt.ArrayLike) -> FloatArray:
        """Mean of `values` ((n, ...) or grouped (n, G, ...)) over each agent's group component."""
        return self._on_members(self.average_members, np.array(values, dtype=float))

    def maximum(self, values: npt.ArrayLike) -> np.ndarray:
        """Running maximum of `values` over each agent's group (exact after diameter rounds)."""
        return self._on_members(self.maximum_members, np.array(values))

    def sum(self, values: npt.ArrayLike) -> FloatArray:
        """Σ of `values` over each agent's group component (leader-ratio consensus, module doc)."""
        return self._on_members(self.sum_members, np.array(values, dtype=float))

    def member_index(self, agents: IntArray, groups: IntArray) -> IntArray:
        """Row of (agent index, group) in the members' blocks (M, ...) of the `*_members` runs."""
        return np.searchsorted(self._member_slots, agents * self.members.shape[1] + groups)

    def average_members(self, mine: FloatArray) -> FloatArray:
        """`average` on the members' blocks only: (M, r) in (agent, group) order → (M, r)."""
        mine = np.array(mine, dtype=float)
        if not self.active:
            return mine
        from cooploc._consensus_kernels import average_round

        w = self.weights()
        starts = np.r_[0, np.flatnonzero(np.diff(self._to)) + 1, self._to.size]
        receivers = self._to[starts[:-1]]
        mine = np.ascontiguousarray(mine.reshape(mine.shape[0], -1))
        out = np.empty_like(mine)
        for done in range(1, self.n_iterations + 1):
            # one round: every pair carries its sender's block (counted as delivered)
            self.network.count(self._n_messages, self.edges.size * mine.shape[1])
            if not average_round(mine, self._from, starts, receivers, w, out):
                # a fixed point: the other rounds change nothing
                self._count_rounds(self.n_iterations - done, mine.shape[1])
                break
            mine, out = out, mine
        return mine

    def maximum_members(self, mine: np.ndarray) -> np.ndarray:
        """`maximum` on the members' blocks only: (M, r) → (M, r)."""
        mine = np.array(mine)
        if not self.active:
            return mine
        starts = np.r_[0, np.flatnonzero(np.diff(self._to)) + 1]
        receivers = self._to[starts]
        for done in range(1, self.n_iterations + 1):
            received = self._exchange(mine)
            if not (received > mine[self._to]).any():   # a fixed point: the other rounds change nothing
                self._count_rounds(self.n_iterations - done, mine.shape[1])
                break
            mine[receivers] = np.maximum(mine[receivers], np.maximum.reduceat(received, starts, axis=0))
        return mine

    def sum_members(self, mine: FloatArray) -> FloatArray:
        """`sum` on the members' blocks only: (M, r) → (M, r)."""
        mine = np.asarray(mine, dtype=float)
        if not self.active:
            return mine.copy()
        ids = self.network.agents[self._member_slots // self.members.shape[1]]
        if self._leader is None:
            self._leader = self.maximum_members(ids[:, None])[:, 0]
        is_leader = (self._leader == ids).astype(float)
        averaged = self.average_members(np.concatenate([mine, is_leader[:, None]], axis=1))
        share = averaged[:, -1]
        ok = share > 1e-9
        return np.where(ok[:, None], averaged[:, :-1] / np.where(ok, share, 1.0)[:, None], mine)

    def _on_members(self, run, values: np.ndarray) -> np.ndarray:
        """Apply a `*_members` run to the members' blocks of (n, [G,] ...) values; the
        other blocks keep their values."""
        x, shape = self._as_blocks(values)
        if not self.active:
            return x.reshape(shape)
        flat = x.reshape(-1, x.shape[2])
        flat[self._member_slots] = run(flat[self._member_slots])
        return x.reshape(shape)

    def _count_rounds(self, rounds: int, width: int) -> None:
        """Count `rounds` rounds of `width` numbers per block that the agents send, but that
        the simulation skips because they would change nothing (a fixed point was reached)."""
        self.network.count(rounds * self._n_messages, rounds * self.edges.size * width)

    def _exchange(self, mine: np.ndarray) -> np.ndarray:
        """One round over the active pairs: the members' blocks (M, ...) → (P, ...) received."""
        return self.network.deliver(mine, self._from, self._n_messages)

    def _as_blocks(self, values: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
        n, G = self.members.shape
        if self.grouped and values.shape[:2] != (n, G):
            raise InvalidInputError(
                f"consensus values must have shape ({n}, {G}, ...) (agents, groups), got {values.shape}"
            )
        if not self.grouped and values.shape[:1] != (n,):
            raise InvalidInputError(f"consensus values must have one row per agent ({n}), got {values.shape}")
        rest = int(np.prod(values.shape[2 if self.grouped else 1:], dtype=np.int64))
        return values.reshape(n, G, rest), values.shape


def average_consensus(network: Network, values: npt.ArrayLike, n_iterations: int,
                      members: _Mask | None = None) -> FloatArray:
    """Each agent's estimate of the mean of `values` over its (group's) component after N_cons rounds."""
    return GroupConsensus(network, members, n_iterations).average(values)


def max_consensus(network: Network, values: npt.ArrayLike, n_iterations: int,
                  members: _Mask | None = None) -> np.ndarray:
    """Each agent's running maximum of `values` over its group after N_cons rounds (exact ≥ diameter)."""
    return GroupConsensus(network, members, n_iterations).maximum(values)


def network_sum(network: Network, values: npt.ArrayLike, n_iterations: int,
                members: _Mask | None = None) -> FloatArray:
    """Each agent's estimate of Σ values over its connected group; non-members keep their entry."""
    return GroupConsensus(network, members, n_iterations).sum(values)


def flood(network: Network, have: _Mask, payload: np.ndarray | int, n_rounds: int,
          priority: npt.ArrayLike, accept: _Mask | None = None, overwrite: bool = False
          ) -> tuple[_Mask, np.ndarray | None, np.ndarray]:
    """Spread blocks to the agents that lack them (module doc).

    Parameters
    ----------
    have : (n, G) which agents hold block g.
    payload : (n, G, ...) their copies; or an int, the numbers a block carries, where the
        caller needs only who holds what (the messages and bytes are counted alike, and
        no (n, G, ...) array is kept).
    n_rounds : forwarding rounds (blocks travel at most this many hops).
    priority : (n, G) integers ranking the copies; higher wins where copies meet.
    accept : (n,) the agents that take copies (None: all); nothing is sent to the others.
    overwrite : the received copies are written into `payload` itself (a float array),
        which is then the payload returned, instead of into a copy of it: for callers
        that replace their copies anyway (a city's (n, G, ...) copy is costly).

    Returns
    -------
    have, payload, priority
        after flooding (payload None where it was an int).
    """
    _check_iterations(n_rounds)
    have = np.array(have, dtype=bool, copy=True)
    carried = not isinstance(payload, (int, np.integer))
    payload = np.array(payload, copy=not overwrite) if carried else int(payload)
    priority = np.array(np.broadcast_to(priority, have.shape), dtype=np.int64, copy=True)
    fresh = have.copy()                                         # blocks to forward this round
    into = (np.ones(network.n_edges, dtype=bool) if accept is None
            else np.asarray(accept, dtype=bool)[network.target])   # edges into agents that take copies
    for _ in range(n_rounds if network.n_edges else 0):
        edges, blocks = _fresh_pairs(fresh, network.source, into)  # fresh blocks to each neighbour
        if edges.size == 0:
            break
        target = network.target[edges]
        rank = priority[network.source[edges], blocks]
        wanted = ~have[target, blocks] | (rank > priority[target, blocks])
        # per (target, block) keep the copy with the highest priority
        candidates = np.flatnonzero(wanted)
        order = candidates[np.lexsort((-rank[candidates], blocks[candidates], target[candidates]))]
        first = np.ones(order.size, dtype=bool)
        key = target[order] * have.shape[1] + blocks[order]
        first[1:] = key[1:] != key[:-1]
        pick = order[first]
        # every pair is delivered and counted; only the kept copies are read
        # (edges come sorted: the distinct ones are counted without a sort)
        n_messages = int(np.count_nonzero(np.diff(edges))) + 1
        fresh = np.zeros_like(have)
        t, b = target[pick], blocks[pick]
        if carried:
            payload[t, b] = network.exchange_blocks(payload, edges, blocks, n_messages, read=pick)
        else:
            network.count(n_messages, edges.size * payload)
        have[t, b] = True
        fresh[t, b] = True
        priority[t, b] = rank[pick]
    return have, (payload if carried else None), priority


def _fresh_pairs(fresh: _Mask, source: IntArray, into: _Mask) -> tuple[IntArray, IntArray]:
    """(edge, block) of every fresh block of an edge's source, on the edges into agents that
    take copies, sorted by edge then block: ``np.nonzero(fresh[source] & into[:, None])``
    without the (edges × blocks) mask, which a dense city (10⁵ edges, 10³ features) cannot
    afford; the cost is the pairs themselves."""
    agent, block = np.nonzero(fresh)                              # by agent, then block
    count = np.bincount(agent, minlength=fresh.shape[0])
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    edges = np.flatnonzero(into)
    per_edge = count[source[edges]]
    total = int(per_edge.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    pair_edge = np.repeat(edges, per_edge)
    offset = np.arange(total) - np.repeat(np.cumsum(per_edge) - per_edge, per_edge)
    return pair_edge, block[first[source[pair_edge]] + offset]


def _check_iterations(n_iterations: int) -> None:
    if int(n_iterations) != n_iterations or n_iterations < 0:
        raise InvalidInputError(f"consensus n_iterations must be an integer >= 0, got {n_iterations!r}")
