"""The compiled loops behind `ragged_association` (numba, imported on use).

Each agent's BPA-DA is a small dense problem: K_a tracks it holds × W_a rows it has.
The entries of all agents are stored flat, agent after agent, each agent's block track
(pair) major: entry `entry_start[p] + w` is (pair p, the agent's row w), pairs
`pair_start[a]:pair_start[a + 1]` are agent a's, `n_rows[a]` its rows (the first
`n_rows[a]` columns of the (n, W) row arrays), `column[p]` the pair's track (of F).
Every operation is the float64 operation that `association.bp_association` does on
the padded (n, F, W) arrays, and every sum adds the same numbers in the same order:
NumPy sums the contiguous last axis pairwise (`_pairwise`, its `pairwise_sum`) and
another axis one slice after the other, so a sum over rows is pairwise over the W
slots, the padding adding exact zeros at the end, and a sum over tracks runs in track
order, except where W = 1, when the track axis is the contiguous one and is summed
pairwise over all F columns. The results are bitwise those of the padded form
(tests/test_icp.py checks this on random cases).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["bp_iterations", "ratio_form"]


@numba.njit(cache=True)
def _block(a: np.ndarray, lo: int, n: int) -> float:
    """NumPy's pairwise_sum of a[lo:lo + n] for n ≤ 128: a plain loop below 8, else 8 running sums."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - n % 8:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@numba.njit(cache=True)
def _pairwise(a: np.ndarray, lo: int, n: int) -> float:
    """Σ a[lo:lo + n] in the order of NumPy's pairwise summation: blocks of at most 128
    (`_block`), longer runs split in halves (a multiple of 8 first) and the halves added.
    The halving is walked with an explicit stack (a recursive njit function loaded from
    numba's cache crashed)."""
    if n <= 128:
        return _block(a, lo, n)
    los = np.empty(64, dtype=np.int64)         # the runs being split, outermost first
    ns = np.empty(64, dtype=np.int64)
    left = np.empty(64)                        # the sum of a run's first half, once known
    right_half = np.zeros(64, dtype=np.bool_)  # whether the run's second half is under way
    sp = 0
    los[0], ns[0] = lo, n
    while True:
        if ns[sp] > 128:                       # split: its first half goes on the stack
            half = ns[sp] // 2
            half -= half % 8
            los[sp + 1], ns[sp + 1], right_half[sp + 1] = los[sp], half, False
            sp += 1
            continue
        value = _block(a, los[sp], ns[sp])
        sp -= 1
        while sp >= 0 and right_half[sp + 1]:  # a second half done: add it to its first
            value = left[sp] + value
            sp -= 1
        if sp < 0:
            return value
        left[sp] = value                       # a first half done: the second one next
        half = ns[sp] // 2
        half -= half % 8
        los[sp + 1], ns[sp + 1], right_half[sp + 1] = los[sp] + half, ns[sp] - half, True
        sp += 1


@numba.njit(cache=True)
def ratio_form(log_psi: np.ndarray, log_missed: np.ndarray, log_clutter: np.ndarray, pair_start: np.ndarray,
               entry_start: np.ndarray, n_rows: np.ndarray, log_floor: float) -> None:
    """`association._ratio_form` before its exponentials, in place: rows (pairs) and
    columns (rows of an agent) rescaled by their maxima, miss and clutter floored."""
    n = n_rows.size
    for a in range(n):
        M = n_rows[a]
        for p in range(pair_start[a], pair_start[a + 1]):       # rows of the (K, M) block
            e0 = entry_start[p]
            row = log_missed[p]
            for w in range(M):
                row = max(row, log_psi[e0 + w])
            if not np.isfinite(row):
                row = 0.0
            for w in range(M):
                log_psi[e0 + w] -= row
            log_missed[p] -= row
        for w in range(M):                                      # columns
            col = log_clutter[a, w]
            for p in range(pair_start[a], pair_start[a + 1]):
                col = max(col, log_psi[entry_start[p] + w])
            if not np.isfinite(col):
                col = 0.0
            for p in range(pair_start[a], pair_start[a + 1]):
                log_psi[entry_start[p] + w] -= col
            log_clutter[a, w] -= col
        for p in range(pair_start[a], pair_start[a + 1]):       # floors
            best = -np.inf
            for w in range(M):
                best = max(best, log_psi[entry_start[p] + w])
            log_missed[p] = max(log_missed[p], best + log_floor if np.isfinite(best) else 0.0)
        for w in range(M):
            best = -np.inf
            for p in range(pair_start[a], pair_start[a + 1]):
                best = max(best, log_psi[entry_start[p] + w])
            log_clutter[a, w] = max(log_clutter[a, w], best + log_floor if np.isfinite(best) else 0.0)


@numba.njit(cache=True)
def _row_sum(psi: np.ndarray, nu: np.ndarray, e0: int, M: int, buf: np.ndarray) -> float:
    """Σ_w ψ ν over a pair's M entries from e0, as NumPy sums the padded last axis (len(buf))."""
    W = buf.size
    if W < 8:                                  # pairwise below 8 is the plain loop; zeros add nothing
        total = 0.0
        for w in range(M):
            total += psi[e0 + w] * nu[e0 + w]
        return total
    for w in range(W):
        buf[w] = psi[e0 + w] * nu[e0 + w] if w < M else 0.0
    return _pairwise(buf, 0, W)


@numba.njit(cache=True)
def _track_sum(mu: np.ndarray, p0: int, p1: int, w: int, entry_start: np.ndarray, column: np.ndarray,
               single: bool, buf: np.ndarray) -> float:
    """Σ_k μ over an agent's pairs for its row w, as NumPy sums the padded track axis (len(buf))."""
    if not single:                              # a strided axis: slice after slice, in track order
        total = 0.0
        for p in range(p0, p1):
            total += mu[entry_start[p] + w]
        return total
    for p in range(p0, p1):                     # W = 1: the contiguous axis, pairwise over F
        buf[column[p]] = mu[entry_start[p] + w]
    total = _pairwise(buf, 0, buf.size)
    for p in range(p0, p1):
        buf[column[p]] = 0.0
    return total


@numba.njit(cache=True)
def _messages(psi: np.ndarray, psi0: np.ndarray, kappa: np.ndarray, nu: np.ndarray, mu: np.ndarray,
              a: int, p0: int, p1: int, M: int, entry_start: np.ndarray, column: np.ndarray,
              row_buf: np.ndarray, track_buf: np.ndarray, update_nu: bool) -> None:
    """μ_{k→m} (eqs. 17, 19) of agent a's block from ν, then (if `update_nu`) ν_{m→k} (eq. 18)."""
    single = row_buf.size == 1
    for p in range(p0, p1):
        e0 = entry_start[p]
        total = _row_sum(psi, nu, e0, M, row_buf)
        for w in range(M):
            pn = psi[e0 + w] * nu[e0 + w]
            mu[e0 + w] = psi[e0 + w] / max(psi0[p] + total - pn, psi0[p])
    if not update_nu:
        return
    for w in range(M):
        total = _track_sum(mu, p0, p1, w, entry_start, column, single, track_buf)
        for p in range(p0, p1):
            e = entry_start[p] + w
            nu[e] = 1.0 / max(kappa[a, w] + total - mu[e], kappa[a, w])


@numba.njit(cache=True)
def bp_iterations(psi: np.ndarray, psi0: np.ndarray, kappa: np.ndarray, pair_start: np.ndarray,
                  entry_start: np.ndarray, n_rows: np.ndarray, column: np.ndarray, n_columns: int,
                  n_iterations: int, feature: np.ndarray, missed: np.ndarray, measurement: np.ndarray,
                  clutter: np.ndarray) -> None:
    """P iterations of `association.bp_association` (ν ≡ 1 at the start) and the marginals:
    feature[e] = P(a_k = m), measurement[e] = P(b_m = k), missed[p], clutter[a, w]; the
    padded problem is (n, n_columns, kappa.shape[1])."""
    n = n_rows.size
    nu = np.ones(psi.size)
    mu = np.empty(psi.size)
    row_buf = np.zeros(kappa.shape[1])
    track_buf = np.zeros(n_columns)
    single = kappa.shape[1] == 1
    for a in range(n):
        p0, p1, M = pair_start[a], pair_start[a + 1], n_rows[a]
        for _ in range(n_iterations):
            _messages(psi, psi0, kappa, nu, mu, a, p0, p1, M, entry_start, column, row_buf, track_buf, True)
        # μ consistent with the final ν, for the measurement marginals
        _messages(psi, psi0, kappa, nu, mu, a, p0, p1, M, entry_start, column, row_buf, track_buf, False)
        for p in range(p0, p1):
            e0 = entry_start[p]
            norm = psi0[p] + _row_sum(psi, nu, e0, M, row_buf)
            for w in range(M):
                feature[e0 + w] = psi[e0 + w] * nu[e0 + w] / norm
            missed[p] = psi0[p] / norm
        for w in range(M):
            norm = kappa[a, w] + _track_sum(mu, p0, p1, w, entry_start, column, single, track_buf)
            for p in range(p0, p1):
                measurement[entry_start[p] + w] = mu[entry_start[p] + w] / norm
            clutter[a, w] = kappa[a, w] / norm
