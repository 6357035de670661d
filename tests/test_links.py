"""`geometry.links_within` and `geometry.close_pairs`: the k-d tree gives exactly the pairs
(and the order) of the dense distance matrix they replace, so recordings stay the same."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cooploc.geometry import close_pairs, links_within


def _dense_links(ids: np.ndarray, positions: np.ndarray, radius: float) -> np.ndarray:
    """The reference: the upper triangle of the n × n distance matrix, row by row."""
    d = np.hypot(*(positions[:, None, :] - positions[None, :, :]).transpose(2, 0, 1))
    i, j = np.nonzero(np.triu(d <= radius, k=1))
    return np.stack([ids[i], ids[j]], axis=1)


# points on a coarse lattice (many exact ties at the radius) and scattered ones
_points = st.integers(0, 60).flatmap(lambda n: st.tuples(
    st.just(n), st.integers(0, 2**32 - 1), st.booleans(), st.sampled_from([0.0, 1.0, 5.0, 10.0, 250.0])))


@settings(max_examples=60, derandomize=True, deadline=None)
@given(_points)
def test_links_are_the_pairs_and_order_of_the_distance_matrix(case: tuple[int, int, bool, float]) -> None:
    n, seed, lattice, radius = case
    rng = np.random.default_rng(seed)
    positions = (rng.integers(0, 6, (n, 2)) * 3.0 + 4e3) if lattice else rng.uniform(-50, 50, (n, 2))
    ids = rng.permutation(10 * n + 1)[:n].astype(np.int64)
    links = links_within(ids, positions, radius)
    assert links.dtype == np.int64 and links.shape[1] == 2
    np.testing.assert_array_equal(links, _dense_links(ids, positions, radius))


def test_tree_order_keeps_the_k_d_tree_pairs() -> None:
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(3)
    positions, ids = rng.uniform(0, 100, (80, 2)), np.arange(80, dtype=np.int64) + 7
    tree = links_within(ids, positions, 20.0, tree_order=True)
    np.testing.assert_array_equal(tree, ids[cKDTree(positions).query_pairs(20.0, output_type="ndarray")])
    # the same set as the sorted default
    same_set = np.unique(np.sort(tree, axis=1), axis=0)
    np.testing.assert_array_equal(same_set, links_within(ids, positions, 20.0))


def test_links_of_no_or_one_point() -> None:
    for n in (0, 1):
        links = links_within(np.arange(n), np.zeros((n, 2)), 10.0)
        assert links.shape == (0, 2) and links.dtype == np.int64


@settings(max_examples=40, derandomize=True, deadline=None)
@given(st.integers(0, 40), st.integers(0, 40), st.integers(0, 2**32 - 1),
       st.sampled_from([0.0, 3.0, 6.0, 50.0]))
def test_close_pairs_are_the_entries_of_the_distance_matrix(n: int, k: int, seed: int, radius: float) -> None:
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 5, (n, 2)) * 3.0   # lattice points: exact ties at the radius
    b = rng.integers(0, 5, (k, 2)) * 3.0
    i, j = close_pairs(a, b, radius)
    expected = np.nonzero(np.hypot(*(b[None] - a[:, None]).transpose(2, 0, 1)) <= radius)
    np.testing.assert_array_equal(i, expected[0])
    np.testing.assert_array_equal(j, expected[1])
