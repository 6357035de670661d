"""`cooploc.network` and `cooploc.consensus`: delivery, counting, and convergence to the
exact mean / max / sum on connected graphs (against direct NumPy reductions)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cooploc.consensus import GroupConsensus, average_consensus, flood, max_consensus, network_sum
from cooploc.errors import InvalidInputError
from cooploc.network import Network, sorted_distinct

# Rounds are chosen from the spectral gap for 1e-12 relative error; values are O(1).
CONVERGED_ATOL = 1e-8


def _path(n: int, offset: int = 0) -> np.ndarray:
    return np.stack([np.arange(n - 1), np.arange(1, n)], axis=1) + offset


def _random_connected(rng: np.random.Generator, n: int, extra: int) -> np.ndarray:
    tree = np.stack([np.arange(1, n), rng.integers(0, np.arange(1, n))], axis=1)  # random tree
    more = rng.integers(0, n, size=(extra, 2))
    return np.concatenate([tree, more])


def test_exchange_delivers_along_links_and_counts() -> None:
    net = Network([10, 20, 30], [[10, 20], [30, 20]])
    assert net.n_edges == 4
    received = net.exchange(np.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]))
    got = {(int(net.agents[t]), int(net.agents[s])): r[0] for t, s, r in
           zip(net.target, net.source, received, strict=True)}
    assert got == {(10, 20): 2.0, (20, 10): 1.0, (20, 30): 3.0, (30, 20): 2.0}
    assert net.counters() == {"messages": 4, "bytes": 4 * 2 * 8}


def test_network_rejects_links_to_strangers() -> None:
    with pytest.raises(InvalidInputError, match="not agents"):
        Network([1, 2], [[1, 3]])
    with pytest.raises(InvalidInputError, match="one row per agent"):
        Network([1, 2], [[1, 2]]).exchange(np.zeros(3))


def test_duplicate_and_self_links_are_ignored() -> None:
    net = Network([0, 1], [[0, 1], [1, 0], [0, 0]])
    assert net.n_edges == 2


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 40), st.integers(0, 200), st.integers(0, 2**31 - 1))
def test_edges_are_each_direction_of_each_link_once_by_receiver(n: int, n_links: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    agents = rng.permutation(1000)[:n]
    links = agents[rng.integers(0, n, (n_links, 2))] if n else np.zeros((0, 2), dtype=np.int64)
    net = Network(agents, links)
    position = {int(a): i for i, a in enumerate(agents)}
    expected = sorted({(position[int(a)], position[int(b)]) for a, b in links if a != b}
                      | {(position[int(b)], position[int(a)]) for a, b in links if a != b})
    assert list(zip(net.target.tolist(), net.source.tolist(), strict=True)) == expected
    assert net.target.dtype == net.source.dtype == np.int64


@given(st.lists(st.integers(-2**40, 2**40), max_size=50))
def test_sorted_distinct_is_numpys_unique(values: list[int]) -> None:
    x = np.asarray(values, dtype=np.int64)
    np.testing.assert_array_equal(sorted_distinct(x), np.unique(x))


def test_metropolis_weights_are_doubly_stochastic(rng: np.random.Generator) -> None:
    n = 9
    net = Network(np.arange(n), _random_connected(rng, n, 6))
    consensus = GroupConsensus(net, None, 1)
    w = consensus.weights()
    assert w.shape == (net.n_edges,)
    W = np.zeros((n, n))
    W[net.target[consensus.edges], net.source[consensus.edges]] = w
    W[np.arange(n), np.arange(n)] = 1.0 - W.sum(axis=1)
    np.testing.assert_allclose(W, W.T, atol=1e-15)
    np.testing.assert_allclose(W.sum(axis=0), 1.0, atol=1e-15)
    assert (np.diag(W) > 0).all()


def _rounds_to_converge(net: Network, tol: float = 1e-12) -> int:
    """Rounds after which Metropolis consensus is within `tol` (relative), from the spectral gap."""
    n = net.n_agents
    consensus = GroupConsensus(net, None, 1)
    W = np.zeros((n, n))
    W[net.target[consensus.edges], net.source[consensus.edges]] = consensus.weights()
    W[np.arange(n), np.arange(n)] = 1.0 - W.sum(axis=1)
    slem = np.sort(np.abs(np.linalg.eigvalsh(W)))[-2]       # second-largest eigenvalue modulus
    return 1 if slem < tol else int(np.ceil(np.log(tol) / np.log(slem))) + 1


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 12), extra=st.integers(0, 10))
@settings(max_examples=30, deadline=None)
def test_average_max_and_sum_converge_on_connected_graphs(seed: int, n: int, extra: int) -> None:
    rng = np.random.default_rng(seed)
    ids = rng.permutation(1000)[:n]
    links = ids[_random_connected(rng, n, extra)]
    net = Network(ids, links)
    rounds = _rounds_to_converge(net)
    values = rng.normal(size=(n, 3, 2))
    avg = average_consensus(net, values, rounds)
    np.testing.assert_allclose(avg, np.broadcast_to(values.mean(axis=0), avg.shape), atol=CONVERGED_ATOL)
    mx = max_consensus(net, values, n)  # diameter ≤ n − 1
    np.testing.assert_array_equal(mx, np.broadcast_to(values.max(axis=0), mx.shape))
    total = network_sum(net, values, rounds)
    np.testing.assert_allclose(total, np.broadcast_to(values.sum(axis=0), total.shape), atol=1e-6)


def test_components_are_separate() -> None:
    net = Network(np.arange(7), np.concatenate([_path(4), _path(3, offset=4)]))
    values = np.arange(7.0)
    total = network_sum(net, values, 300)
    np.testing.assert_allclose(total, [6, 6, 6, 6, 15, 15, 15], atol=1e-6)
    np.testing.assert_array_equal(max_consensus(net, values, 5), [3, 3, 3, 3, 6, 6, 6])
    assert len(set(net.components().tolist())) == 2


def test_isolated_agent_keeps_its_value() -> None:
    net = Network([5], np.zeros((0, 2)))
    np.testing.assert_array_equal(average_consensus(net, [[2.0]], 10), [[2.0]])
    np.testing.assert_array_equal(network_sum(net, [[2.0]], 10), [[2.0]])
    empty = Network([], np.zeros((0, 2)))
    assert network_sum(empty, np.zeros((0, 2)), 3).shape == (0, 2)


def test_result_does_not_depend_on_agent_order(rng: np.random.Generator) -> None:
    n = 8
    ids = np.arange(n) * 3
    links = ids[_random_connected(rng, n, 4)]
    values = rng.normal(size=(n, 4))
    ref = network_sum(Network(ids, links), values, 7)
    perm = rng.permutation(n)
    again = network_sum(Network(ids[perm], links[::-1]), values[perm], 7)
    np.testing.assert_allclose(again, ref[perm], atol=1e-12)


def test_message_count_per_round() -> None:
    net = Network(np.arange(4), _path(4))
    average_consensus(net, np.zeros((4, 5)), 3)
    # one degree round (1 number) + three rounds of 5 floats, 6 directed edges each
    assert net.counters() == {"messages": 6 * 4, "bytes": 6 * 8 * (1 + 3 * 5)}


def test_groups_agree_only_among_members(rng: np.random.Generator) -> None:
    # chain 0-1-2-3-4; group A = {0, 1, 2}, group B = {3, 4}, group C = {0, 4} (not connected
    # inside the group: each member keeps its own value)
    net = Network(np.arange(5), _path(5))
    members = np.zeros((5, 3), dtype=bool)
    members[[0, 1, 2], 0] = True
    members[[3, 4], 1] = True
    members[[0, 4], 2] = True
    values = rng.normal(size=(5, 3, 2))
    total = network_sum(net, values, 200, members)
    np.testing.assert_allclose(total[[0, 1, 2], 0], np.broadcast_to(values[[0, 1, 2], 0].sum(0), (3, 2)),
                               atol=1e-6)
    np.testing.assert_allclose(total[[3, 4], 1], np.broadcast_to(values[[3, 4], 1].sum(0), (2, 2)), atol=1e-6)
    np.testing.assert_array_equal(total[[0, 4], 2], values[[0, 4], 2])
    np.testing.assert_array_equal(total[~members], values[~members])   # non-members untouched


def test_complete_group_is_exact_in_one_round(rng: np.random.Generator) -> None:
    n = 5
    i, j = np.triu_indices(n, 1)
    net = Network(np.arange(n), np.stack([i, j], 1))
    values = rng.normal(size=(n, 3))
    np.testing.assert_allclose(average_consensus(net, values, 1), np.broadcast_to(values.mean(0), (n, 3)),
                               atol=1e-12)


def test_group_messages_count_only_shared_blocks() -> None:
    net = Network(np.arange(3), _path(3))
    members = np.array([[True, False], [True, True], [False, True]])
    average_consensus(net, np.zeros((3, 2, 4)), 1, members)
    # edges 0↔1 carry group 0 only, 1↔2 group 1 only: 4 messages; degree round 1 number
    # per block, one averaging round 4 numbers per block
    assert net.counters() == {"messages": 4 * 2, "bytes": 4 * 8 * (1 + 4)}


def test_bad_iterations() -> None:
    with pytest.raises(InvalidInputError, match="n_iterations"):
        average_consensus(Network([0], []), [[1.0]], -1)


def test_flood_reaches_everyone_within_the_hop_count() -> None:
    net = Network(np.arange(6), _path(6))                  # 0-1-2-3-4-5
    have = np.zeros((6, 2), dtype=bool)
    have[0, 0] = True                                      # block 0 from agent 0
    have[[2, 5], 1] = True                                 # block 1 from two holders
    payload = np.zeros((6, 2, 3))
    payload[0, 0] = 1.0
    payload[2, 1] = 2.0
    payload[5, 1] = 5.0
    got, data, _ = flood(net, have, payload, 3, priority=np.arange(6)[:, None] * np.ones((1, 2), int))
    assert got[:, 0].tolist() == [True, True, True, True, False, False]   # 3 hops from agent 0
    assert got[:, 1].all()
    # the higher priority (agent 5's copy) overrides as it travels: 3 hops reach agent 2
    assert data[:, 1, 0].tolist() == [2.0, 2.0, 5.0, 5.0, 5.0, 5.0]
    got, data, _ = flood(net, have, payload, 10, priority=np.arange(6)[:, None] * np.ones((1, 2), int))
    assert got.all() and (data[:, 0, 0] == 1.0).all() and (data[:, 1, 0] == 5.0).all()


def test_flood_counts_each_forward_once() -> None:
    net = Network(np.arange(3), _path(3))
    have = np.array([[True], [False], [False]])
    flood(net, have, np.ones((3, 1, 4)), 5, priority=np.zeros((3, 1), int))
    # 0 → 1 (round 1), 1 → 0 and 1 → 2 (round 2), 2 → 1 (round 3): 4 block-messages of 4 floats
    assert net.counters() == {"messages": 4, "bytes": 4 * 4 * 8}


@pytest.mark.parametrize("seed", range(4))
def test_flood_of_sizes_only_knows_and_counts_what_the_copies_would(seed: int) -> None:
    # payload given as the numbers per block: the same holders and the same traffic as
    # carrying an (n, G, 6) array, and no copies returned
    rng = np.random.default_rng(seed)
    n, G = 9, 5
    edges = _random_connected(rng, n, 6)
    have = rng.random((n, G)) < 0.2
    priority = rng.integers(0, 4, (n, G))
    carrying, counting = Network(np.arange(n), edges), Network(np.arange(n), edges)
    got, data, _ = flood(carrying, have, rng.normal(size=(n, G, 6)), 3, priority)
    known, nothing, _ = flood(counting, have, 6, 3, priority)
    np.testing.assert_array_equal(known, got)
    assert nothing is None and data.shape == (n, G, 6)
    assert counting.counters() == carrying.counters() and carrying.counters()["messages"] > 0


def test_flood_sends_only_to_agents_that_accept() -> None:
    net = Network(np.arange(3), _path(3))                  # 0-1-2
    have = np.array([[True], [False], [False]])
    got, _, _ = flood(net, have, np.arange(3.0).reshape(3, 1, 1) + 1, 3, np.zeros((3, 1), int),
                         accept=np.array([False, False, True]))
    assert got[:, 0].tolist() == [True, False, False]     # 1 does not take it, so 2 never hears of it
    assert net.counters()["messages"] == 0
    got, _, _ = flood(net, np.array([[False], [True], [False]]), np.ones((3, 1, 1)), 1,
                         np.zeros((3, 1), int), accept=np.array([False, False, True]))
    assert got[:, 0].tolist() == [False, True, True] and net.counters()["messages"] == 1


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 10), extra=st.integers(0, 12),
       rounds=st.integers(1, 25))
@settings(max_examples=25, deadline=None, derandomize=True)
def test_runs_equal_the_weight_matrix_iteration(seed: int, n: int, extra: int, rounds: int) -> None:
    """x ← W x for N_cons rounds with the dense Metropolis matrix W, and the running maximum:
    the runs (which stop at a fixed point) give the same numbers and count every round."""
    rng = np.random.default_rng(seed)
    net = Network(np.arange(n), _random_connected(rng, n, extra))
    consensus = GroupConsensus(net, None, rounds)
    W = np.zeros((n, n))
    W[net.target[consensus.edges], net.source[consensus.edges]] = consensus.weights()
    W[np.arange(n), np.arange(n)] = 1.0 - W.sum(axis=1)
    values = rng.normal(size=(n, 3))
    expected = np.linalg.matrix_power(W, rounds) @ values
    np.testing.assert_allclose(consensus.average(values), expected, rtol=0, atol=1e-12)
    A = (W > 0).astype(int)
    reach = np.linalg.matrix_power(A, rounds) > 0          # within `rounds` hops (A has self-loops)
    expected_max = np.where(reach[:, :, None], values[None], -np.inf).max(axis=1)
    np.testing.assert_array_equal(consensus.maximum(values), expected_max)
    before = net.counters()["messages"]
    consensus.average(np.ones((n, 2)))                     # at its fixed point from the start
    assert net.counters()["messages"] - before == rounds * net.n_edges


def test_member_runs_equal_the_grouped_runs_bitwise(rng: np.random.Generator) -> None:
    """The (M, r) runs on the members' blocks give, bitwise, the members' blocks of the
    (n, G, r) runs, and the non-members keep their values there."""
    n, G = 9, 4
    net = Network(np.arange(n) * 5, np.arange(n)[_random_connected(rng, n, 8)] * 5)
    members = rng.random((n, G)) < 0.6
    values = rng.normal(size=(n, G, 3))
    grouped = GroupConsensus(net, members, 6)
    ai, gi = np.nonzero(members)
    rows = grouped.member_index(ai, gi)
    assert rows.tolist() == list(range(ai.size))
    for dense, compact in ((grouped.sum, grouped.sum_members), (grouped.average, grouped.average_members),
                           (grouped.maximum, grouped.maximum_members)):
        full = dense(values)
        np.testing.assert_array_equal(full[ai, gi], compact(values[ai, gi]))
        np.testing.assert_array_equal(full[~members], values[~members])


def test_flood_pairs_equal_the_dense_mask() -> None:
    """The sparse enumeration of (edge, fresh block) pairs is the dense mask's nonzero, in
    its order (ties between equal priorities are broken by that order)."""
    from cooploc.consensus import _fresh_pairs

    rng = np.random.default_rng(3)
    n, G = 30, 7
    links = np.array([(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < 0.2])
    net = Network(np.arange(n) * 3 + 1, links * 3 + 1)
    fresh = rng.random((n, G)) < 0.3
    into = rng.random(net.n_edges) < 0.8
    want = np.nonzero(fresh[net.source] & into[:, None])
    got = _fresh_pairs(fresh, net.source, into)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    empty = _fresh_pairs(np.zeros((n, G), bool), net.source, into)
    assert empty[0].size == 0 and empty[1].size == 0
