"""Numba kernels of `plbp`: small dense linear algebra, one link per loop iteration.

Compiled on first use: `cooploc.estimators.plbp` imports this module inside the
functions that call it, so that importing the package does not import numba.
Batched NumPy LAPACK calls on 3×3 and 2×2 matrices cost more in per-matrix overhead
than in arithmetic; these loops do the same arithmetic without it (`benchmarks/plbp.py`
times them).

- `cavities` — moments of the cavities, belief ÷ the link's own message;
- `link_messages` — the Gaussian BP message of eq. (24) of every link;
- `accumulate` — the beliefs of eq. (9) in information form;
- `aoa_joint_slr` — the joint posterior approximation of eq. (10) and the unscented SLR
  of eqs. (14)–(22) of both bearings of a link, fused (`plbp.linearization` has the
  NumPy reference it is tested against);
- `cholesky`, `cho_solve` — the factorisation they share.

Every function costs O(F) small-matrix operations for F links (O(F (2dx)³) for the SLR).
"""

from __future__ import annotations

import numba
import numpy as np

from cooploc.types import FloatArray, IntArray

__all__ = ["accumulate", "aoa_joint_slr", "cavities", "cho_solve", "cholesky", "link_messages"]


@numba.njit(cache=True)
def cholesky(M: FloatArray, L: FloatArray) -> None:  # pragma: no cover - compiled
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
def cho_solve(L: FloatArray, X: FloatArray) -> None:  # pragma: no cover - compiled
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
def cavities(Lam: FloatArray, eta: FloatArray, index: IntArray, J: FloatArray, h: FloatArray
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
        cholesky(C, L)
        cho_solve(L, S)                                     # Σ_{i∖f} = (Λ_i − J_{f→i})⁻¹
        for r in range(d):
            acc = 0.0
            for q in range(d):
                cov[f, r, q] = 0.5 * (S[r, q] + S[q, r])
                acc += S[r, q] * (eta[i, q] - h[f, q])       # μ_{i∖f} = Σ (η_i − h_{f→i})
            mu[f, r] = acc
    return mu, cov


@numba.njit(cache=True)
def link_messages(A_to: FloatArray, A_from: FloatArray, mu: FloatArray, cov: FloatArray,
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
        cholesky(S, L)
        cho_solve(L, X)                                     # S⁻¹ [A_i | innovation]
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
def accumulate(Lam0: FloatArray, eta0: FloatArray, a: IntArray, b: IntArray, Ja: FloatArray,
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
def aoa_joint_slr(mu_a: FloatArray, cov_a: FloatArray, mu_b: FloatArray, cov_b: FloatArray,
                  A_prev: FloatArray, y_prev: FloatArray, noise_prev: FloatArray, update: bool,
                  z: FloatArray, index: IntArray, central_weight: float
                  ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover
    """Joint posterior approximation and SLR of the two bearings of every link (fused).

    Per link: the joint N(m, P) of [x_a; x_b] is the product of the cavities, Kalman-updated
    (Joseph form) with the previous linearization y = A x + e, e ~ N(0, noise) when
    `update` (eq. 10); then the unscented SLR (eqs. 14–22) of h = [θ_{a←b}, θ_{b←a}] with the
    branch correction of eq. (15) towards the measurement z. The same numbers as
    `linearization._linearize_reference` (NumPy, via `gaussian.statistical_linear_regression`), at a
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
            cholesky(Sm, Ls)
            for r in range(D):                               # K = (S⁻¹ (P Hᵀ)ᵀ)ᵀ, S symmetric
                K[r, 0], K[r, 1] = PH[r, 0], PH[r, 1]
            Kt = np.ascontiguousarray(K.T)
            cho_solve(Ls, Kt)
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
        cholesky(P, L)
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
        cho_solve(L, X)                                     # P⁻¹ Ψ = Aᵀ
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

