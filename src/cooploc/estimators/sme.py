r"""`sme-pf`, `sme-ukf`: the symmetric measurement equation (SME) filter of Zhang et al. 2016.

Paper: Zhang, Hinz, Gulati, Clarke & Knoll, GeoInformatica 2016, §3.2–3.3
(``papers/001_80a6c560b7fdaa20.txt``); SME after Kamen 1992 and Leven & Lanterman.

Model
-----
The joint state stacks the N vehicles, x = [x¹; …; xᴺ] (eq. 1), each in cooploc's
layout [p_x, p_y, v_x, v_y], and follows the vehicles' motion model block by block
(eqs. 5–6, 16). The anonymous GPS rows m_i = p_{π(i)} + w_i (unknown permutation π)
become the sum-of-powers pseudo-measurement of eq. (17), per axis a ∈ {x, y}

.. math:: s_{a,k} = \sum_{i=1}^N m_{a,i}^k,  k = 1..N,

and the radar rows q_i = R(θ)ᵀ(p_{π'(i)} − t) + w'_i, whose pose (t, θ) is unknown,
become the topology pseudo-measurement of eq. (18)

.. math:: T = \sum_{i<j} \lVert q_i - q_j \rVert^2 = N \sum_i \lVert q_i - \bar q \rVert^2,

which is invariant to the pose (a rotation and translation of all q) and to π'. Both
are symmetric in the vehicles, so no association is needed; eq. (19) stacks them into
a (2N + 1)-vector.

Numerical scaling (our choice): before taking powers every position is mapped to
u = (p − c)/ℓ with a centre c and length ℓ fixed by the *predicted* belief (mean of the
predicted vehicle positions, RMS spread of them, at least `min_scale` m) — never by the
measurements, so the map stays a fixed symmetric function at each step. Without it,
p⁵ of 150 m is ~10¹¹ and the pseudo-measurement covariance spans ~30 orders of
magnitude. T is divided by ℓ².

Pseudo-measurement noise (the paper defers to its refs [12, 22]; derived here)
-------------------------------------------------------------------------------
*Sums of powers.* For one axis let m_i = u_i + v_i, v_i ~ N(0, σ_i²) independent
(σ_i² the row variance along that axis, scaled by 1/ℓ²). The raw moments
μ_n(i) = E[m_iⁿ] of a Gaussian obey μ_0 = 1, μ_1 = u_i and

.. math:: μ_n = u_i μ_{n-1} + (n-1) σ_i^2 μ_{n-2},

(integration by parts, Stein's lemma). Because the rows are independent and the sums
are symmetric, the permutation does not matter and

.. math:: E[s_k] = \sum_i μ_k(i),\qquad
          \operatorname{Cov}(s_k, s_l) = \sum_i \big(μ_{k+l}(i) - μ_k(i) μ_l(i)\big).

So the pseudo-measurement has a state-dependent *bias* b_k = Σ_i (μ_k(i) − u_iᵏ)
(e.g. b_2 = Σ σ_i², b_3 = 3 Σ u_i σ_i²) and a state-dependent, full N × N covariance
R_a(u). Moments up to order 2N are needed. The x and y sums are independent when each
row's covariance is diagonal (as in the paper); off-diagonal terms are ignored.

*Complex sums of powers* (``form="complex"``, our default). Eq. (17) recovers the
multiset of x values and the multiset of y values, but not which x goes with which y
— information *is* lost in 2-D, contrary to §3.2.3, and eq. (18) is a function of the
two multisets as well, so it cannot restore the pairing. In §4.1 three vehicles start
at one point, and a per-axis SME can then follow the x-motion of one vehicle with the
y-motion of another forever (tests/test_sme.py shows two such sets). Taking
c_i = x_i + i y_i and s_k = Σ_i c_iᵏ (k = 1..N; real and imaginary parts, 2N reals as
eq. 17) keeps the pairing: the c_i are the roots of one polynomial. With isotropic
row noise ε_i = v_x + i v_y, E|ε|² = 2σ² =: s_i, the noise is circular
(E[εᵃ ε̄ᵇ] = δ_ab a! s_iᵃ, E[εᵃ] = 0 for a ≥ 1), hence

.. math:: E[s_k] = \sum_i c_i^k \quad\text{(no bias)},\qquad
          Γ_{kl} = E[(s_k - E s_k)\overline{(s_l - E s_l)}]
          = \sum_i \sum_{j=1}^{\min(k,l)} \binom{k}{j}\binom{l}{j} j!\, s_i^j\,
            c_i^{k-j} \bar c_i^{\,l-j},

and the pseudo-covariance E[(s_k − E s_k)(s_l − E s_l)] = 0, so the covariance of
[Re s; Im s] is ½ [[Re Γ, −Im Γ], [Im Γ, Re Γ]]. (Row variances that differ between
axes are averaged.)

*Topology.* Stack the radar rows of one axis as q_a = P_a + w_a (P_a the rotated and
translated true positions, w_a ~ N(0, D), D = diag(d_i), isotropic rows). With the
Laplacian of the complete graph L = N I − 11ᵀ, T = Σ_a q_aᵀ L q_a, a Gaussian quadratic
form:

.. math:: E[T] = \sum_{i<j} \lVert p_i - p_j \rVert^2 + 2 (N-1) \sum_i d_i,

.. math:: \operatorname{Var}[T] = \sum_a \big(2 \operatorname{tr}(L D L D)
          + 4 P_aᵀ L D L P_a\big)
          = 4\big[((N-1)^2 - 1) \sum_i d_i^2 + (\sum_i d_i)^2\big]
          + 4 N^2 \sum_i d_i \lVert p_i - \bar p \rVert^2 .

L annihilates translations and the sum over both axes is rotation invariant, so the
moments depend on the true positions only through p_i − p̄, as T itself does. With
equal d: Var[T] = 4 d² N² (N − 1) + 4 N² d Σ‖p_i − p̄‖². (Tested against Monte Carlo
in tests/test_sme.py.) GPS and radar noises are independent: the (2N + 1)-covariance
is block diagonal [R_x, R_y, Var T].

The pseudo-measurement is then treated as y = h(x) + b(x) + e, e ~ N(0, R(x)) — exact
first two moments, Gaussian shape (a good approximation when the noise is small
against the spacing of the vehicles). A relative jitter `jitter` · diag(R) is added to
R: when vehicles coincide (three start at the same point in §4.1) the Vandermonde
structure makes R nearly singular.

Filters
-------
- `sme-pf` (the paper's): particle filter over the joint state, particles
  (n_particles, N, 4) predicted by the motion model and weighted in log domain with the
  Gaussian pseudo-likelihood evaluated *per particle* (its own bias and R; a numba
  kernel, one pass over the particles, checked against the NumPy reference). A plain
  bootstrap update collapses in this 20-dimensional state (effective sample size ~10
  of 2000 with the §4.1 noise), so the update is tempered (progressive correction,
  Oudjane & Musso 2000): the likelihood enters in powers δ chosen by bisection so that
  each stage keeps `target_ess` of the particles (Jasra et al. 2011), and after each
  systematic resampling `n_moves` Metropolis–Hastings sweeps move the particles
  (resample-move, Gilks & Berzuini 2001) with target p(x_k | x_{k−1}) p(y | x_k)^β
  given each particle's own parent x_{k−1}, random-walk proposals scaled 2.38²/d times
  the narrower of the cloud's and the transition's covariance (acceptance ≈ 0.24).
  `n_particles` = 2000 by measurement (benchmarks/zhang2016.py, 8 runs of
  zhang2016-cv each; total error of eq. 20): 250 → 3.52 ± 0.27 m, 500 → 2.61 ± 0.05,
  1000 → 2.41 ± 0.04, 2000 → 2.11 ± 0.03, 4000 → 1.97 ± 0.02; beyond 2000 each halving
  of the error costs far more time than the particles double. After
  each update the vehicle blocks of every particle are relabelled by the permutation
  that best matches the predicted estimate (exhaustive over the N! permutations for
  N ≤ 7, otherwise skipped): the likelihood and the (identical per-vehicle) motion
  model are symmetric, so this leaves the symmetrised posterior unchanged, but it keeps
  particles that swapped two crossing vehicles from being averaged into a point between
  them (the MMOSPA-style estimate of Crouse, Willett et al. 2011).
- `sme-ukf`: the same model under an unscented Kalman filter (scaled sigma points,
  α, β, κ), R averaged over the sigma points. The paper says (§4.2.3) that EKF and UKF
  "do not give satisfying results" with polynomials up to order 5; see
  `cooploc reproduce zhang2016` for what we measure.

Missed detections and clutter (paper §4.2.1 leaves them open)
-------------------------------------------------------------
The SME map needs exactly N rows. When the setup has clutter (`Setup.clutter_rate` > 0)
or more than N rows arrive, GPS rows farther than the χ²₂ gate `gate_probability`
from every predicted vehicle (Mahalanobis, predicted covariance + row covariance) are
dropped as clutter (without clutter, N rows are used as they come: gating them would
let a filter that drifted discard the rows that could bring it back); if the count of
the remaining GPS rows (resp. of the radar rows, which cannot be gated without the
pose) differs from N, that pseudo-measurement is
skipped this step and the filter only predicts with it. `Estimate.info` reports
``gnss_rows_used``, ``gnss_rows_gated``, ``skipped`` (kinds skipped this step) and,
for the PF, ``ess`` and ``resampled``.

Estimates are set-valued: the vehicle blocks carry the ids of `frame.vehicles` in
order, but the measurements cannot tell vehicles apart, so ``info["set_valued"]`` is
True and metrics score them after an optimal assignment (`metrics.evaluate`).

Vehicles that enter get a block from `Setup.vehicle_prior` if they have one (predicted
to the step), else a belief centred on the GPS row farthest from every predicted
vehicle with `default_birth_cov` velocity variance; vehicles that leave lose their block.

Complexity per step: PF O(S P N⁴) for S tempering stages with n_moves likelihood
passes each (per particle: moments O(N³) — O(N⁴) in complex form — and a 2N × 2N
Cholesky) plus O(P N! N) for the relabelling; UKF O((4N)³) for the joint 4N-state and
O(N · N⁴) moments per sigma point.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numba
import numpy as np
from scipy.special import comb, factorial
from scipy.stats import chi2

from cooploc.estimators.base import birth_beliefs, default_birth_cov
from cooploc.gaussian import gaussian_logpdf, symmetrize
from cooploc.params import Params, param
from cooploc.particles import log_sum_exp
from cooploc.registry import register_estimator
from cooploc.types import Estimate, FloatArray, Frame, IntArray, Setup, StateSet

__all__ = [
    "SmePF",
    "SmePFParams",
    "SmeUKF",
    "SmeUKFParams",
    "complex_power_sum_moments",
    "complex_power_sums",
    "gaussian_raw_moments",
    "points_from_power_sums",
    "power_sum_moments",
    "power_sums",
    "systematic_resample",
    "topology",
    "topology_moments",
]

_MAX_EXHAUSTIVE = 7  # N! permutations up to 5040 for the relabelling


# ----------------------------------------------------------------------------
# the symmetric maps and their noise moments (pure functions)
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
    information (§3.2.3).
    """
    s = np.asarray(sums, dtype=float)
    n = s.size
    e = np.zeros(n + 1)
    e[0] = 1.0
    for k in range(1, n + 1):
        i = np.arange(1, k + 1)
        e[k] = np.sum((-1.0) ** (i - 1) * e[k - i] * s[i - 1]) / k
    coefficients = (-1.0) ** np.arange(n + 1) * e
    return np.sort(np.roots(coefficients).real)


def gaussian_raw_moments(mean: FloatArray, var: FloatArray, order: int) -> FloatArray:
    """E[mⁿ] for m ~ N(mean, var), n = 0..order: (...,) → (..., order + 1).

    μ_n = mean μ_{n−1} + (n − 1) var μ_{n−2} (module docstring).
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



def complex_power_sums(points: FloatArray, order: int) -> FloatArray:
    """[Re s_1..s_order, Im s_1..s_order] of s_k = Σ_i (x_i + i y_i)ᵏ: points (..., N, 2) → (..., 2 order)."""
    points = np.asarray(points, dtype=float)
    c = points[..., 0] + 1j * points[..., 1]
    s = (c[..., None] ** np.arange(1, order + 1)).sum(-2)
    return np.concatenate([s.real, s.imag], axis=-1)


def complex_power_sum_moments(points: FloatArray, var: FloatArray, order: int
                              ) -> tuple[FloatArray, FloatArray]:
    """Mean (..., 2 order) and covariance (..., 2 order, 2 order) of `complex_power_sums` of
    noisy points, isotropic noise of variance var (..., N) or (N,) per axis (module docstring)."""
    points = np.asarray(points, dtype=float)
    c = points[..., 0] + 1j * points[..., 1]                                  # (..., N)
    s = 2.0 * np.broadcast_to(np.asarray(var, dtype=float), c.shape)          # E|ε|² = 2σ²
    k = np.arange(1, order + 1)
    mean = (c[..., None] ** k).sum(-2)                                        # E[s_k] = Σ c_iᵏ
    gamma = np.zeros((*c.shape[:-1], order, order), dtype=complex)
    K, L = np.meshgrid(k, k, indexing="ij")
    for j in range(1, order + 1):   # Γ_kl = Σ_i Σ_j C(k,j) C(l,j) c^{k−j} c̄^{l−j} j! sʲ
        valid = (K >= j) & (L >= j)
        coeff = np.where(valid, comb(K, j) * comb(L, j) * factorial(j), 0.0)
        term = (c[..., None, None] ** np.where(valid, K - j, 0)[None]
                * np.conj(c)[..., None, None] ** np.where(valid, L - j, 0)[None])
        gamma = gamma + (coeff * term * (s**j)[..., None, None]).sum(-3)
    re, im = gamma.real, gamma.imag
    cov = 0.5 * np.concatenate([np.concatenate([re, -im], -1), np.concatenate([im, re], -1)], -2)
    return np.concatenate([mean.real, mean.imag], axis=-1), cov

# ----------------------------------------------------------------------------
# the pseudo-likelihood per particle (numba: the hot loop of sme-pf)
# ----------------------------------------------------------------------------

_LOG_2PI = float(np.log(2.0 * np.pi))
_MAX_ORDER = 16
_COMB = np.array([[float(comb(k, j, exact=True)) for j in range(_MAX_ORDER + 1)]
                  for k in range(_MAX_ORDER + 1)])
_FACT = np.array([float(factorial(j, exact=True)) for j in range(_MAX_ORDER + 1)])


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
def _complex_gnss_log_likelihood(u: FloatArray, y: FloatArray, var: float, C: FloatArray,
                                 r: FloatArray, p: int) -> float:
    """log N(y; E[s], Cov s) of the complex power sums for particle p (module docstring)."""
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
            C[k - 1, l - 1] = 0.5 * g.real
            C[n + k - 1, n + l - 1] = 0.5 * g.real
            C[k - 1, n + l - 1] = -0.5 * g.imag
            C[n + k - 1, l - 1] = 0.5 * g.imag
    return 0.0


@numba.njit(cache=True)
def _sme_log_likelihood(u: FloatArray, y_gnss: FloatArray, gnss_var: FloatArray, use_gnss: bool,
                        complex_form: bool, y_radar: float, radar_var: float, use_radar: bool,
                        jitter: float) -> FloatArray:
    """log p(y | u_p) for scaled positions u (P, N, 2): the numba twin of
    `PseudoMeasurement.log_likelihood_reference` (same moments, module docstring)."""
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
            _complex_gnss_log_likelihood(u, y_gnss, 0.5 * (gnss_var[0] + gnss_var[1]), C2, r2, p)
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


# ----------------------------------------------------------------------------
# shared model of both filters
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class PseudoMeasurement:
    """The stacked pseudo-measurement of one step (eq. 19) and how to predict it.

    centre (2,), scale ℓ: the fixed affine map u = (p − c)/ℓ of this step.
    form : "axes" (eq. 17: sums of powers of x and of y) or "complex" (of x + i y).
    gnss_var (2,) per-axis GPS row variance (scaled), radar_var the radar one (scaled),
    y_gnss (2N,) measured GPS pseudo-measurement or None (skipped), y_radar measured T or None.
    """

    centre: FloatArray
    scale: float
    form: str
    gnss_var: FloatArray
    radar_var: float
    y_gnss: FloatArray | None
    y_radar: float | None
    jitter: float

    def log_likelihood(self, positions: FloatArray) -> FloatArray:
        """log p(y | positions) for positions (P, N, 2) in the global frame → (P,) (numba)."""
        u = np.ascontiguousarray((positions - self.centre) / self.scale)
        y_gnss = np.zeros(2 * u.shape[1]) if self.y_gnss is None else self.y_gnss
        return _sme_log_likelihood(u, np.ascontiguousarray(y_gnss, dtype=float),
                                   np.asarray(self.gnss_var, dtype=float), self.y_gnss is not None,
                                   self.form == "complex", float(self.y_radar or 0.0),
                                   float(self.radar_var), self.y_radar is not None, float(self.jitter))

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
        if self.y_gnss is not None:
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
        R = np.zeros((S, D, D))
        start = 0
        for b in blocks:
            d = b.shape[-1]
            R[:, start:start + d, start:start + d] = b
            start += d
        return np.concatenate(ys), np.concatenate(means, axis=-1), R


def systematic_resample(log_weights: FloatArray, rng: np.random.Generator) -> IntArray:
    """Indices of a systematic resample of normalised log-weights (P,)."""
    P = log_weights.size
    cumulative = np.cumsum(np.exp(log_weights - log_sum_exp(log_weights, axis=None)))
    cumulative[-1] = 1.0
    positions = (rng.random() + np.arange(P)) / P
    return np.minimum(np.searchsorted(cumulative, positions), P - 1)


@dataclass(frozen=True)
class _SmeParams(Params):
    """Parameters shared by both SME filters.

    form : "axes" — eq. (17), sums of powers of the x and of the y coordinates (the
        paper's); "complex" — sums of powers of x + i y (keeps which x goes with which y).

    min_scale : smallest length ℓ (m) of the position scaling.
    jitter : relative regularisation of the pseudo-measurement covariance.
    gate_probability : χ²₂ gate of GPS rows against the predicted vehicles (clutter).
    use_radar : use the topology pseudo-measurement of the radar (eq. 18).
    """

    form: Literal["axes", "complex"] = "complex"
    min_scale: float = param(10.0, gt=0)
    jitter: float = param(1e-9, ge=0, lt=1)
    gate_probability: float = param(0.9999, gt=0, lt=1)
    use_radar: bool = True


class _SmeFilter:
    """Bookkeeping of both SME filters: vehicles in and out, pseudo-measurements, gating."""

    Params: ClassVar[type[Params]]
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "zhang2016-cv"
    required_sensors: ClassVar[tuple[str, ...]] = ("gnss", "radar")

    def __init__(self, setup: Setup, params: _SmeParams, rng: np.random.Generator) -> None:
        self.setup = setup
        self.params = params
        self.rng = rng
        self.pos = list(setup.vehicle_layout.position)
        self.dx = setup.vehicle_layout.dim
        self.F = setup.vehicle_motion.transition_matrix(setup.dt)
        self.Q = setup.vehicle_motion.noise_covariance(setup.dt)
        if self.Q.ndim == 3:  # state-dependent noise: use its value at rest for the joint model
            self.Q = self.Q[0]
        self.ids: IntArray = np.zeros(0, np.int64)
        self._gate = chi2.ppf(params.gate_probability, df=2)
        self._gnss_cols = list(getattr(setup.sensors.get("gnss"), "state_indices", self.pos))

    # -- to be provided by the filter ------------------------------------------------
    def _moments(self) -> tuple[FloatArray, FloatArray]:
        """(N, dx) mean and (N, dx, dx) covariance of each vehicle block."""
        raise NotImplementedError

    # -- shared ------------------------------------------------------------------------
    def _births(self, born: IntArray, frame: Frame, predicted: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Mean (b, dx) and cov (b, dx, dx) of entering vehicles (module docstring)."""
        beliefs = birth_beliefs(self.setup, born, frame)
        mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
        unknown = np.flatnonzero(~np.isin(born, self.setup.vehicle_prior.ids))
        gnss = frame.batches.get("gnss")
        if unknown.size and gnss is not None and len(gnss):
            z = gnss.z
            if predicted.shape[0]:
                dist = np.linalg.norm(z[:, None, :] - predicted[None, :, :], axis=-1).min(axis=1)
            else:
                dist = np.zeros(len(z))
            rows = np.argsort(-dist, kind="stable")[: unknown.size]
            for i, row in zip(unknown[: rows.size], rows, strict=False):
                mean[i] = 0.0
                mean[i, self._gnss_cols] = z[row]
                cov[i] = default_birth_cov(self.setup)
                cov[i][np.ix_(self.pos, self.pos)] = gnss.cov[row]
        return mean, cov

    def _pseudo_measurement(self, frame: Frame, mean: FloatArray, cov: FloatArray
                            ) -> tuple[PseudoMeasurement, dict[str, Any]]:
        """Build eq. (19) from the frame, gating GPS rows against the predicted vehicles."""
        n = mean.shape[0]
        p = mean[:, self.pos]
        centre = p.mean(axis=0)
        scale = max(float(np.sqrt(((p - centre) ** 2).sum(-1).mean())), self.params.min_scale)
        info: dict[str, Any] = {"skipped": [], "gnss_rows_used": 0, "gnss_rows_gated": 0}
        y_gnss, gnss_var = None, np.ones(2)
        gnss = frame.batches.get("gnss")
        if gnss is not None and len(gnss):
            S = cov[:, self.pos][:, :, self.pos][None] + gnss.cov[:, None]          # (M, N, 2, 2)
            r = gnss.z[:, None, :] - p[None]
            d2 = np.einsum("mni,mni->mn", r, np.linalg.solve(S, r[..., None])[..., 0])
            keep = d2.min(axis=1) <= self._gate
            if len(gnss) == n and self.setup.clutter_rate == 0:
                keep[:] = True  # no clutter in the model: N rows are the N vehicles
            info["gnss_rows_gated"] = int((~keep).sum())
            if keep.sum() == n:
                z = gnss.z[keep]
                gnss_var = np.einsum("mii->mi", gnss.cov[keep]).mean(0) / scale**2
                u = (z - centre) / scale
                y_gnss = (complex_power_sums(u, n) if self.params.form == "complex"
                          else np.concatenate([power_sums(u[:, a], n) for a in range(2)]))
                info["gnss_rows_used"] = n
            else:
                info["skipped"].append("gnss")
        elif n:
            info["skipped"].append("gnss")
        y_radar, radar_var = None, 1.0
        radar = frame.batches.get("radar")
        if self.params.use_radar and radar is not None and len(radar):
            if len(radar) == n and n >= 2:
                y_radar = float(topology(radar.z)) / scale**2
                # isotropic per-axis variance of each row: the rotation is unknown, so a
                # non-isotropic covariance is replaced by its mean eigenvalue
                radar_var = float(np.einsum("mii->m", radar.cov).mean() / 2) / scale**2
            else:
                info["skipped"].append("radar")
        elif self.params.use_radar and n:
            info["skipped"].append("radar")
        model = PseudoMeasurement(centre, scale, self.params.form, gnss_var, radar_var, y_gnss, y_radar,
                                  self.params.jitter)
        return model, info

    def _estimate(self, info: dict[str, Any]) -> Estimate:
        mean, cov = self._moments()
        info["set_valued"] = True
        return Estimate(StateSet(self.ids, mean, cov), None, info)


# ----------------------------------------------------------------------------
# sme-pf
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class SmePFParams(_SmeParams):
    """`sme-pf` parameters.

    n_particles : particles of the joint state (default chosen by measurement: see
        `benchmarks/zhang2016.py` and the report of `cooploc reproduce zhang2016`).
    resample_threshold : resample when ESS < threshold · n_particles.
    relabel : align the vehicle blocks of the particles to the predicted estimate.
    target_ess : ESS fraction each tempering stage keeps (progressive correction).
    n_moves : Metropolis–Hastings sweeps after each resampling inside the update (0: a
        plain bootstrap filter with tempering only).
    max_stages : at most this many tempering stages per step.
    """

    n_particles: int = param(2000, ge=2)
    resample_threshold: float = param(0.5, ge=0, le=1)
    relabel: bool = True
    target_ess: float = param(0.5, gt=0, lt=1)
    n_moves: int = param(2, ge=0)
    max_stages: int = param(20, ge=1)


@register_estimator
class SmePF(_SmeFilter):
    """SME particle filter over the joint state of all vehicles (the paper's method)."""

    name: ClassVar[str] = "sme-pf"
    summary: ClassVar[str] = ("symmetric measurement equation particle filter: anonymous GPS "
                              "(sum of powers) + radar topology of unknown pose (Zhang 2016)")
    Params: ClassVar[type[Params]] = SmePFParams

    def __init__(self, setup: Setup, params: SmePFParams, rng: np.random.Generator) -> None:
        super().__init__(setup, params, rng)
        self.params: SmePFParams = params
        P = params.n_particles
        self.particles = np.zeros((P, 0, self.dx))
        self.log_w = np.full(P, -np.log(P))
        self._L_Q = np.linalg.cholesky(self.Q + 1e-12 * np.eye(self.dx))
        self._perms: IntArray | None = None
        self._started = False

    def _moments(self) -> tuple[FloatArray, FloatArray]:
        w = np.exp(self.log_w - log_sum_exp(self.log_w, axis=None))
        mean = np.einsum("p,pni->ni", w, self.particles)
        r = self.particles - mean
        cov = np.einsum("p,pni,pnj->nij", w, r, r)
        cov = symmetrize(cov) + 1e-9 * np.eye(self.dx)  # keep SPD when particles collapse
        return mean, cov

    def _sync(self, frame: Frame) -> None:
        present = np.sort(frame.vehicles)
        if np.array_equal(present, self.ids):
            return
        keep = np.isin(self.ids, present)
        born = present[~np.isin(present, self.ids)]
        continuing = self.particles[:, keep]
        predicted = continuing[:, :, self.pos].mean(0) if continuing.shape[1] else np.zeros((0, 2))
        parts, ids = [continuing], [self.ids[keep]]
        if born.size:
            mean, cov = self._births(born, frame, predicted)
            L = np.linalg.cholesky(cov)
            white = self.rng.standard_normal((self.params.n_particles, born.size, self.dx))
            parts.append(mean + np.einsum("nij,pnj->pni", L, white))
            ids.append(born)
        ids_all = np.concatenate(ids)
        order = np.argsort(ids_all)
        self.ids = ids_all[order]
        self.particles = np.concatenate(parts, axis=1)[:, order]
        self._perms = None

    def _relabel(self, reference: FloatArray) -> None:
        """Permute each particle's vehicle blocks to best match `reference` (N, dx)."""
        n = self.ids.size
        if not self.params.relabel or n < 2 or n > _MAX_EXHAUSTIVE:
            return
        if self._perms is None or self._perms.shape[1] != n:
            self._perms = np.array(list(itertools.permutations(range(n))), dtype=np.int64)
        diff = self.particles[:, None, :, :] - reference[None, :, None, :]     # (P, N_ref, N, dx)
        cost = (diff**2).sum(-1)                                                 # (P, i, j)
        total = cost[:, np.arange(n)[None, :], self._perms].sum(-1)              # (P, n!)
        best = self._perms[np.argmin(total, axis=1)]                             # (P, N)
        moved = (best != np.arange(n)).any(axis=1)
        if moved.any():
            rows = np.flatnonzero(moved)
            self.particles[rows] = np.take_along_axis(self.particles[rows], best[rows][..., None], 1)

    def _log_prior(self, x: FloatArray, parents: FloatArray) -> FloatArray:
        """log p(x_k | x_{k−1}) up to a constant, summed over vehicle blocks: (P,)."""
        r = x - parents @ self.F.T
        white = np.linalg.solve(self._L_Q, r.reshape(-1, self.dx).T).T          # L⁻¹ r
        return -0.5 * (white**2).reshape(x.shape[0], -1).sum(-1)

    def _move(self, model: PseudoMeasurement, beta: float, loglik: FloatArray,
              parents: FloatArray) -> tuple[FloatArray, float]:
        """`n_moves` Metropolis–Hastings sweeps targeting p(x | x_{k−1}) p(y | x)^β.

        Random-walk proposals per vehicle block with covariance (2.38²/d) min(Σ̂, Q): the
        spread of the cloud Σ̂ or, when the cloud is wider, of the transition kernel Q
        that each particle's target is narrower than (d the joint dimension;
        Roberts & Rosenthal 2001). Returns the new log-likelihoods and the acceptance rate.
        """
        P, n, dx = self.particles.shape
        _, cov = self._moments()
        # per block, the narrower of Σ̂ and Q in the sense of their traces
        narrow = np.where((np.trace(cov, axis1=1, axis2=2) < np.trace(self.Q))[:, None, None],
                          cov, self.Q)
        L = np.linalg.cholesky(narrow * (2.38**2 / (n * dx)) + 1e-12 * np.eye(dx))   # (N, dx, dx)
        log_prior = self._log_prior(self.particles, parents)
        accepted = 0
        for _ in range(self.params.n_moves):
            proposal = self.particles + np.einsum(
                "nij,pnj->pni", L, self.rng.standard_normal(self.particles.shape))
            ll_new = model.log_likelihood(proposal[:, :, self.pos])
            lp_new = self._log_prior(proposal, parents)
            log_alpha = beta * (ll_new - loglik) + lp_new - log_prior
            accept = np.log(self.rng.random(P)) < np.nan_to_num(log_alpha, nan=-np.inf)
            self.particles[accept] = proposal[accept]
            loglik = np.where(accept, ll_new, loglik)
            log_prior = np.where(accept, lp_new, log_prior)
            accepted += int(accept.sum())
        return loglik, accepted / max(P * self.params.n_moves, 1)

    def _resample(self, parents: FloatArray, loglik: FloatArray) -> tuple[FloatArray, FloatArray]:
        idx = systematic_resample(self.log_w, self.rng)
        self.particles = self.particles[idx]
        self.log_w = np.full(idx.size, -np.log(idx.size))
        return parents[idx], loglik[idx]

    def _ess(self) -> float:
        return float(np.exp(2 * log_sum_exp(self.log_w, axis=None) - log_sum_exp(2 * self.log_w, axis=None)))

    def _next_increment(self, loglik: FloatArray, remaining: float) -> float:
        """Largest δ ≤ remaining with ESS(w · p(y|x)^δ) ≥ target (bisection; Jasra et al. 2011)."""
        target = self.params.target_ess * self.log_w.size

        def ess(delta: float) -> float:
            lw = self.log_w + delta * loglik
            return float(np.exp(2 * log_sum_exp(lw, axis=None) - log_sum_exp(2 * lw, axis=None)))

        if ess(remaining) >= target:
            return remaining
        low, high = 0.0, remaining
        for _ in range(30):
            mid = 0.5 * (low + high)
            low, high = (mid, high) if ess(mid) >= target else (low, mid)
        return max(low, remaining * 1e-3)

    def _update(self, model: PseudoMeasurement, parents: FloatArray, info: dict[str, Any]) -> None:
        """Tempered update (progressive correction) with resample-move between stages."""
        loglik = model.log_likelihood(self.particles[:, :, self.pos])
        finite = np.isfinite(loglik)
        if not finite.any():
            info["degenerate"] = True
            return
        loglik = np.where(finite, loglik, -1e300)
        beta, stages, rates = 0.0, 0, []
        while beta < 1.0:
            stages += 1
            remaining = 1.0 - beta
            delta = remaining if stages >= self.params.max_stages else self._next_increment(
                loglik, remaining)
            # w ∝ w p(y | x)^δ   (eq. 19 pseudo-likelihood, tempered)
            self.log_w = self.log_w + delta * loglik
            self.log_w -= log_sum_exp(self.log_w, axis=None)
            beta = 1.0 if delta >= remaining else beta + delta
            if beta < 1.0 or self._ess() < self.params.resample_threshold * self.log_w.size:
                parents, loglik = self._resample(parents, loglik)
                if self.params.n_moves:
                    loglik, rate = self._move(model, beta, loglik, parents)
                    rates.append(rate)
        info["stages"] = stages
        info["acceptance"] = float(np.mean(rates)) if rates else None

    def step(self, frame: Frame) -> Estimate:
        parents = None  # x_{k−1} of each particle, for the move kernel
        if self.ids.size and self._started:
            parents = self.particles
            # predict: x_k = A x_{k−1} + w_k, every vehicle block (eq. 16)
            noise = self.rng.standard_normal(self.particles.shape) @ self._L_Q.T
            self.particles = self.particles @ self.F.T + noise
        self._started = True
        if not np.array_equal(np.sort(frame.vehicles), self.ids):
            self._sync(frame)
            parents = None  # blocks changed: no move kernel this step
        info: dict[str, Any] = {"n_particles": self.params.n_particles}
        n = self.ids.size
        if n == 0:
            info.update(set_valued=True, skipped=[], ess=float(self.params.n_particles),
                        resampled=False, stages=0)
            return Estimate(StateSet.empty(self.dx), None, info)
        mean, cov = self._moments()
        model, pm_info = self._pseudo_measurement(frame, mean, cov)
        info.update(pm_info)
        info["stages"] = 0
        if model.y_gnss is not None or model.y_radar is not None:
            if parents is None:
                # nothing to move against (first step, vehicles entered): one plain update
                self.log_w = self.log_w + model.log_likelihood(self.particles[:, :, self.pos])
                self.log_w = np.where(np.isfinite(self.log_w), self.log_w, -np.inf)
                if not np.isfinite(self.log_w).any():
                    self.log_w = np.zeros_like(self.log_w)
                    info["degenerate"] = True
                self.log_w -= log_sum_exp(self.log_w, axis=None)
                info["stages"] = 1
            else:
                self._update(model, parents, info)
        self._relabel(mean)
        ess = self._ess()
        info["ess"] = ess
        estimate = self._estimate(info)
        info["resampled"] = ess < self.params.resample_threshold * self.params.n_particles
        if info["resampled"]:
            idx = systematic_resample(self.log_w, self.rng)
            self.particles = self.particles[idx]
            self.log_w = np.full(idx.size, -np.log(idx.size))
        return estimate


# ----------------------------------------------------------------------------
# sme-ukf
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class SmeUKFParams(_SmeParams):
    """`sme-ukf` parameters: the scaled unscented transform (Wan & van der Merwe 2000).

    alpha, beta, kappa : spread of the sigma points, prior-shape weight, secondary scaling.
    """

    alpha: float = param(1.0, gt=0)
    beta: float = 2.0
    kappa: float = 0.0


@register_estimator
class SmeUKF(_SmeFilter):
    """SME under an unscented Kalman filter over the joint state (§4.2.3 check)."""

    name: ClassVar[str] = "sme-ukf"
    summary: ClassVar[str] = "symmetric measurement equation under an unscented Kalman filter (check)"
    Params: ClassVar[type[Params]] = SmeUKFParams

    def __init__(self, setup: Setup, params: SmeUKFParams, rng: np.random.Generator) -> None:
        super().__init__(setup, params, rng)
        self.params: SmeUKFParams = params
        self.mean = np.zeros((0, self.dx))       # (N, dx)
        self.cov = np.zeros((0, 0))              # (N dx, N dx) joint
        self._started = False

    def _moments(self) -> tuple[FloatArray, FloatArray]:
        n, dx = self.mean.shape
        blocks = self.cov.reshape(n, dx, n, dx)[np.arange(n), :, np.arange(n), :]
        return self.mean.copy(), symmetrize(blocks) + 1e-9 * np.eye(dx)

    def _sync(self, frame: Frame) -> None:
        present = np.sort(frame.vehicles)
        if np.array_equal(present, self.ids):
            return
        dx = self.mean.shape[1]
        keep = np.isin(self.ids, present)
        born = present[~np.isin(present, self.ids)]
        cols = (np.flatnonzero(keep)[:, None] * dx + np.arange(dx)).ravel()
        mean, cov = self.mean[keep], self.cov[np.ix_(cols, cols)]
        ids = self.ids[keep]
        if born.size:
            b_mean, b_cov = self._births(born, frame, mean[:, self.pos])
            mean = np.concatenate([mean, b_mean])
            m = cov.shape[0]
            grown = np.zeros((m + born.size * dx,) * 2)
            grown[:m, :m] = cov
            for i in range(born.size):  # few per step
                s = m + i * dx
                grown[s:s + dx, s:s + dx] = b_cov[i]
            cov, ids = grown, np.concatenate([ids, born])
        order = np.argsort(ids)
        cols = (order[:, None] * dx + np.arange(dx)).ravel()
        self.ids, self.mean, self.cov = ids[order], mean[order], cov[np.ix_(cols, cols)]

    def _sigma_points(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(2d + 1, N, dx) points and mean/covariance weights of the scaled UT."""
        p = self.params
        d = self.cov.shape[0]
        lam = p.alpha**2 * (d + p.kappa) - d
        L = np.linalg.cholesky(symmetrize(self.cov) * (d + lam) + 1e-12 * np.eye(d))
        x = self.mean.ravel()
        points = np.concatenate([x[None], x + L.T, x - L.T])
        w_m = np.full(2 * d + 1, 0.5 / (d + lam))
        w_c = w_m.copy()
        w_m[0] = lam / (d + lam)
        w_c[0] = w_m[0] + 1 - p.alpha**2 + p.beta
        return points.reshape(2 * d + 1, *self.mean.shape), w_m, w_c

    def step(self, frame: Frame) -> Estimate:
        n = self.ids.size
        if n and self._started:
            # predict every block: m = A m, P = A P Aᵀ + Q (block diagonal)
            A = np.kron(np.eye(n), self.F)
            self.mean = self.mean @ self.F.T
            self.cov = symmetrize(A @ self.cov @ A.T + np.kron(np.eye(n), self.Q))
        self._started = True
        self._sync(frame)
        n = self.ids.size
        if n == 0:
            return Estimate(StateSet.empty(self.dx), None, {"set_valued": True, "skipped": []})
        mean, cov = self._moments()
        model, info = self._pseudo_measurement(frame, mean, cov)
        if model.y_gnss is not None or model.y_radar is not None:
            points, w_m, w_c = self._sigma_points()
            y, Y, R = model.predict(points[:, :, self.pos])
            y_hat = w_m @ Y                                                  # ȳ = Σ W_m Y
            dY = Y - y_hat
            dX = points.reshape(points.shape[0], -1) - self.mean.ravel()
            S = symmetrize(np.einsum("s,si,sj->ij", w_c, dY, dY) + np.einsum("s,sij->ij", w_m, R))
            C = np.einsum("s,si,sj->ij", w_c, dX, dY)                        # cross-covariance
            K = np.linalg.solve(S, C.T).T                                    # K = C S⁻¹
            self.mean = (self.mean.ravel() + K @ (y - y_hat)).reshape(self.mean.shape)
            self.cov = symmetrize(self.cov - K @ S @ K.T)
            eig_min = np.linalg.eigvalsh(self.cov).min()
            if eig_min <= 1e-9:  # the UT lost positive definiteness: lift the spectrum
                self.cov = self.cov + (1e-9 - eig_min) * np.eye(self.cov.shape[0])
                info["covariance_repaired"] = True
        return self._estimate(info)
