"""The compiled loop of `rsu_bp.vehicles.log_gauss_groups` (numba; imported on first use).

For pairs p sorted by group g, each with a residual offset a_p, the inverse Cholesky
factor L_p⁻¹ of its covariance and a log coefficient c_p, and particles x_l of the
particle set `sample_of[p]`:

    out[g, l] = log Σ_{p ∈ g} exp(c_p − ½ ‖L_p⁻¹ (a_p + H x_l)‖²),

accumulated as a running log-sum-exp, so no (pairs × particles) array is stored.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["group_log_gauss"]


@numba.njit(cache=True)  # serial: one thread per worker process; no fastmath: sums start at −inf
def group_log_gauss(offset: np.ndarray, inv_chol: np.ndarray, log_coef: np.ndarray,
                    sample_of: np.ndarray, starts: np.ndarray, samples: np.ndarray, H: np.ndarray,
                    out: np.ndarray) -> None:
    """Fill out (G, N) as in the module docstring; `starts` (G + 1,) delimits the groups.

    The loops over particles are innermost and contiguous, so they vectorise.
    """
    G = starts.size - 1
    N, dx = samples.shape[1], samples.shape[2]
    d = offset.shape[1]
    r = np.empty((d, N))
    w = np.empty(N)
    q = np.empty(N)
    x = np.empty((dx, N))
    for g in range(G):
        first = True
        for p in range(starts[g], starts[g + 1]):
            a = sample_of[p]
            for e in range(dx):
                for l in range(N):
                    x[e, l] = samples[a, l, e]
            for j in range(d):
                for l in range(N):
                    r[j, l] = offset[p, j]
                for e in range(dx):
                    h = H[j, e]
                    if h != 0.0:
                        for l in range(N):
                            r[j, l] += h * x[e, l]
            for l in range(N):
                q[l] = 0.0
            for i in range(d):
                for l in range(N):
                    w[l] = 0.0
                for j in range(i + 1):
                    c = inv_chol[p, i, j]
                    for l in range(N):
                        w[l] += c * r[j, l]
                for l in range(N):
                    q[l] += w[l] * w[l]
            c0 = log_coef[p]
            if first:
                for l in range(N):
                    out[g, l] = c0 - 0.5 * q[l]
                first = False
            else:
                for l in range(N):
                    v = c0 - 0.5 * q[l]
                    cur = out[g, l]
                    if v == -math.inf:  # adds nothing (and −inf − −inf below would be NaN)
                        continue
                    if v > cur:
                        out[g, l] = v + math.log1p(math.exp(cur - v))
                    else:
                        out[g, l] = cur + math.log1p(math.exp(v - cur))
