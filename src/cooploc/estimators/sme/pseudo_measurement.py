r"""The SME pseudo-measurements and their Gaussian noise moments (pure functions).

Paper: Zhang, Hinz, Gulati, Clarke & Knoll, GeoInformatica 2016, §3.2–3.3
(``papers/001_80a6c560b7fdaa20.txt``); SME after Kamen 1992 and Leven & Lanterman 2004.
Derivation of every moment below: ``docs/sme.md``.

Model
-----
Anonymous GPS rows m_i = p_{π(i)} + w_i (unknown permutation π) become the
sum-of-powers pseudo-measurement of eq. (17), per axis a ∈ {x, y},

.. math:: s_{a,k} = \sum_{i=1}^N m_{a,i}^k,  k = 1..N   (`power_sums`),

or, keeping which x goes with which y, the complex sums s_k = Σ_i (x_i + i y_i)ᵏ
(`complex_power_sums`, our default: eq. 17 loses the pairing in 2-D). Radar rows of
unknown pose become the topology of eq. (18)

.. math:: T = \sum_{i<j} \lVert q_i - q_j \rVert^2 = N \sum_i \lVert q_i - \bar q \rVert^2
          (`topology`),

invariant to the radar's rotation and translation and to the order of its rows.
Newton's identities invert the power sums (`points_from_power_sums`, §3.2.3).

With Gaussian row noise, each map's mean and covariance are exact functions of the true
positions (`power_sum_moments` from the raw moments `gaussian_raw_moments`;
`complex_power_sum_moments`; `topology_moments`). `PseudoMeasurement` stacks the
measured parts as eq. (19) and evaluates y = h(x) + b(x) + e, e ~ N(0, R(x)) — bias
b and covariance R per state, Gaussian shape, relative `jitter` on diag R — as a
log-likelihood per particle (numba, `_kernels`, compiled on first use) and as the
stacked moments at sigma points. With ``density="exact"`` the GPS part is instead the
exact density of the sums of powers: the rows recovered from y (Newton's identities,
`complex_points_from_power_sums`), log Σ_σ Π_i N(m_σ(i); p_i, R) − log |det ∂y/∂m|, a sum
over the N! associations (``docs/sme.md``, "The exact density").

Positions enter scaled, u = (p − c)/ℓ, with c and ℓ fixed per step by the predicted
belief (``docs/sme.md``, "Numerical scaling").

Complexity per state: O(N²) power sums, O(N³) per-axis moments, O(N⁴) complex moments,
O(N) topology; a 2N × 2N Cholesky per likelihood; the exact density O(N! N) at most.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import cache

import numpy as np

from cooploc.gaussian import gaussian_logpdf
from cooploc.types import FloatArray

__all__ = [
    "PseudoMeasurement",
    "complex_points_from_power_sums",
    "complex_power_sum_moments",
    "complex_power_sums",
    "gaussian_raw_moments",
    "permutations",
    "points_from_power_sums",
    "power_sum_moments",
    "power_sums",
    "topology",
    "topology_moments",
]


MAX_EXACT_VEHICLES = 7   # the exact density sums over N! associations: 5040 at N = 7


@cache
def permutations(n: int) -> np.ndarray:
    """(n!, n) int64: every permutation of range(n), the identity first (read-only)."""
    table = np.array(list(itertools.permutations(range(n))), dtype=np.int64).reshape(-1, n)
    table.setflags(write=False)
    return table


@cache
def binomial_table(n: int) -> FloatArray:
    """C(k, j) as floats for k, j = 0..n, (n + 1, n + 1), zero where j > k (read-only)."""
    table = np.array([[float(math.comb(k, j)) for j in range(n + 1)] for k in range(n + 1)])
    table.setflags(write=False)
    return table


@cache
def factorial_table(n: int) -> FloatArray:
    """j! as floats for j = 0..n, (n + 1,) (read-only)."""
    table = np.array([float(math.factorial(j)) for j in range(n + 1)])
    table.setflags(write=False)
    return table


# ----------------------------------------------------------------------------
# sums of powers (eq. 17)
# ----------------------------------------------------------------------------


def power_sums(values: FloatArray, order: int) -> FloatArray:
    """s_k = Σ_i values_iᵏ for k = 1..order (eq. 17): values (..., N) → (..., order)."""
    values = np.asarray(values, dtype=float)
    powers = values[..., None] ** np.arange(1, order + 1)
    return powers.sum(axis=-2)


def points_from_power_sums(sums: FloatArray) -> FloatArray:
    """Recover the N values from their first N power sums (Newton's identities).

    e_0 = 1, k e_k = Σ_{i=1..k} (−1)^{i−1} e_{k−i} s_i, and the values are the roots of
    Σ_k (−1)^k e_k t^{N−k}. Returns the real parts, sorted. This is why the map loses no
    information in one dimension (§3.2.3).
    """
    return np.sort(_roots_of_power_sums(np.asarray(sums, dtype=float)).real)


def complex_points_from_power_sums(sums: FloatArray) -> FloatArray:
    """Recover the N points (N, 2) from [Re s; Im s] (2N,) of their complex power sums.

    The same Newton identities over the complex numbers: the points x + i y are the roots
    of one polynomial, so they come back with their pairing (in no particular order).
    """
    s = np.asarray(sums, dtype=float)
    n = s.size // 2
    c = _roots_of_power_sums(s[:n] + 1j * s[n:])
    return np.stack([c.real, c.imag], axis=-1)


def _roots_of_power_sums(s: np.ndarray) -> np.ndarray:
    """The N roots whose power sums s_k, k = 1..N, are s (real or complex), unsorted."""
    n = s.size
    e = np.zeros(n + 1, dtype=s.dtype)
    e[0] = 1.0
    for k in range(1, n + 1):                  # k e_k = Σ_{i=1..k} (−1)^{i−1} e_{k−i} s_i
        i = np.arange(1, k + 1)
        e[k] = np.sum((-1.0) ** (i - 1) * e[k - i] * s[i - 1]) / k
    return np.roots((-1.0) ** np.arange(n + 1) * e)


def gaussian_raw_moments(mean: FloatArray, var: FloatArray, order: int) -> FloatArray:
    """E[mⁿ] for m ~ N(mean, var), n = 0..order: (...,) → (..., order + 1).

    μ_n = mean μ_{n−1} + (n − 1) var μ_{n−2} (Stein's lemma; docs/sme.md).
    """
    mean, var = np.broadcast_arrays(np.asarray(mean, float), np.asarray(var, float))
    out = np.empty((*mean.shape, order + 1))
    out[..., 0] = 1.0
    if order >= 1:
        out[..., 1] = mean
    for n in range(2, order + 1):
        out[..., n] = mean * out[..., n - 1] + (n - 1) * var * out[..., n - 2]
    return out


def power_sum_moments(values: FloatArray, var: FloatArray, order: int) -> tuple[FloatArray, FloatArray]:
    """Mean (..., order) and covariance (..., order, order) of Σ_i (values_i + v_i)ᵏ, k = 1..order.

    values (..., N) true values, var (..., N) or (N,) noise variances of the rows.
    """
    mu = gaussian_raw_moments(values, var, 2 * order)               # (..., N, 2 order + 1)
    k = np.arange(1, order + 1)
    mean = mu[..., k].sum(-2)                                       # E[s_k] = Σ_i μ_k(i)
    # Cov(s_k, s_l) = Σ_i μ_{k+l}(i) − μ_k(i) μ_l(i)
    cov = (mu[..., k[:, None] + k[None, :]]
           - mu[..., k][..., :, None] * mu[..., k][..., None, :]).sum(-3)
    return mean, cov


# ----------------------------------------------------------------------------
# complex sums of powers (our default form of eq. 17)
# ----------------------------------------------------------------------------


def complex_power_sums(points: FloatArray, order: int) -> FloatArray:
    """[Re s_1..s_order, Im s_1..s_order] of s_k = Σ_i (x_i + i y_i)ᵏ: points (..., N, 2) → (..., 2 order)."""
    points = np.asarray(points, dtype=float)
    c = points[..., 0] + 1j * points[..., 1]
    s = (c[..., None] ** np.arange(1, order + 1)).sum(-2)
    return np.concatenate([s.real, s.imag], axis=-1)


def complex_power_sum_moments(points: FloatArray, var: FloatArray, order: int
                              ) -> tuple[FloatArray, FloatArray]:
    """Mean (..., 2 order) and covariance (..., 2 order, 2 order) of `complex_power_sums` of
    noisy points, isotropic noise of variance var (..., N) or (N,) per axis (docs/sme.md)."""
    points = np.asarray(points, dtype=float)
    c = points[..., 0] + 1j * points[..., 1]                                  # (..., N)
    s = 2.0 * np.broadcast_to(np.asarray(var, dtype=float), c.shape)          # E|ε|² = 2σ²
    k = np.arange(1, order + 1)
    mean = (c[..., None] ** k).sum(-2)                                        # E[s_k] = Σ c_iᵏ
    gamma = np.zeros((*c.shape[:-1], order, order), dtype=complex)
    K, L = np.meshgrid(k, k, indexing="ij")
    binom, fact = binomial_table(order), factorial_table(order)
    for j in range(1, order + 1):   # Γ_kl = Σ_i Σ_j C(k,j) C(l,j) c^{k−j} c̄^{l−j} j! sʲ
        valid = (K >= j) & (L >= j)
        coeff = np.where(valid, binom[K, j] * binom[L, j] * fact[j], 0.0)
        term = (c[..., None, None] ** np.where(valid, K - j, 0)[None]
                * np.conj(c)[..., None, None] ** np.where(valid, L - j, 0)[None])
        gamma = gamma + (coeff * term * (s**j)[..., None, None]).sum(-3)
    re, im = gamma.real, gamma.imag
    cov = 0.5 * np.concatenate([np.concatenate([re, -im], -1), np.concatenate([im, re], -1)], -2)
    return np.concatenate([mean.real, mean.imag], axis=-1), cov


# ----------------------------------------------------------------------------
# topology (eq. 18)
# ----------------------------------------------------------------------------


def topology(points: FloatArray) -> FloatArray:
    """T = Σ_{i<j} ‖p_i − p_j‖² = N Σ_i ‖p_i − p̄‖² (eq. 18): points (..., N, 2) → (...)."""
    points = np.asarray(points, dtype=float)
    centred = points - points.mean(axis=-2, keepdims=True)
    return points.shape[-2] * (centred**2).sum(axis=(-2, -1))


def topology_moments(points: FloatArray, var: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean and variance of T of noisy points: points (..., N, 2), var (..., N) or (N,) per axis."""
    points = np.asarray(points, dtype=float)
    n = points.shape[-2]
    d = np.broadcast_to(np.asarray(var, dtype=float), points.shape[:-1])
    centred = points - points.mean(axis=-2, keepdims=True)
    spread = (centred**2).sum(-1)                                   # ‖p_i − p̄‖²
    mean = n * spread.sum(-1) + 2.0 * (n - 1) * d.sum(-1)
    variance = (4.0 * (((n - 1) ** 2 - 1) * (d**2).sum(-1) + d.sum(-1) ** 2)
                + 4.0 * n**2 * (d * spread).sum(-1))
    return mean, variance


# ----------------------------------------------------------------------------
# the stacked pseudo-measurement of one step (eq. 19)
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class PseudoMeasurement:
    """The stacked pseudo-measurement of one step (eq. 19) and how to predict it.

    centre (2,), scale ℓ: the fixed affine map u = (p − c)/ℓ of this step.
    form : "axes" (eq. 17: sums of powers of x and of y) or "complex" (of x + i y).
    gnss_var (2,) per-axis GPS row variance (scaled), radar_var the radar one (scaled),
    y_gnss (2N,) measured GPS pseudo-measurement or None (skipped), y_radar measured T or None.
    jitter : relative regularisation added to diag R.
    density : the GPS part's density p(y_gnss | x): "gaussian" — N(y; h(x) + b(x), R(x)),
        eq. (19)'s Gaussian pseudo-noise with exact moments; "exact" — the exact density of
        the power sums of Gaussian rows (``docs/sme.md``, "The exact density"), used for
        N ≤ `MAX_EXACT_VEHICLES` (the Gaussian one above that). T is Gaussian in both.
    """

    centre: FloatArray
    scale: float
    form: str
    gnss_var: FloatArray
    radar_var: float
    y_gnss: FloatArray | None
    y_radar: float | None
    jitter: float
    density: str = "gaussian"

    def exact(self, n: int) -> bool:
        """Whether the GPS part of N = n vehicles uses the exact density."""
        return self.density == "exact" and self.y_gnss is not None and n <= MAX_EXACT_VEHICLES

    def rows(self) -> tuple[FloatArray, float]:
        """The scaled GPS rows (N, 2) the measured power sums are of, in no particular order
        (per axis, each column sorted on its own: the pairing is not in eq. 17), and
        log |det ∂y_gnss/∂rows| (``docs/sme.md``, "The exact density")."""
        y = np.asarray(self.y_gnss, dtype=float)
        n = y.size // 2
        if self.form == "complex":
            rows = complex_points_from_power_sums(y)
            c = rows[:, 0] + 1j * rows[:, 1]
            gaps = [np.abs(c[i] - c[j]) for i in range(n) for j in range(i)]
            # |det_R| = |det_C|² = (N! ∏_{i<j} |c_i − c_j|)² for a holomorphic map
            log_jacobian = 2.0 * (math.lgamma(n + 1) + float(np.sum(np.log(gaps))))
        else:
            rows = np.stack([points_from_power_sums(y[:n]), points_from_power_sums(y[n:])], -1)
            gaps = [np.abs(rows[i] - rows[j]) for i in range(n) for j in range(i)]
            # per axis det = N! ∏_{i<j} (v_i − v_j) (Vandermonde)
            log_jacobian = 2.0 * math.lgamma(n + 1) + float(np.sum(np.log(gaps)))
        return rows, log_jacobian if np.isfinite(log_jacobian) else 0.0

    def log_likelihood(self, positions: FloatArray) -> FloatArray:
        """log p(y | positions) for positions (P, N, 2) in the global frame → (P,) (numba)."""
        from cooploc.estimators.sme._kernels import anonymous_rows_log_likelihood, sme_log_likelihood

        u = np.ascontiguousarray((positions - self.centre) / self.scale)
        exact = self.exact(u.shape[1])
        y_gnss = np.zeros(2 * u.shape[1]) if self.y_gnss is None else self.y_gnss
        gnss_var = np.asarray(self.gnss_var, dtype=float)
        out = sme_log_likelihood(u, np.ascontiguousarray(y_gnss, dtype=float),
                                 gnss_var, self.y_gnss is not None and not exact,
                                 self.form == "complex", float(self.y_radar or 0.0),
                                 float(self.radar_var), self.y_radar is not None, float(self.jitter))
        if exact:
            rows, log_jacobian = self.rows()
            out += anonymous_rows_log_likelihood(u, rows, gnss_var, permutations(u.shape[1]),
                                                 self.form == "complex") - log_jacobian
        return out

    def exact_gnss_log_likelihood_reference(self, positions: FloatArray) -> FloatArray:
        """The exact density's log p(y_gnss | positions) (..., N, 2) → (...) in plain NumPy (tests):
        log Σ_σ Π_i N(m_σ(i); u_i, diag var) − log |det ∂y/∂m|, per axis for ``form="axes"``."""
        u = (positions - self.centre) / self.scale
        rows, log_jacobian = self.rows()
        perms = permutations(u.shape[-2])
        var = np.asarray(self.gnss_var, dtype=float)
        # −½ (m_j − u_i)² / var − ½ log(2π var), per axis: (..., N, N, 2)
        cost = -0.5 * ((rows[None, :] - u[..., :, None, :]) ** 2 / var + np.log(2 * np.pi * var))
        n = u.shape[-2]
        if self.form == "complex":
            per_sigma = cost.sum(-1)[..., np.arange(n), perms].sum(-1)            # (..., N!)
            return np.logaddexp.reduce(per_sigma, axis=-1) - log_jacobian
        per_sigma = cost[..., np.arange(n), perms, :].sum(-2)                      # (..., N!, 2)
        return np.logaddexp.reduce(per_sigma, axis=-2).sum(-1) - log_jacobian

    def gnss_moments(self, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """E[y_gnss | u] (..., 2N) and its covariance (..., 2N, 2N) for scaled positions u (..., N, 2)."""
        n = u.shape[-2]
        if self.form == "complex":
            mean, cov = complex_power_sum_moments(u, self.gnss_var.mean(), n)
        else:
            mx, cx = power_sum_moments(u[..., 0], self.gnss_var[0], n)
            my, cy = power_sum_moments(u[..., 1], self.gnss_var[1], n)
            mean = np.concatenate([mx, my], -1)
            cov = np.zeros((*u.shape[:-2], 2 * n, 2 * n))
            cov[..., :n, :n], cov[..., n:, n:] = cx, cy
        diag = np.einsum("...ii->...i", cov)
        return mean, cov + self.jitter * diag[..., None] * np.eye(2 * n)

    def log_likelihood_reference(self, positions: FloatArray) -> FloatArray:
        """The same as `log_likelihood` in plain NumPy, for positions (..., N, 2) (tests)."""
        u = (positions - self.centre) / self.scale
        total = np.zeros(u.shape[:-2])
        if self.exact(u.shape[-2]):
            total = total + self.exact_gnss_log_likelihood_reference(positions)
        elif self.y_gnss is not None:
            mean, cov = self.gnss_moments(u)
            total = total + gaussian_logpdf(self.y_gnss - mean, cov)
        if self.y_radar is not None:
            mean, var = topology_moments(u, self.radar_var)
            total = total - 0.5 * (np.log(2 * np.pi * var) + (self.y_radar - mean) ** 2 / var)
        return total

    def predict(self, positions: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(y, E[y | x], R(x)) stacked for the used parts: positions (S, N, 2) → (D,), (S, D), (S, D, D)."""
        u = (positions - self.centre) / self.scale
        S = u.shape[0]
        ys, means, blocks = [], [], []
        if self.y_gnss is not None:
            mean, cov = self.gnss_moments(u)
            ys.append(self.y_gnss)
            means.append(mean)
            blocks.append(cov)
        if self.y_radar is not None:
            mean, var = topology_moments(u, self.radar_var)
            ys.append(np.array([self.y_radar]))
            means.append(mean[:, None])
            blocks.append(var[:, None, None])
        D = sum(b.shape[-1] for b in blocks)
        R = np.zeros((S, D, D))                     # GPS and radar noises independent: block diagonal
        start = 0
        for b in blocks:
            d = b.shape[-1]
            R[:, start:start + d, start:start + d] = b
            start += d
        return np.concatenate(ys), np.concatenate(means, axis=-1), R
