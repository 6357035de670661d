r"""The linearized optimal proposal of `sme-pf`: each particle moves by a Kalman update.

A bootstrap particle filter draws x_k from the motion model and weights by the
likelihood; with the 2N + 1 pseudo-measurements of eq. (19) constraining a 4N-dimensional
joint state (N = 5: 20 dimensions) most of those draws miss, and the cloud is thin where
the posterior is (``cooploc reproduce zhang2016`` measures what that costs). This module
builds the proposal of the extended/unscented particle filter instead (Doucet, Godsill
& Andrieu 2000, §II.D; van der Merwe, Doucet, de Freitas & Wan 2000), used by `sme-pf`
as an auxiliary particle filter (Pitt & Shephard 1999): each particle is drawn from the
posterior of a *linearized* model given its parent.

Model
-----
Each particle's prior kernel is N(x; μ_j, Σ₀) — μ_j = A x_{k−1}^j with Σ₀ = blockdiag(Q)
(eq. 16) for vehicles that continue, the entry belief for vehicles that enter. The
pseudo-measurement y (eq. 19) is linearized once per step by statistical linear
regression (SLR) about the Gaussian moment-matched to the predicted cloud,
N(m, P) with m = Σ w_j μ_j, P = Σ w_j (μ_j − m)(μ_j − m)ᵀ + Σ₀:

.. math:: y ≈ H x + c + e, \quad e ∼ N(0, Λ), \quad Λ = Ω_{SLR} + E[R(x)],

where Ω_SLR is the SLR's linearization error over the whole cloud and E[R(x)] the
pseudo-measurement noise averaged over the sigma points (`PseudoMeasurement.predict`).
With ``iterations`` > 1 the SLR is repeated about the Gaussian posterior of the previous
linearization (posterior linearization, García-Fernández et al. 2015). Under that model
each parent's posterior is Gaussian with a shared gain:

.. math:: S = H Σ₀ Hᵀ + Λ, \quad K = Σ₀ Hᵀ S^{-1}, \quad
          μ_j^+ = μ_j + K (y − H μ_j − c), \quad Σ^+ = (I − K H) Σ₀ (I − K H)ᵀ + K Λ Kᵀ,

and N(x; μ_j, Σ₀) N(y; H x + c, Λ) = λ_j N(x; μ_j^+, Σ^+) with λ_j = N(y; H μ_j + c, S)
for every x. The auxiliary filter draws parent j with probability ∝ w_j λ_j, then
x ~ N(μ_j^+, Σ^+), and weights by the *exact* pseudo-likelihood over the linearized one,

.. math:: w ∝ p(y | x) \, N(x; μ_j, Σ₀) / (λ_j N(x; μ_j^+, Σ^+)) = p(y | x) / N(y; H x + c, Λ),

so the linearization only shapes the proposal, never the target. Where the model is
linear (the GPS sums of powers of well separated vehicles, locally) the weights are
equal; Ω_SLR widens the proposal where it is not, which keeps the weights' tails bounded.

Complexity per step: O(d³ + d² D) for the SLR and the gain (d = N dx, D = 2N + 1, one
pass of the 2d + 1 sigma points per iteration), O(P d²) to draw, O(P D²) for the
linearized likelihoods.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cooploc.estimators.sme.pseudo_measurement import PseudoMeasurement
from cooploc.gaussian import sigma_points, statistical_linear_regression, symmetrize
from cooploc.particles import log_sum_exp
from cooploc.types import FloatArray

__all__ = ["LinearizedProposal", "linearized_proposal"]


@dataclass(frozen=True)
class LinearizedProposal:
    """Per-particle Gaussian proposals N(mean_i, L Lᵀ) with a shared covariance.

    mean : (P, N, dx) proposal means μ_i^+.
    chol : (d, d) lower Cholesky factor L of the shared proposal covariance Σ^+ (d = N dx).
    log_predictive : (P,) log N(y; H μ_i + c, S), each parent's predictive likelihood
        under the linearized model (the auxiliary particle filter's first-stage weight).
    y, H, c, Lam_chol : the measured pseudo-measurement (D,) and the linearized model
        y ≈ H x + c + e, e ~ N(0, Λ): H (D, d), c (D,), the lower Cholesky factor of Λ (D, D).
    """

    mean: FloatArray
    chol: FloatArray
    log_predictive: FloatArray
    y: FloatArray
    H: FloatArray
    c: FloatArray
    Lam_chol: FloatArray

    def linearized_log_likelihood(self, x: FloatArray) -> FloatArray:
        """log N(y; H x + c, Λ) for particles x (P, N, dx) → (P,)."""
        r = self.y - self.c - x.reshape(x.shape[0], -1) @ self.H.T
        return _shared_logpdf(r, self.Lam_chol)

    def draw(self, centres: FloatArray, rng: np.random.Generator) -> FloatArray:
        """One draw x ~ N(centre, L Lᵀ) per row of centres (P, N, dx) (proposal means)."""
        white = rng.standard_normal((centres.shape[0], self.chol.shape[0]))
        return centres + (white @ self.chol.T).reshape(centres.shape)


def _shared_logpdf(residual: FloatArray, L: FloatArray) -> FloatArray:
    """log N(r_i; 0, L Lᵀ) for residuals (P, D) sharing one covariance, given its lower factor L."""
    white = np.linalg.solve(L, residual.T)                                   # L⁻¹ r_i, (D, P)
    log_det = 2.0 * np.log(np.diagonal(L)).sum()
    return -0.5 * (residual.shape[1] * np.log(2.0 * np.pi) + log_det + (white**2).sum(0))


def _linearize(model: PseudoMeasurement, mean: FloatArray, cov: FloatArray,
               positions: Callable[[FloatArray], FloatArray]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """SLR y ≈ H x + c + e, e ~ N(0, Λ) over N(mean, cov): Λ = Ω_SLR + E[R(x)]."""
    # SLR of the conditional mean E[y | x] (bias included)
    H, c, Omega = statistical_linear_regression(
        mean[None], cov[None], lambda chi: model.predict(positions(chi[0]))[1][None])
    chi, weights = sigma_points(mean[None], cov[None])
    R_mean = np.einsum("s,sij->ij", weights, model.predict(positions(chi[0]))[2])    # E[R(x)]
    return H[0], c[0], symmetrize(Omega[0] + R_mean)


def linearized_proposal(prior_mean: FloatArray, prior_cov: FloatArray, log_w: FloatArray,
                        model: PseudoMeasurement, position: list[int], iterations: int = 1
                        ) -> LinearizedProposal:
    """The proposal of the module docstring for particles with prior kernels N(μ_i, Σ₀).

    Parameters
    ----------
    prior_mean : (P, N, dx) μ_i, each particle's prior mean.
    prior_cov : (N, dx, dx) the blocks of Σ₀, shared by all particles.
    log_w : (P,) log-weights (need not be normalised) the predicted cloud is summarised with.
    model : the step's pseudo-measurement (eq. 19), at least one part measured.
    position : the position components of a vehicle block.
    iterations : SLRs, each about the previous one's Gaussian posterior (1: about the prior).

    Raises
    ------
    numpy.linalg.LinAlgError
        where a covariance of the linearized model is not positive definite (the caller
        falls back to another proposal).
    """
    P, N, dx = prior_mean.shape
    d = N * dx
    w = np.exp(log_w - log_sum_exp(log_w, axis=None))
    mu = prior_mean.reshape(P, d)
    Sigma0 = np.zeros((d, d))
    for n in range(N):   # blockdiag(Σ₀); N is small
        Sigma0[n * dx:(n + 1) * dx, n * dx:(n + 1) * dx] = prior_cov[n]
    m = w @ mu
    centred = mu - m
    Pcov = symmetrize((centred * w[:, None]).T @ centred + Sigma0)

    def positions(chi: FloatArray) -> FloatArray:
        return chi.reshape(-1, N, dx)[:, :, position]

    y = model.predict(positions(m[None]))[0]
    H, c, Lam = _linearize(model, m, Pcov, positions)
    for _ in range(iterations - 1):
        # posterior linearization: relinearize about the joint posterior of this linearization
        S_joint = symmetrize(H @ Pcov @ H.T + Lam)
        K_joint = np.linalg.solve(S_joint, H @ Pcov).T
        I_KH = np.eye(d) - K_joint @ H
        m_post = m + K_joint @ (y - H @ m - c)
        P_post = symmetrize(I_KH @ Pcov @ I_KH.T + K_joint @ Lam @ K_joint.T)
        H, c, Lam = _linearize(model, m_post, P_post, positions)
    S = symmetrize(H @ Sigma0 @ H.T + Lam)                                  # S = H Σ₀ Hᵀ + Λ
    K = np.linalg.solve(S, H @ Sigma0).T                                    # K = Σ₀ Hᵀ S⁻¹
    innovation = y - c - mu @ H.T                                           # y − H μ_i − c
    mean = (mu + innovation @ K.T).reshape(P, N, dx)
    I_KH = np.eye(d) - K @ H
    cov = symmetrize(I_KH @ Sigma0 @ I_KH.T + K @ Lam @ K.T)                # Joseph form
    log_predictive = _shared_logpdf(innovation, np.linalg.cholesky(S))      # log N(y; H μ_i + c, S)
    return LinearizedProposal(mean, np.linalg.cholesky(cov), log_predictive, y, H, c,
                              np.linalg.cholesky(Lam))
