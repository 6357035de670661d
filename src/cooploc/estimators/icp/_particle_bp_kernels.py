"""The compiled message sums of `icp-da-pf`'s particle BPA-L (numba, imported on use).

The pair likelihood of eq. (18) between the particles of feature copy q (f) and of its
vehicle (v) is

    G[q, f, v] = max(Σ_{b ∈ q} c_b · (s_b[f] · K_b[f, v]) + c0_q, 1e-300)

with K_b the float32 kernel values and s_b the row scales of `particles.PairKernel`
(one block b per soft pairing ℓ of the pair), c_b = P(α = ℓ) / η(α = ℓ) and c0_q the
"not detected" mass. The BPA-L needs only two products with G per iteration,

    (25)–(26)  Σ_v G[q, f, v] w[q, v]   → `sum_over_vehicles`  (P, J_f)
    (27)       Σ_f w[q, f] G[q, f, v]   → `sum_over_features`  (P, J_v)

so G is not stored: both kernels rebuild each element from the float32 blocks as they
read them (half the bytes of a float64 G, and no (P, J, J) array per step). Each
element is the float64 value the stored G had (the blocks of a pair added in their
order, the same operations, no fastmath); only the order of the sum over f or v is
the kernels' own (a few units in the last place against `np.einsum` on the stored G).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["sum_over_features", "sum_over_vehicles"]


@numba.njit(cache=True, inline="always")
def _pair_row(values: np.ndarray, scale: np.ndarray, coef: np.ndarray, blocks: np.ndarray,
              missed: float, f: int, row: np.ndarray) -> None:
    """row[v] = G[q, f, v] for the pair whose blocks are `blocks` (in their order)."""
    L = row.size
    b = blocks[0]
    c, s, vals = coef[b], scale[b, f], values[b, f]
    for v in range(L):                      # 0 + x is x for the x ≥ 0 here
        row[v] = c * (s * np.float64(vals[v]))
    for t in range(1, blocks.size):          # more than one soft pairing
        b = blocks[t]
        c, s, vals = coef[b], scale[b, f], values[b, f]
        for v in range(L):
            row[v] += c * (s * np.float64(vals[v]))
    if missed >= 1e-300:                     # then G ≥ missed: the floor changes nothing
        for v in range(L):
            row[v] += missed
    else:
        for v in range(L):
            x = row[v] + missed
            row[v] = x if x > 1e-300 else 1e-300


@numba.njit(parallel=True, cache=True)
def sum_over_vehicles(values: np.ndarray, scale: np.ndarray, coef: np.ndarray, starts: np.ndarray,
                      order: np.ndarray, missed: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """out[q, f] = Σ_v G[q, f, v] w[q, v]; pair q's blocks are order[starts[q]:starts[q + 1]].

    values (B, J_f, J_v) float32, scale (B, J_f), coef (B,), missed (P,), w (P, J_v),
    out (P, J_f). The sum over v runs in 8 lanes (lane t takes v ≡ t mod 8, in order;
    then the lanes pairwise, then the tail): a fixed order that vectorises.
    """
    P, Jf = out.shape
    L = w.shape[1]
    top = L - L % 8
    for q in numba.prange(P):
        blocks = order[starts[q]:starts[q + 1]]
        row = np.empty(L)
        acc = np.empty(8)
        wq = w[q]
        for f in range(Jf):
            _pair_row(values, scale, coef, blocks, missed[q], f, row)
            for v in range(L):
                row[v] *= wq[v]
            for t in range(8):
                acc[t] = 0.0
            for v in range(0, top, 8):
                for t in range(8):
                    acc[t] += row[v + t]
            total = ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
            for v in range(top, L):
                total += row[v]
            out[q, f] = total


@numba.njit(parallel=True, cache=True)
def sum_over_features(values: np.ndarray, scale: np.ndarray, coef: np.ndarray, starts: np.ndarray,
                      order: np.ndarray, missed: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """out[q, v] = Σ_f w[q, f] G[q, f, v] (f in order); the arguments as `sum_over_vehicles`,
    w (P, J_f), out (P, J_v)."""
    P, L = out.shape
    Jf = w.shape[1]
    for q in numba.prange(P):
        blocks = order[starts[q]:starts[q + 1]]
        row = np.empty(L)
        o = out[q]
        for v in range(L):
            o[v] = 0.0
        for f in range(Jf):
            _pair_row(values, scale, coef, blocks, missed[q], f, row)
            wf = w[q, f]
            for v in range(L):
                o[v] += wf * row[v]
