"""The compiled loop of `rsu_bp.vehicles.log_gauss_groups` (numba; imported on first use).

For pairs p sorted by group g, each with a residual offset a_p, the inverse Cholesky
factor L_p⁻¹ of its covariance and a log coefficient c_p, and particles x_l of the
particle set `sample_of[p]`:

    out[g, l] = log Σ_{p ∈ g} exp(c_p − ½ ‖L_p⁻¹ (a_p + H x_l)‖²),

accumulated as a running log-sum-exp, so no (pairs × particles) array is stored. The
`prange` loop runs over groups; each group writes only its own row.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["group_log_gauss"]


@numba.njit(parallel=True, cache=True)  # no fastmath: the sums start at −inf
def group_log_gauss(offset: np.ndarray, inv_chol: np.ndarray, log_coef: np.ndarray,
                    sample_of: np.ndarray, starts: np.ndarray, samples: np.ndarray, H: np.ndarray,
                    out: np.ndarray) -> None:
    """Fill out (G, N) as in the module docstring; `starts` (G + 1,) delimits the groups."""
    G = starts.size - 1
    N, dx = samples.shape[1], samples.shape[2]
    d = offset.shape[1]
    for g in numba.prange(G):
        r = np.empty(d)
        for l in range(N):
            out[g, l] = -np.inf
        for p in range(starts[g], starts[g + 1]):
            a = sample_of[p]
            c = log_coef[p]
            single = starts[g + 1] - starts[g] == 1
            for l in range(N):
                for j in range(d):
                    s = offset[p, j]
                    for e in range(dx):
                        s += H[j, e] * samples[a, l, e]
                    r[j] = s
                q = 0.0
                for i in range(d):
                    w = 0.0
                    for j in range(i + 1):
                        w += inv_chol[p, i, j] * r[j]
                    q += w * w
                v = c - 0.5 * q
                cur = out[g, l]
                if single or cur == -np.inf:
                    out[g, l] = v
                elif v > cur:
                    out[g, l] = v + math.log1p(math.exp(cur - v))
                else:
                    out[g, l] = cur + math.log1p(math.exp(v - cur))
