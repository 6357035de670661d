"""BPA-DA (14)–(17) of every agent over its own (track, row) pairs only, stored flat.

`association.bp_association` runs a batch of sensors padded to (B, K, M). For
`icp-da-lc` the batch is the agents, K every track of the network and M the most rows
of any vehicle, while each agent holds a few dozen tracks and has a few rows: on the
Berlin city cut (1246 vehicles) the padding is 17 times the real (agent, track, row)
entries. Here the entries are stored flat, in the order of `np.nonzero` over the padded
array (agent, track, row), with the layout of `ragged_layout`: pairs (agent, track) of
agent a are `pair_start[a]:pair_start[a + 1]`, pair p's entries
`entry_start[p]:entry_start[p + 1]`, one for each of its agent's `n_rows[a]` rows.

The model, the iterations and the floors are those of `association.bp_association`
(Williams & Lau, in its ratio form), operation for operation, with sums over tracks in
track order and over rows in row order: the marginals are bitwise those of the padded
form (tests/test_icp.py). Cost O(P Σ_a K_a W_a) instead of O(P n F W).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.association import FLOOR
from cooploc.errors import InvalidInputError
from cooploc.types import FloatArray, IntArray

__all__ = ["RaggedMarginals", "ragged_bp_association", "ragged_layout"]


@dataclass(frozen=True)
class RaggedMarginals:
    """Marginals of the flat entries (`ragged_bp_association`).

    Attributes
    ----------
    feature : (E,) P(a_k = m) of each entry (pair k, row m).
    measurement : (E,) P(b_m = k) of each entry.
    missed : (P,) P(a_k = 0) of each pair.
    clutter : (n, W) P(b_m = 0) of each row (0 in the padding).
    """

    feature: FloatArray
    measurement: FloatArray
    missed: FloatArray
    clutter: FloatArray


def ragged_layout(pair_agent: IntArray, n_rows: IntArray) -> tuple[IntArray, IntArray]:
    """`pair_start` (n + 1,) and `entry_start` (P + 1,) for pairs of agents `pair_agent`
    (P,), sorted, and `n_rows` (n,) rows per agent."""
    n = n_rows.size
    pair_start = np.searchsorted(pair_agent, np.arange(n + 1))
    entry_start = np.concatenate([[0], np.cumsum(n_rows[pair_agent])]).astype(np.int64)
    return pair_start.astype(np.int64), entry_start


def ragged_bp_association(log_psi: FloatArray, log_missed: FloatArray, log_clutter: FloatArray,
                          pair_start: IntArray, entry_start: IntArray, n_rows: IntArray,
                          column: IntArray, n_columns: int, n_iterations: int) -> RaggedMarginals:
    """`association.bp_association` of every agent, on the flat entries (module docstring).

    Parameters
    ----------
    log_psi : (E,) log ψ_k(m) of each entry (−inf allowed).
    log_missed : (P,) log ψ_k(0) of each pair.
    log_clutter : (n, W) log κ_m of each row; columns past `n_rows[a]` are ignored.
    pair_start, entry_start, n_rows : the layout (`ragged_layout`).
    column, n_columns : the track (column) of each pair (P,), of `n_columns` in the padded
        form; sums follow its order (`_ragged_kernels`).
    n_iterations : P, ν-updates (at least 1).
    """
    from cooploc.estimators.icp._ragged_kernels import bp_iterations, ratio_form  # numba, on use

    log_psi = np.array(log_psi, dtype=float)
    log_missed = np.array(log_missed, dtype=float)
    log_clutter = np.array(log_clutter, dtype=float)
    ratio_form(log_psi, log_missed, log_clutter, pair_start, entry_start, n_rows, float(np.log(FLOOR)))
    psi, psi0, kappa = np.exp(log_psi), np.exp(log_missed), np.exp(log_clutter)
    feature, measurement = np.zeros(psi.size), np.zeros(psi.size)
    missed, clutter = np.zeros(psi0.size), np.zeros(kappa.shape)
    if int(n_iterations) != n_iterations or n_iterations < 1:
        raise InvalidInputError(f"n_iterations must be a positive integer, got {n_iterations!r}")
    bp_iterations(psi, psi0, kappa, pair_start, entry_start, n_rows, np.asarray(column, dtype=np.int64),
                  int(n_columns), int(n_iterations), feature, missed, measurement, clutter)
    return RaggedMarginals(feature, measurement, missed, clutter)
