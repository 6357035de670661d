"""The SME pseudo-likelihood per particle, compiled with numba: the hot loop of `sme-pf`.

Imported on first use by `PseudoMeasurement.log_likelihood` (never at package import,
so that `import cooploc` does not pay for numba). `sme_log_likelihood` evaluates, for
every particle p, log N(y; E[y | u_p], Cov(y | u_p)) of the stacked pseudo-measurement
of Zhang et al. 2016 eq. (19): the GPS sums of powers (eq. 17, per axis or complex)
with their exact Gaussian noise moments, plus the topology T (eq. 18) with its mean and
variance — the formulas of ``docs/sme.md``, the same as the NumPy functions of
`cooploc.estimators.sme.pseudo_measurement` (which tests compare it with:
`PseudoMeasurement.log_likelihood_reference`).

Complexity per particle: O(N³) per-axis moments or O(N⁴) complex moments, a 2N × 2N
Cholesky, O(N) topology; one pass over the particles, scratch arrays allocated once.
"""

from __future__ import annotations

import numba
import numpy as np

from cooploc.estimators.sme.pseudo_measurement import binomial_table, factorial_table
from cooploc.types import FloatArray

_LOG_2PI = float(np.log(2.0 * np.pi))
_MAX_ORDER = 16
# numba freezes global arrays into the compiled code: writable copies of the tables
_COMB = np.array(binomial_table(_MAX_ORDER))
_FACT = np.array(factorial_table(_MAX_ORDER))


@numba.njit(cache=True)
def _cholesky_logpdf(r: FloatArray, C: FloatArray) -> float:
    """log N(r; 0, C) by an in-place Cholesky of the small matrix C; −inf if not SPD."""
    n = r.size
    logdet = 0.0
    for j in range(n):
        s = C[j, j]
        for k in range(j):
            s -= C[j, k] * C[j, k]
        if not s > 0.0:
            return -np.inf
        d = np.sqrt(s)
        C[j, j] = d
        logdet += 2.0 * np.log(d)
        for i in range(j + 1, n):
            t = C[i, j]
            for k in range(j):
                t -= C[i, k] * C[j, k]
            C[i, j] = t / d
    quad = 0.0
    a = np.empty(n)
    for i in range(n):                      # L a = r, quad = ‖a‖² = rᵀ C⁻¹ r
        t = r[i]
        for k in range(i):
            t -= C[i, k] * a[k]
        a[i] = t / C[i, i]
        quad += a[i] * a[i]
    return -0.5 * (n * _LOG_2PI + logdet + quad)


@numba.njit(cache=True)
def _complex_residual_and_covariance(u: FloatArray, y: FloatArray, var: float, C: FloatArray,
                                     r: FloatArray, p: int) -> None:
    """Fill r = y − E[s] and C = Cov s of the complex power sums of particle p (docs/sme.md)."""
    n = u.shape[1]
    s = 2.0 * var
    c = np.empty(n, dtype=np.complex128)
    for i in range(n):
        c[i] = u[p, i, 0] + 1j * u[p, i, 1]
    # powers cp[i, m] = c_i^m and their conjugates, m = 0..n
    cp = np.empty((n, n + 1), dtype=np.complex128)
    for i in range(n):
        cp[i, 0] = 1.0
        for m in range(1, n + 1):
            cp[i, m] = cp[i, m - 1] * c[i]
    for k in range(1, n + 1):
        acc = 0j
        for i in range(n):
            acc += cp[i, k]
        r[k - 1] = y[k - 1] - acc.real
        r[n + k - 1] = y[n + k - 1] - acc.imag
    for k in range(1, n + 1):
        for l in range(1, n + 1):
            g = 0j
            for j in range(1, min(k, l) + 1):
                coeff = _COMB[k, j] * _COMB[l, j] * _FACT[j] * s**j
                for i in range(n):
                    g += coeff * cp[i, k - j] * np.conj(cp[i, l - j])
            # Cov [Re s; Im s] = ½ [[Re Γ, −Im Γ], [Im Γ, Re Γ]]
            C[k - 1, l - 1] = 0.5 * g.real
            C[n + k - 1, n + l - 1] = 0.5 * g.real
            C[k - 1, n + l - 1] = -0.5 * g.imag
            C[n + k - 1, l - 1] = 0.5 * g.imag


@numba.njit(cache=True)
def sme_log_likelihood(u: FloatArray, y_gnss: FloatArray, gnss_var: FloatArray, use_gnss: bool,
                       complex_form: bool, y_radar: float, radar_var: float, use_radar: bool,
                       jitter: float) -> FloatArray:
    """log p(y | u_p) for scaled positions u (P, N, 2): the numba twin of
    `PseudoMeasurement.log_likelihood_reference` (same moments, docs/sme.md)."""
    P, n = u.shape[0], u.shape[1]
    order = 2 * n
    out = np.zeros(P)
    mu = np.empty((n, order + 1))
    C = np.empty((n, n))
    r = np.empty(n)
    C2 = np.empty((2 * n, 2 * n))
    r2 = np.empty(2 * n)
    for p in range(P):
        total = 0.0
        if use_gnss and complex_form:
            _complex_residual_and_covariance(u, y_gnss, 0.5 * (gnss_var[0] + gnss_var[1]), C2, r2, p)
            for k in range(2 * n):
                C2[k, k] *= 1.0 + jitter
            total += _cholesky_logpdf(r2, C2)
        elif use_gnss:
            for axis in range(2):
                var = gnss_var[axis]
                for i in range(n):                     # μ_m = u μ_{m−1} + (m − 1) σ² μ_{m−2}
                    x = u[p, i, axis]
                    mu[i, 0] = 1.0
                    mu[i, 1] = x
                    for m in range(2, order + 1):
                        mu[i, m] = x * mu[i, m - 1] + (m - 1) * var * mu[i, m - 2]
                for k in range(n):
                    acc = 0.0
                    for i in range(n):
                        acc += mu[i, k + 1]
                    r[k] = y_gnss[axis * n + k] - acc
                for k in range(n):
                    for l in range(k + 1):
                        acc = 0.0
                        for i in range(n):
                            acc += mu[i, k + l + 2] - mu[i, k + 1] * mu[i, l + 1]
                        C[k, l] = acc
                        C[l, k] = acc
                for k in range(n):
                    C[k, k] *= 1.0 + jitter
                total += _cholesky_logpdf(r, C)
        if use_radar:
            cx = 0.0
            cy = 0.0
            for i in range(n):
                cx += u[p, i, 0]
                cy += u[p, i, 1]
            cx /= n
            cy /= n
            spread = 0.0
            for i in range(n):
                spread += (u[p, i, 0] - cx) ** 2 + (u[p, i, 1] - cy) ** 2
            d = radar_var
            m_t = n * spread + 2.0 * (n - 1) * n * d
            v_t = 4.0 * (((n - 1) ** 2 - 1) * n * d * d + (n * d) ** 2) + 4.0 * n * n * d * spread
            total += -0.5 * (_LOG_2PI + np.log(v_t) + (y_radar - m_t) ** 2 / v_t)
        out[p] = total
    return out


_NEGLIGIBLE = 40.0   # an association whose cost exceeds the best by this adds < e^−40 relative


@numba.njit(cache=True)
def _greedy_cost(cost: FloatArray, a0: int, a1: int, taken: np.ndarray) -> float:
    """Cost of the greedy association (each slot in turn its cheapest free row) over the
    axes a0..a1 − 1 of cost (2, N, N): an upper bound on the best association's cost."""
    n = cost.shape[1]
    taken[:] = False
    total = 0.0
    for i in range(n):
        best, arg = np.inf, 0
        for j in range(n):
            c = 0.0
            for a in range(a0, a1):
                c += cost[a, i, j]
            if not taken[j] and c < best:
                best, arg = c, j
        taken[arg] = True
        total += best
    return total


@numba.njit(cache=True)
def anonymous_rows_log_likelihood(u: FloatArray, rows: FloatArray, var: FloatArray, perms: np.ndarray,
                                  joint: bool) -> FloatArray:
    """log Σ_σ Π_i N(rows_σ(i); u_p,i, diag var) for scaled positions u (P, N, 2): the exact
    density of anonymous rows (N, 2) up to the Jacobian of the power sums (docs/sme.md).

    joint: one association σ for both axes (complex sums); else one per axis (eq. 17 per
    axis: the x rows and the y rows are two multisets). perms (N!, N). Associations whose
    cost exceeds the greedy one's by `_NEGLIGIBLE` are dropped as soon as their partial sum
    does (their share is below e^−40 of the best: beneath float64 rounding of the sum), so
    apart vehicles cost O(N!) comparisons and a few exponentials. O(P N! N) at most.
    """
    P, n = u.shape[0], u.shape[1]
    out = np.empty(P)
    norm = -0.5 * n * (np.log(2.0 * np.pi * var[0]) + np.log(2.0 * np.pi * var[1]))
    cost = np.empty((2, n, n))
    taken = np.zeros(n, dtype=np.bool_)
    kept = np.empty(perms.shape[0])
    for p in range(P):
        for a in range(2):
            for i in range(n):
                for j in range(n):
                    d = rows[j, a] - u[p, i, a]
                    cost[a, i, j] = 0.5 * d * d / var[a]
        total = norm
        for axis in range(1 if joint else 2):
            a0, a1 = (0, 2) if joint else (axis, axis + 1)
            bound = _greedy_cost(cost, a0, a1, taken) + _NEGLIGIBLE
            count = 0
            best = np.inf
            for m in range(perms.shape[0]):
                c = 0.0
                for i in range(n):
                    for a in range(a0, a1):
                        c += cost[a, i, perms[m, i]]
                    if c > bound:
                        break
                if c <= bound:
                    kept[count] = c
                    count += 1
                    best = min(best, c)
            acc = 0.0                                # −log Σ exp(−c) = best − log Σ exp(best − c)
            for m in range(count):
                acc += np.exp(best - kept[m])
            total += -best + np.log(acc)
        out[p] = total
    return out


@numba.njit(cache=True)
def best_permutations(cost: FloatArray, perms: np.ndarray) -> np.ndarray:
    """For each particle p, the row of `perms` (M, N) minimising Σ_i cost[p, i, perms[m, i]].

    cost (P, N, N): cost[p, i, j] of putting the particle's block j in slot i (the
    relabelling of `sme-pf`); returns (P,) indices into perms. O(P M N).
    """
    P, n = cost.shape[0], cost.shape[1]
    out = np.zeros(P, dtype=np.int64)
    for p in range(P):
        best = np.inf
        for m in range(perms.shape[0]):
            total = 0.0
            for i in range(n):
                total += cost[p, i, perms[m, i]]
                if total >= best:
                    break
            if total < best:
                best = total
                out[p] = m
    return out
