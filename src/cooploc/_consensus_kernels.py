"""Compiled round of average consensus (`cooploc.consensus.GroupConsensus.average_members`).

One pass over the active (sender, receiver) pairs, grouped by receiver, instead of the
five array passes of gather, subtract, scale, sparse sum and add: the same floating-point
operations in the same order (each receiver's terms summed from 0 in pair order, as
SciPy's CSR product does), so the results are bitwise those of the array form.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def average_round(mine: np.ndarray, source: np.ndarray, receiver_start: np.ndarray,
                  receivers: np.ndarray, weight: np.ndarray, out: np.ndarray) -> bool:
    """out = mine + Σ_p w_p (mine[source_p] − mine[receiver]) per receiver; False (out
    untouched) when every pair already agrees (a fixed point).

    Pairs are sorted by receiver: those of receivers[g] are receiver_start[g] … [g + 1].
    """
    r = mine.shape[1]
    changed = False
    for g in range(receivers.size):
        i = receivers[g]
        for p in range(receiver_start[g], receiver_start[g + 1]):
            s = source[p]
            for c in range(r):
                if mine[s, c] != mine[i, c]:
                    changed = True
                    break
            if changed:
                break
        if changed:
            break
    if not changed:
        return False
    out[:] = mine
    acc = np.empty(r)
    for g in range(receivers.size):
        i = receivers[g]
        for c in range(r):
            acc[c] = 0.0
        for p in range(receiver_start[g], receiver_start[g + 1]):
            s = source[p]
            w = weight[p]
            for c in range(r):
                acc[c] += 1.0 * (w * (mine[s, c] - mine[i, c]))
        for c in range(r):
            out[i, c] = mine[i, c] + acc[c]
    return True
