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

All traffic goes through `Network.exchange`, so messages and bytes are counted.
Cost: O(N_cons E F · payload) per call.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from cooploc.errors import InvalidInputError
from cooploc.network import Network
from cooploc.types import FloatArray

__all__ = ["average_consensus", "max_consensus", "metropolis_weights", "network_sum"]

_Mask = npt.NDArray[np.bool_]


def _groups(network: Network, values: np.ndarray, members: _Mask | None) -> tuple[np.ndarray, _Mask, _Mask]:
    """Values as (n, F, rest), the member mask (n, F) and the active edges (E, F)."""
    n = network.n_agents
    if members is None:
        x = values.reshape(n, 1, -1)
        members = np.ones((n, 1), dtype=bool)
    else:
        members = np.asarray(members, dtype=bool)
        if members.shape != values.shape[:2]:
            raise InvalidInputError(
                f"consensus members must have shape {values.shape[:2]} (agents, groups), got {members.shape}"
            )
        x = values.reshape(n, members.shape[1], -1)
    on = members[network.target] & members[network.source]
    return x, members, on


def metropolis_weights(network: Network, members: _Mask | None = None) -> FloatArray:
    """(E, F) Metropolis–Hastings weight of each directed edge in each group (0 off-group).

    One round of degree exchange (counted).
    """
    members = np.ones((network.n_agents, 1), dtype=bool) if members is None else np.asarray(members, bool)
    on = members[network.target] & members[network.source]
    degree = network.gather_sum(on.astype(float))                      # (n, F) within each group
    received = network.exchange(degree, sent=on)                       # d_j arrives along j → i
    return np.where(on, 1.0 / (1.0 + np.maximum(degree[network.target], received)), 0.0)


def average_consensus(
    network: Network, values: npt.ArrayLike, n_iterations: int, members: _Mask | None = None
) -> FloatArray:
    """Each agent's estimate of the mean of `values` over its (group's) component after N_cons rounds.

    values : (n, ...) or, with `members` (n, F), (n, F, ...); non-members keep their value.
    """
    _check_iterations(n_iterations)
    values = np.array(values, dtype=float, copy=True)
    if network.n_edges == 0 or n_iterations == 0 or values.size == 0:
        return values
    x, members, on = _groups(network, values, members)
    if not on.any():
        return values
    w = metropolis_weights(network, members)[..., None]
    for _ in range(n_iterations):
        received = network.exchange(x, sent=on)
        x = x + network.gather_sum(w * (received - x[network.target]))
    return x.reshape(values.shape)


def max_consensus(
    network: Network, values: npt.ArrayLike, n_iterations: int, members: _Mask | None = None
) -> np.ndarray:
    """Each agent's running maximum of `values` over its group after N_cons rounds (exact ≥ diameter)."""
    _check_iterations(n_iterations)
    values = np.array(values, copy=True)
    if network.n_edges == 0 or n_iterations == 0 or values.size == 0:
        return values
    x, members, on = _groups(network, values, members)
    low = np.iinfo(x.dtype).min if np.issubdtype(x.dtype, np.integer) else -np.inf
    for _ in range(n_iterations):
        received = np.where(on[..., None], network.exchange(x, sent=on), low)
        x = network.gather_max(received, x)
    return x.reshape(values.shape)


def network_sum(
    network: Network, values: npt.ArrayLike, n_iterations: int, members: _Mask | None = None
) -> FloatArray:
    """Each agent's estimate of Σ values over its connected group (leader-ratio consensus).

    values : (n, ...) or, with `members` (n, F), (n, F, ...). Entries of non-members
    are returned unchanged.
    """
    _check_iterations(n_iterations)
    values = np.asarray(values, dtype=float)
    n = network.n_agents
    if n == 0 or network.n_edges == 0 or n_iterations == 0 or values.size == 0:
        return values.copy()  # an agent alone (or no rounds): its own value is all it knows
    x, members, _ = _groups(network, values, members)
    G = members.shape[1]
    ids = np.where(members, network.agents[:, None], np.iinfo(np.int64).min)
    leader = max_consensus(network, ids, n_iterations, members)            # (n, G)
    is_leader = (members & (leader == network.agents[:, None])).astype(float)
    joint = np.concatenate([x, is_leader[..., None]], axis=2)              # (n, G, rest + 1)
    averaged = average_consensus(network, joint, n_iterations, members)
    share = averaged[..., -1]
    ok = share > 1e-9
    total = np.where(ok[..., None], averaged[..., :-1] / np.where(ok, share, 1.0)[..., None], x)
    total = np.where(members[..., None], total, x)
    return total.reshape(values.shape) if G else values.copy()


def _check_iterations(n_iterations: int) -> None:
    if int(n_iterations) != n_iterations or n_iterations < 0:
        raise InvalidInputError(f"consensus n_iterations must be an integer >= 0, got {n_iterations!r}")
