"""`plbp` and `prior-lbp`: cooperative position and heading estimation from angle of arrival
with posterior-linearization belief propagation.

Paper: "Cooperative Localization with Angular Measurements and Posterior Linearization"
(`papers/002_dfdb230c2e4252cd.txt`; equations restated in `papers/plbp_model_notes.md`),
after García-Fernández, Svensson & Särkkä, IEEE TVT 2018 (PLBP) and IEEE TSP 2015 (PLF).

Model
-----
Vehicle state x_i = [p_x, p_y, α] (the AoA sensor's `state_indices`), Gaussian prior
N(μ_i, Σ_i) (eq. 1). Each AoA row is θ_{i←j} = wrap(atan2(p_j − p_i) − α_i) + w,
w ~ N(0, σ²_θ) (eqs. 2–5), `sensor` = receiver i, `subject` = transmitter j. The rows of
one vehicle pair form one link factor with the measurement vector z_ij = [θ_{i←j}, θ_{j←i}]
(whichever ends saw the other; an end that did not measure is a zero row, see below).

Algorithm 1 (information form, flooding schedule)
-------------------------------------------------
    beliefs ← priors;  messages ← 0
    for j in 1..J:                                   # linearization iterations
        for every link (i, j): SLR of h w.r.t. the current joint posterior approximation
            (eq. 10: product of the two cavities × the link's current linearized
            likelihood; at j = 1 the product of the priors) → (A, c, Ω)   (eqs. 11–22)
        for l in 1..L:                               # BP on the linearized model
            every message:  S = R + Ω + A_j Σ_{j∖i} A_jᵀ
                            J_{ij→i} = A_iᵀ S⁻¹ A_i                       (eq. 24)
                            h_{ij→i} = A_iᵀ S⁻¹ (z̃ − c − A_j μ_{j∖i})
            every belief:   Λ_i = Σ_i⁻¹ + Σ J_{·→i},  η_i = Σ_i⁻¹ μ_i + Σ h_{·→i}   (eq. 9)
`prior-lbp` is the same loop with the links linearized once, w.r.t. the priors, and
never again (the paper's "prior LF"): its J iterations are J·L BP iterations on one
linear model, so the two are compared at equal message-passing cost.

Every step is one batched NumPy operation over all links (no Python loop over links
or vehicles): a linearization costs O(F (2dx)³) for F links, a BP iteration O(F dx³) plus
an O(F) scatter-add into the vehicles. Per vehicle: O(J L |N_i| dx³), as the paper states.

Choices the paper leaves open (documented for DESIGN)
-----------------------------------------------------
- A link whose one end did not measure (field of view) keeps a 2-row model whose
  missing row is A = 0, c = 0, z = 0 with unit variance and no correlation: exactly
  equivalent to the 1-row model, and it keeps every link the same shape.
- Two rows of one direction of one pair (not produced by our scenarios) become two
  links.
- z̃ (eq. 24): z moved onto the branch nearest the SLR prediction c + A ȳ.
- Sigma points: unscented with central weight 1/3 (default) or cubature.
- The heading of a belief is kept unwrapped during one solve (messages in information
  form refer to one branch) and wrapped to [−π, π) in the output.
- Tracking (beyond the paper): the belief of the previous step is predicted with the
  scenario's motion model (`RandomWalk` for `aoa-grid`), then updated with that step's
  `"gnss"` rows (a fresh position/heading fix, angular components moved onto the
  branch of the prediction) in information form; the result is the prior of this
  step's PLBP. Vehicles that enter start from `Setup.vehicle_prior` or their first fix
  (`estimators.base.birth_beliefs`).
- AoA rows naming a vehicle that is not present are ignored.
- `info["iterate_means"]` (J + 1, n, dx): the beliefs' means before the first and after
  every linearization iteration (heading wrapped), in the order of `Estimate.vehicles`;
  the estimator never sees truth, so per-iteration errors are computed by the caller
  (`iteration_errors`). `info["n_links"]`: the number of link factors.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numba
import numpy as np

from cooploc.errors import ConfigError
from cooploc.estimators.base import VehicleBeliefs
from cooploc.gaussian import (
    SIGMA_POINT_METHODS,
    Gaussians,
    from_information,
    kf_predict,
    kf_update,
    statistical_linear_regression,
    symmetrize,
    to_information,
)
from cooploc.geometry import wrap_angle
from cooploc.params import Params, param
from cooploc.registry import register_estimator
from cooploc.sensors import AngleOfArrival
from cooploc.types import Batch, Estimate, FloatArray, Frame, IntArray, Setup, StateLayout, StateSet

__all__ = [
    "PLBP",
    "LinkFactors",
    "PLBPParams",
    "PriorLBP",
    "PriorLBPParams",
    "gaussian_bp",
    "iteration_errors",
    "link_factors",
    "plbp_solve",
]


# ----------------------------------------------------------------------------
# parameters
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class PLBPParams(Params):
    """Parameters of `plbp`.

    Attributes
    ----------
    linearization_iterations : J, relinearizations per snapshot (paper: converged by 4).
    bp_iterations : L, BP iterations per linearization.
    sigma_points : "unscented" or "cubature".
    central_weight : w₀ of the unscented points.
    """

    linearization_iterations: int = param(5, ge=1)
    bp_iterations: int = param(3, ge=1)
    sigma_points: Literal["unscented", "cubature"] = "unscented"
    central_weight: float = param(1.0 / 3.0, ge=0, lt=1)


@dataclass(frozen=True)
class PriorLBPParams(PLBPParams):
    """Parameters of `prior-lbp` (as `plbp`; the links are linearized once, at the priors)."""



# ----------------------------------------------------------------------------
# link factors
# ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class LinkFactors:
    """AoA link factors between vehicles (by position in the belief arrays).

    Attributes
    ----------
    a, b : (F,) the two vehicles of each link.
    z : (F, 2) [θ_{a←b}, θ_{b←a}] in rad; 0 where not measured.
    measured : (F, 2) which of the two was measured.
    R : (F, 2, 2) noise covariance: diag(σ²) on measured rows, 1 on missing ones.
    """

    a: IntArray
    b: IntArray
    z: FloatArray
    measured: np.ndarray
    R: FloatArray

    def __len__(self) -> int:
        return self.a.size


def link_factors(batch: Batch, ids: IntArray) -> LinkFactors:
    """Group AoA rows into link factors over vehicles `ids` (sorted or not).

    Rows whose receiver or transmitter is not in `ids`, or which measure a vehicle
    itself, are dropped. The two directions of a pair share one factor; a second row of
    the same direction starts another factor.
    """
    order = np.argsort(ids, kind="stable")
    if ids.size == 0 or len(batch) == 0:
        empty = np.zeros(0, np.int64)
        return LinkFactors(empty, empty, np.zeros((0, 2)), np.zeros((0, 2), bool), np.zeros((0, 2, 2)))
    rx = order[np.minimum(np.searchsorted(ids, batch.sensor, sorter=order), ids.size - 1)]
    tx = order[np.minimum(np.searchsorted(ids, batch.subject, sorter=order), ids.size - 1)]
    keep = (ids[rx] == batch.sensor) & (ids[tx] == batch.subject) & (rx != tx)
    rx, tx = rx[keep], tx[keep]
    z_rows, var_rows = batch.z[keep, 0], batch.cov[keep, 0, 0]
    lo, hi = np.minimum(rx, tx), np.maximum(rx, tx)
    comp = (rx != lo).astype(np.int64)               # 0: θ measured at `a` = lo, 1: at `b` = hi
    pair = lo * ids.size + hi
    rows = np.lexsort((comp, pair))                  # group rows by (pair, direction)
    key = pair[rows] * 2 + comp[rows]
    start = np.r_[0, np.flatnonzero(np.diff(key)) + 1]
    rank = np.empty(rows.size, np.int64)             # occurrence of the row within its group
    rank[rows] = np.arange(rows.size) - np.repeat(start, np.diff(np.r_[start, rows.size]))
    factor_key, factor = np.unique(pair * (rows.size + 1) + rank, return_inverse=True)
    F = factor_key.size
    a, b = np.zeros(F, np.int64), np.zeros(F, np.int64)
    a[factor], b[factor] = lo, hi
    z, measured, R = np.zeros((F, 2)), np.zeros((F, 2), bool), np.zeros((F, 2, 2))
    z[factor, comp], measured[factor, comp] = z_rows, True
    R[:, 0, 0] = R[:, 1, 1] = 1.0
    R[factor, comp, comp] = var_rows
    return LinkFactors(a, b, z, measured, R)


# ----------------------------------------------------------------------------
# Gaussian BP on a linearized model, and Algorithm 1
# ----------------------------------------------------------------------------


def _scatter(index: IntArray, values: FloatArray, n: int) -> FloatArray:
    """Σ of `values` (F, ...) into n slots by `index` (F,)."""
    out = np.zeros((n, *values.shape[1:]))
    np.add.at(out, index, values)
    return out


# Small dense kernels, one link per loop iteration (numba): batched NumPy LAPACK calls
# on 3×3 and 2×2 matrices cost more in per-matrix overhead than in arithmetic.


@numba.njit(cache=True)
def _cholesky(M: FloatArray, L: FloatArray) -> None:  # pragma: no cover - compiled
    """Lower Cholesky factor of a small SPD matrix M into L. A non-positive pivot (round-off
    only: every matrix factored here is SPD in exact arithmetic) is floored at 1e-300."""
    d = M.shape[0]
    for j in range(d):
        s = M[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        L[j, j] = np.sqrt(max(s, 1e-300))
        for i in range(j + 1, d):
            t = M[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
            L[j, i] = 0.0


@numba.njit(cache=True)
def _cho_solve(L: FloatArray, X: FloatArray) -> None:  # pragma: no cover - compiled
    """Overwrite X (d, k) with the solution of L Lᵀ X = X: forward, then backward substitution."""
    d, k = X.shape
    for col in range(k):
        for i in range(d):
            t = X[i, col]
            for m in range(i):
                t -= L[i, m] * X[m, col]
            X[i, col] = t / L[i, i]
        for i in range(d - 1, -1, -1):
            t = X[i, col]
            for m in range(i + 1, d):
                t -= L[m, i] * X[m, col]
            X[i, col] = t / L[i, i]


@numba.njit(cache=True)
def _cavities(Lam: FloatArray, eta: FloatArray, index: IntArray, J: FloatArray, h: FloatArray
              ) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """Moments of the cavities (belief ÷ this link's message): μ (F, d), Σ (F, d, d)."""
    F, d = index.size, Lam.shape[1]
    mu, cov = np.empty((F, d)), np.empty((F, d, d))
    C, L, S = np.empty((d, d)), np.zeros((d, d)), np.empty((d, d))
    for f in range(F):
        i = index[f]
        for r in range(d):
            for q in range(d):
                C[r, q] = Lam[i, r, q] - J[f, r, q]          # Λ_i − J_{f→i}
                S[r, q] = 1.0 if r == q else 0.0
        _cholesky(C, L)
        _cho_solve(L, S)                                     # Σ_{i∖f} = (Λ_i − J_{f→i})⁻¹
        for r in range(d):
            acc = 0.0
            for q in range(d):
                cov[f, r, q] = 0.5 * (S[r, q] + S[q, r])
                acc += S[r, q] * (eta[i, q] - h[f, q])       # μ_{i∖f} = Σ (η_i − h_{f→i})
            mu[f, r] = acc
    return mu, cov


@numba.njit(cache=True)
def _link_messages(A_to: FloatArray, A_from: FloatArray, mu: FloatArray, cov: FloatArray,
                   c: FloatArray, noise: FloatArray, z: FloatArray
                   ) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """eq. (24) for every link: J = A_iᵀ S⁻¹ A_i, h = A_iᵀ S⁻¹ (z̃ − c − A_j μ_{j∖i}),
    S = R + Ω + A_j Σ_{j∖i} A_jᵀ, with the cavity (μ, Σ) of the other end j."""
    F, dz, d = A_to.shape
    J, h = np.empty((F, d, d)), np.empty((F, d))
    AS, S, L = np.empty((dz, d)), np.empty((dz, dz)), np.zeros((dz, dz))
    X = np.empty((dz, d + 1))                                # [A_i | innovation], solved in place
    for f in range(F):
        for r in range(dz):
            for q in range(d):
                acc = 0.0
                for m in range(d):
                    acc += A_from[f, r, m] * cov[f, m, q]
                AS[r, q] = acc                               # A_j Σ
        for r in range(dz):
            for q in range(dz):
                acc = 0.0
                for m in range(d):
                    acc += AS[r, m] * A_from[f, q, m]
                S[r, q] = noise[f, r, q] + acc               # S = R + Ω + A_j Σ A_jᵀ
            acc = 0.0
            for m in range(d):
                acc += A_from[f, r, m] * mu[f, m]
                X[r, m] = A_to[f, r, m]
            X[r, d] = z[f, r] - c[f, r] - acc                # z̃ − c − A_j μ_{j∖i}
        for r in range(dz):
            for q in range(r):
                v = 0.5 * (S[r, q] + S[q, r])
                S[r, q] = v
                S[q, r] = v
        _cholesky(S, L)
        _cho_solve(L, X)                                     # S⁻¹ [A_i | innovation]
        for r in range(d):
            acc = 0.0
            for m in range(dz):
                acc += A_to[f, m, r] * X[m, d]
            h[f, r] = acc
            for q in range(r + 1):
                acc = 0.0
                for m in range(dz):
                    acc += A_to[f, m, r] * X[m, q]
                J[f, r, q] = acc                             # A_iᵀ S⁻¹ A_i, symmetric
                J[f, q, r] = acc
    return J, h


@numba.njit(cache=True)
def _accumulate(Lam0: FloatArray, eta0: FloatArray, a: IntArray, b: IntArray, Ja: FloatArray,
                ha: FloatArray, Jb: FloatArray, hb: FloatArray
                ) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """eq. (9): Λ_i = Λ⁰_i + Σ J_{·→i}, η_i = η⁰_i + Σ h_{·→i}."""
    Lam, eta = Lam0.copy(), eta0.copy()
    for f in range(a.size):
        Lam[a[f]] += Ja[f]
        eta[a[f]] += ha[f]
        Lam[b[f]] += Jb[f]
        eta[b[f]] += hb[f]
    return Lam, eta


@numba.njit(cache=True)
def _aoa_joint_slr(mu_a: FloatArray, cov_a: FloatArray, mu_b: FloatArray, cov_b: FloatArray,
                   A_prev: FloatArray, y_prev: FloatArray, noise_prev: FloatArray, update: bool,
                   z: FloatArray, index: IntArray, central_weight: float
                   ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover
    """Joint posterior approximation and SLR of the two bearings of every link (fused).

    Per link: the joint N(m, P) of [x_a; x_b] is the product of the cavities, Kalman-updated
    (Joseph form) with the previous linearization y = A x + e, e ~ N(0, noise) when
    `update` (eq. 10); then the unscented SLR (eqs. 14–22) of h = [θ_{a←b}, θ_{b←a}] with the
    branch correction of eq. (15) towards the measurement z. The same numbers as
    `_linearize_reference` (NumPy, via `gaussian.statistical_linear_regression`), at a
    fraction of the cost: no (F, S, 2dx) temporaries. `index` = (p_x, p_y, α) in x.
    Returns A (F, 2, 2d), c (F, 2), Ω (F, 2, 2), joint means (F, 2d).
    """
    F, d = mu_a.shape
    D, S = 2 * d, 4 * d + 1
    ix, iy, ia = index[0], index[1], index[2]
    A_out, c_out = np.empty((F, 2, D)), np.empty((F, 2))
    O_out, m_out = np.empty((F, 2, 2)), np.empty((F, D))
    m, P, L = np.empty(D), np.empty((D, D)), np.zeros((D, D))
    PH, Sm, Ls, K, KH, T = (np.empty((D, 2)), np.empty((2, 2)), np.zeros((2, 2)), np.empty((D, 2)),
                            np.empty((D, D)), np.empty((D, D)))
    chi, zeta, w = np.empty((S, D)), np.empty((S, 2)), np.empty(S)
    Psi, X = np.empty((D, 2)), np.empty((D, 2))
    spread = np.sqrt(D / (1.0 - central_weight))
    w[0] = central_weight
    for s in range(1, S):
        w[s] = (1.0 - central_weight) / (2 * D)
    for f in range(F):
        P[:, :] = 0.0
        for r in range(d):
            m[r], m[d + r] = mu_a[f, r], mu_b[f, r]
            for q in range(d):
                P[r, q], P[d + r, d + q] = cov_a[f, r, q], cov_b[f, r, q]
        if update:
            # K = P Hᵀ S⁻¹, S = H P Hᵀ + R; m += K (y − H m); P = (I − KH) P (I − KH)ᵀ + K R Kᵀ
            for r in range(D):
                for k in range(2):
                    acc = 0.0
                    for q in range(D):
                        acc += P[r, q] * A_prev[f, k, q]
                    PH[r, k] = acc
            for k in range(2):
                for l2 in range(2):
                    acc = noise_prev[f, k, l2]
                    for q in range(D):
                        acc += A_prev[f, k, q] * PH[q, l2]
                    Sm[k, l2] = acc
            v = 0.5 * (Sm[0, 1] + Sm[1, 0])
            Sm[0, 1], Sm[1, 0] = v, v
            _cholesky(Sm, Ls)
            for r in range(D):                               # K = (S⁻¹ (P Hᵀ)ᵀ)ᵀ, S symmetric
                K[r, 0], K[r, 1] = PH[r, 0], PH[r, 1]
            Kt = np.ascontiguousarray(K.T)
            _cho_solve(Ls, Kt)
            innov0, innov1 = y_prev[f, 0], y_prev[f, 1]
            for q in range(D):
                innov0 -= A_prev[f, 0, q] * m[q]
                innov1 -= A_prev[f, 1, q] * m[q]
            for r in range(D):
                K[r, 0], K[r, 1] = Kt[0, r], Kt[1, r]
                m[r] += K[r, 0] * innov0 + K[r, 1] * innov1
            for r in range(D):
                for q in range(D):
                    KH[r, q] = ((1.0 if r == q else 0.0) - K[r, 0] * A_prev[f, 0, q]
                                - K[r, 1] * A_prev[f, 1, q])
            for r in range(D):                               # T = (I − KH) P
                for q in range(D):
                    acc = 0.0
                    for k in range(D):
                        acc += KH[r, k] * P[k, q]
                    T[r, q] = acc
            for r in range(D):                               # P = T (I − KH)ᵀ + K R Kᵀ
                for q in range(r + 1):
                    acc = 0.0
                    for k in range(D):
                        acc += T[r, k] * KH[q, k]
                    for k in range(2):
                        for l2 in range(2):
                            acc += K[r, k] * noise_prev[f, k, l2] * K[q, l2]
                    P[r, q] = acc
            for r in range(D):
                for q in range(r + 1, D):
                    P[r, q] = P[q, r]
        _cholesky(P, L)
        # sigma points: m, m ± spread · L_k
        for r in range(D):
            chi[0, r] = m[r]
        for k in range(D):
            for r in range(D):
                chi[1 + k, r] = m[r] + spread * L[r, k]
                chi[1 + D + k, r] = m[r] - spread * L[r, k]
        zbar0 = zbar1 = 0.0
        for s in range(S):
            t0 = np.arctan2(chi[s, d + iy] - chi[s, iy], chi[s, d + ix] - chi[s, ix]) - chi[s, ia]
            t1 = np.arctan2(chi[s, iy] - chi[s, d + iy], chi[s, ix] - chi[s, d + ix]) - chi[s, d + ia]
            # eq. (15): ζ̃ = z + mod(ζ − z + π, 2π) − π
            zeta[s, 0] = z[f, 0] + np.mod(t0 - z[f, 0] + np.pi, 2.0 * np.pi) - np.pi
            zeta[s, 1] = z[f, 1] + np.mod(t1 - z[f, 1] + np.pi, 2.0 * np.pi) - np.pi
            zbar0 += w[s] * zeta[s, 0]
            zbar1 += w[s] * zeta[s, 1]
        Psi[:, :] = 0.0
        p00 = p01 = p11 = 0.0
        for s in range(S):
            e0, e1 = zeta[s, 0] - zbar0, zeta[s, 1] - zbar1
            p00 += w[s] * e0 * e0
            p01 += w[s] * e0 * e1
            p11 += w[s] * e1 * e1
            for r in range(D):
                dc = w[s] * (chi[s, r] - m[r])
                Psi[r, 0] += dc * e0
                Psi[r, 1] += dc * e1
        X[:, :] = Psi
        _cho_solve(L, X)                                     # P⁻¹ Ψ = Aᵀ
        o00, o01, o11 = p00, p01, p11                        # Ω = Φ − A P Aᵀ = Φ − Ψᵀ P⁻¹ Ψ
        c0, c1 = zbar0, zbar1
        for r in range(D):
            A_out[f, 0, r], A_out[f, 1, r] = X[r, 0], X[r, 1]
            o00 -= Psi[r, 0] * X[r, 0]
            o01 -= 0.5 * (Psi[r, 0] * X[r, 1] + Psi[r, 1] * X[r, 0])
            o11 -= Psi[r, 1] * X[r, 1]
            c0 -= X[r, 0] * m[r]
            c1 -= X[r, 1] * m[r]
            m_out[f, r] = m[r]
        c_out[f, 0], c_out[f, 1] = c0, c1
        O_out[f, 0, 0], O_out[f, 0, 1], O_out[f, 1, 0], O_out[f, 1, 1] = o00, o01, o01, o11
    return A_out, c_out, O_out, m_out


class _BP:
    """Running quantities of Gaussian BP in information form over link factors."""

    def __init__(self, prior: Gaussians, links: LinkFactors) -> None:
        self.links = links
        self.Lam0, self.eta0 = to_information(prior)
        F, d = len(links), prior.mean.shape[1]
        self.Ja, self.ha = np.zeros((F, d, d)), np.zeros((F, d))
        self.Jb, self.hb = np.zeros((F, d, d)), np.zeros((F, d))
        self.Lam, self.eta = self.Lam0.copy(), self.eta0.copy()

    def cavities(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(μ_a, Σ_a, μ_b, Σ_b) of every link's two cavities."""
        links = self.links
        mu_a, cov_a = _cavities(self.Lam, self.eta, links.a, self.Ja, self.ha)
        mu_b, cov_b = _cavities(self.Lam, self.eta, links.b, self.Jb, self.hb)
        return mu_a, cov_a, mu_b, cov_b

    def iterate(self, A: FloatArray, c: FloatArray, noise: FloatArray, z: FloatArray,
                cavities: tuple[FloatArray, ...] | None = None) -> None:
        """One flooding iteration: every message (eq. 24), then every belief (eq. 9).

        `cavities`: those of the current beliefs, if the caller has them already.
        """
        d = self.Lam0.shape[1]
        mu_a, cov_a, mu_b, cov_b = self.cavities() if cavities is None else cavities
        Aa, Ab = A[..., :d], A[..., d:]
        self.Ja, self.ha = _link_messages(Aa, Ab, mu_b, cov_b, c, noise, z)
        self.Jb, self.hb = _link_messages(Ab, Aa, mu_a, cov_a, c, noise, z)
        self.Lam, self.eta = _accumulate(self.Lam0, self.eta0, self.links.a, self.links.b,
                                         self.Ja, self.ha, self.Jb, self.hb)

    def beliefs(self) -> Gaussians:
        return from_information(symmetrize(self.Lam), self.eta)


def gaussian_bp(prior: Gaussians, links: LinkFactors, A: FloatArray, c: FloatArray,
                noise: FloatArray, iterations: int) -> Gaussians:
    """Gaussian BP on the linear model z = A [x_a; x_b] + c + e, e ~ N(0, noise), per link.

    prior : n Gaussians; A (F, dz, 2dx), c (F, dz), noise (F, dz, dz), measurements `links.z`.
    Exact marginals on a tree after as many iterations as its diameter.
    """
    bp = _BP(prior, links)
    for _ in range(iterations):
        bp.iterate(A, c, noise, links.z)
    return bp.beliefs()


def _link_model(sensor: AngleOfArrival, dx: int):
    """h(y) = [θ_{a←b}, θ_{b←a}] of the joint y = [x_a; x_b] (..., 2dx) → (..., 2)."""

    def h(y: FloatArray) -> FloatArray:
        xa, xb = y[..., :dx], y[..., dx:]
        return np.stack([sensor.bearing(xa, xb), sensor.bearing(xb, xa)], axis=-1)

    return h


def _linearize_reference(cavities: tuple[FloatArray, ...], previous: tuple[FloatArray, ...] | None,
                         z: FloatArray, sensor: AngleOfArrival, method: str = "unscented",
                         central_weight: float = 1.0 / 3.0
                         ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """What `_aoa_joint_slr` computes, with the general NumPy building blocks (for tests).

    eq. (10): joint of (x_a, x_b) ∝ cavity_a · cavity_b · current linearized likelihood
    (`previous` = (A, z̃ − c, R + Ω), a Kalman update in the joint space); then the SLR of
    eqs. (14)–(22) with the branch correction towards the measurement z.
    """
    mu_a, cov_a, mu_b, cov_b = cavities
    F, dx = mu_a.shape
    cov = np.zeros((F, 2 * dx, 2 * dx))
    cov[:, :dx, :dx], cov[:, dx:, dx:] = cov_a, cov_b
    joint = Gaussians(np.concatenate([mu_a, mu_b], axis=1), cov)
    if previous is not None:
        A, y, noise = previous
        joint = kf_update(joint, y, A, noise)
    A, c, Omega = statistical_linear_regression(
        joint.mean, joint.cov, _link_model(sensor, dx), method=method, angular=(True, True),
        reference=z, central_weight=central_weight)
    return A, c, Omega, joint.mean


def plbp_solve(
    prior: Gaussians,
    links: LinkFactors,
    sensor: AngleOfArrival,
    *,
    linearization_iterations: int = 5,
    bp_iterations: int = 3,
    posterior: bool = True,
    method: str = "unscented",
    central_weight: float = 1.0 / 3.0,
) -> tuple[Gaussians, FloatArray]:
    """Algorithm 1 on one snapshot: (posterior beliefs, means after each iteration (J+1, n, dx)).

    posterior : relinearize every iteration w.r.t. the current joint posterior
        approximation (`plbp`); False: linearize once w.r.t. the priors (`prior-lbp`).
    The heading is not wrapped here (see the module docstring).
    """
    n, dx = prior.mean.shape
    iterates = np.empty((linearization_iterations + 1, n, dx))
    iterates[0] = prior.mean
    if len(links) == 0:
        iterates[1:] = prior.mean
        return prior, iterates
    bp = _BP(prior, links)
    missing = ~links.measured
    F = len(links)
    if method not in SIGMA_POINT_METHODS:
        raise ConfigError(f"sigma point method must be one of {SIGMA_POINT_METHODS}, got {method!r}")
    w0 = 0.0 if method == "cubature" else central_weight   # cubature = unscented with w₀ = 0
    index = np.asarray(sensor.state_indices, dtype=np.int64)
    A0 = np.zeros((F, 2, 2 * dx))
    previous = None
    for j in range(linearization_iterations):
        cavities = None
        if j == 0 or posterior:
            cavities = bp.cavities()
            A, c, Omega, joint_mean = _aoa_joint_slr(
                *cavities, *(previous if previous is not None else (A0, A0[..., 0], A0[..., :2])),
                previous is not None, links.z, index, w0)
            A = np.where(missing[..., None], 0.0, A)
            c = np.where(missing, 0.0, c)
            Omega = np.where(missing[:, :, None] | missing[:, None, :], 0.0, Omega)
            noise = symmetrize(links.R + Omega)
            predicted = c + (A @ joint_mean[..., None])[..., 0]
            z = np.where(missing, 0.0, predicted + wrap_angle(links.z - predicted))   # z̃
            previous = (A, z - c, noise)
        for _ in range(bp_iterations):
            bp.iterate(A, c, noise, z, cavities)
            cavities = None
        iterates[j + 1] = bp.beliefs().mean
    out = bp.beliefs()
    # a vehicle in no link keeps its prior exactly (not a round trip through Λ, η)
    isolated = ~np.isin(np.arange(n), np.concatenate([links.a, links.b]))
    mean, cov = out.mean.copy(), out.cov.copy()
    mean[isolated], cov[isolated] = prior.mean[isolated], prior.cov[isolated]
    iterates[:, isolated] = prior.mean[isolated]
    return Gaussians(mean, cov), iterates


def iteration_errors(estimate: Estimate, true_states: FloatArray, layout: StateLayout
                     ) -> tuple[FloatArray, FloatArray]:
    """Position and wrapped heading errors (J+1, n) of `info["iterate_means"]`.

    true_states : (n, dx) in the order of `estimate.vehicles.ids`.
    """
    means = np.asarray(estimate.info["iterate_means"])
    pos = list(layout.position)
    err_pos = np.linalg.norm(means[..., pos] - true_states[None, :, pos], axis=-1)
    if layout.heading is None:
        return err_pos, np.full(err_pos.shape, np.nan)
    err_heading = np.abs(wrap_angle(means[..., layout.heading] - true_states[None, :, layout.heading]))
    return err_pos, err_heading


# ----------------------------------------------------------------------------
# estimators
# ----------------------------------------------------------------------------


@register_estimator
class PLBP:
    """Posterior-linearization Gaussian BP over AoA links, one solve per frame."""

    name: ClassVar[str] = "plbp"
    summary: ClassVar[str] = "AoA cooperative position + heading, posterior-linearization Gaussian BP"
    Params: ClassVar[type[Params]] = PLBPParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "aoa-grid"
    required_sensors: ClassVar[tuple[str, ...]] = ("aoa",)
    posterior: ClassVar[bool] = True

    def __init__(self, setup: Setup, params: PLBPParams, rng: np.random.Generator) -> None:
        sensor = setup.sensors.get("aoa")
        if not isinstance(sensor, AngleOfArrival):
            raise ConfigError(f"{self.name} needs an 'aoa' sensor (AngleOfArrival) in the setup, "
                              f"got {sensor!r}")
        layout = setup.vehicle_layout
        if layout.heading is None:
            raise ConfigError(f"{self.name} needs a vehicle layout with a heading, got {layout}")
        self.setup, self.params, self.sensor = setup, params, sensor
        self.vehicles = VehicleBeliefs(setup)
        motion = setup.vehicle_motion
        self._F = motion.transition_matrix(setup.dt)
        self._Q = None if motion.state_dependent_noise else motion.noise_covariance(setup.dt)
        self._heading = layout.heading
        self._started = False

    def step(self, frame: Frame) -> Estimate:
        born = self.vehicles.sync(frame)
        beliefs = self._predict(self.vehicles.beliefs, ~born)
        self._started = True
        beliefs = self._fix(beliefs, frame.batches.get("gnss"))
        links = link_factors(frame.batch("aoa", 1), self.vehicles.ids)
        p = self.params
        posterior, iterates = plbp_solve(
            beliefs, links, self.sensor, linearization_iterations=p.linearization_iterations,
            bp_iterations=p.bp_iterations, posterior=self.posterior, method=p.sigma_points,
            central_weight=p.central_weight)
        mean = posterior.mean.copy()
        mean[:, self._heading] = wrap_angle(mean[:, self._heading])
        iterates[..., self._heading] = wrap_angle(iterates[..., self._heading])
        self.vehicles.beliefs = Gaussians(mean, posterior.cov)
        info: dict[str, Any] = {"iterate_means": iterates, "n_links": len(links)}
        return Estimate(StateSet(self.vehicles.ids, mean, posterior.cov), info=info)

    def _predict(self, beliefs: Gaussians, moving: np.ndarray) -> Gaussians:
        """Prediction with the motion model of every vehicle that was already there."""
        if not self._started or not moving.any():
            return beliefs
        Q = self._Q if self._Q is not None else self.setup.vehicle_motion.noise_covariance(
            self.setup.dt, beliefs.mean[moving])
        predicted = kf_predict(beliefs.take(moving), self._F, Q)
        mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
        mean[moving], cov[moving] = predicted.mean, predicted.cov
        return Gaussians(mean, cov)

    def _fix(self, beliefs: Gaussians, gnss: Batch | None) -> Gaussians:
        """Information-form update with this step's own fixes (tracking): Λ += Hᵀ R⁻¹ H, η += Hᵀ R⁻¹ z̃."""
        sensor = self.setup.sensors.get("gnss")
        ids = self.vehicles.ids
        if gnss is None or len(gnss) == 0 or sensor is None or ids.size == 0:
            return beliefs
        pos = np.minimum(np.searchsorted(ids, gnss.subject), ids.size - 1)   # ids are sorted
        rows = np.flatnonzero(ids[pos] == gnss.subject)
        if rows.size == 0:
            return beliefs
        target = pos[rows]
        dx = beliefs.mean.shape[1]
        H = sensor.observation_matrix(dx)
        z = gnss.z[rows].copy()
        angular = np.flatnonzero(H[:, self._heading] != 0)          # heading components of the fix
        prediction = beliefs.mean[target] @ H.T
        z[:, angular] = prediction[:, angular] + wrap_angle(z[:, angular] - prediction[:, angular])
        Rinv_H = np.linalg.solve(gnss.cov[rows], np.broadcast_to(H, (rows.size, *H.shape)))
        Rinv_z = np.linalg.solve(gnss.cov[rows], z[..., None])[..., 0]
        Lam, eta = to_information(beliefs)
        n = ids.size
        Lam = symmetrize(Lam + _scatter(target, H.T @ Rinv_H, n))
        eta = eta + _scatter(target, Rinv_z @ H, n)
        return from_information(Lam, eta)


@register_estimator
class PriorLBP(PLBP):
    """The baseline: the same Gaussian BP, linearized once w.r.t. the priors."""

    name: ClassVar[str] = "prior-lbp"
    summary: ClassVar[str] = "AoA cooperative position + heading, Gaussian BP linearized at the priors"
    Params: ClassVar[type[Params]] = PriorLBPParams
    posterior: ClassVar[bool] = False
