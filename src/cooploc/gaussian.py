"""Batched Gaussian building blocks: Kalman predict/update and the information form.

All functions are pure and vectorised over a leading batch dimension n (vehicles,
features, hypotheses): means are (n, dx), covariances (n, dx, dx).

Kalman filter (e.g. Bar-Shalom, Li & Kirubarajan 2001, §5.2):

    predict:  m⁻ = F m + B u,            P⁻ = F P Fᵀ + Q
    update:   S  = H P⁻ Hᵀ + R,          K  = P⁻ Hᵀ S⁻¹
              m  = m⁻ + K (z − H m⁻),    P  = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ   (Joseph)

The Joseph form keeps P symmetric positive semi-definite under round-off, which the
short form (I − K H) P⁻ does not guarantee; gains come from `solve`, never an inverse.

Information form: Λ = P⁻¹, η = P⁻¹ m. A measurement z = H x + w, w ~ N(0, R) adds
Hᵀ R⁻¹ H to Λ and Hᵀ R⁻¹ z to η — the product of Gaussian messages is a sum, which is
why Gaussian belief propagation works in this form.

Complexity: O(n (dx³ + dz³)) per call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.types import FloatArray

__all__ = [
    "Gaussians",
    "block_diagonal",
    "from_information",
    "gaussian_logpdf",
    "information_update",
    "kf_predict",
    "kf_update",
    "symmetrize",
    "to_information",
]

_LOG_2PI = np.log(2.0 * np.pi)


@dataclass(frozen=True, slots=True)
class Gaussians:
    """A batch of Gaussian beliefs: mean (n, dx), cov (n, dx, dx)."""

    mean: FloatArray
    cov: FloatArray

    def __len__(self) -> int:
        return self.mean.shape[0]

    def take(self, rows: np.ndarray) -> Gaussians:
        return Gaussians(self.mean[rows], self.cov[rows])


def block_diagonal(*stacks: FloatArray) -> FloatArray:
    """Block-diagonal matrix of stacks of equal blocks, (n_i, d_i, d_i) each, in order.

    Vectorised per stack (no Python loop over blocks), unlike `scipy.linalg.block_diag`.
    """
    sizes = [s.shape[0] * s.shape[1] for s in stacks]
    out = np.zeros((sum(sizes), sum(sizes)))
    start = 0
    for stack, size in zip(stacks, sizes, strict=True):
        n, d = stack.shape[0], stack.shape[1]
        if n:
            view = out[start:start + size, start:start + size].reshape(n, d, n, d)
            view[np.arange(n), :, np.arange(n), :] = stack  # the n diagonal blocks
        start += size
    return out


def symmetrize(cov: FloatArray) -> FloatArray:
    """(P + Pᵀ)/2 over the last two axes."""
    return 0.5 * (cov + np.swapaxes(cov, -1, -2))


def kf_predict(
    prior: Gaussians,
    F: FloatArray,
    Q: FloatArray,
    B: FloatArray | None = None,
    u: FloatArray | None = None,
) -> Gaussians:
    """Kalman prediction of every belief: F (dx, dx) or (n, dx, dx); Q likewise; u (n, du)."""
    mean = np.einsum("...ij,...j->...i", F, prior.mean)           # m⁻ = F m
    if B is not None and u is not None:
        mean = mean + u @ B.T                                     # + B u
    cov = F @ prior.cov @ np.swapaxes(F, -1, -2) + Q              # P⁻ = F P Fᵀ + Q
    return Gaussians(mean, symmetrize(cov))


def kf_update(prior: Gaussians, z: FloatArray, H: FloatArray, R: FloatArray) -> Gaussians:
    """Joseph-form Kalman update of every belief.

    Parameters
    ----------
    prior : n beliefs (n, dx), (n, dx, dx).
    z : (n, dz) one measurement per belief.
    H : (dz, dx) or (n, dz, dx).
    R : (dz, dz) or (n, dz, dz).
    """
    P = prior.cov
    Ht = np.swapaxes(H, -1, -2)
    PHt = P @ Ht
    S = symmetrize(H @ PHt + R)                                   # S = H P Hᵀ + R
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)  # K = P Hᵀ S⁻¹
    innovation = z - np.einsum("...ij,...j->...i", H, prior.mean)
    mean = prior.mean + np.einsum("...ij,...j->...i", K, innovation)
    I_KH = np.eye(P.shape[-1]) - K @ H
    # P = (I − K H) P (I − K H)ᵀ + K R Kᵀ   (Joseph form)
    cov = I_KH @ P @ np.swapaxes(I_KH, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
    return Gaussians(mean, symmetrize(cov))


def to_information(belief: Gaussians) -> tuple[FloatArray, FloatArray]:
    """(Λ, η) = (P⁻¹, P⁻¹ m) via Cholesky solves."""
    L = np.linalg.cholesky(belief.cov)
    eye = np.broadcast_to(np.eye(belief.cov.shape[-1]), belief.cov.shape)
    Linv = np.linalg.solve(L, eye)
    Lam = np.swapaxes(Linv, -1, -2) @ Linv
    eta = np.einsum("...ij,...j->...i", Lam, belief.mean)
    return symmetrize(Lam), eta


def from_information(Lam: FloatArray, eta: FloatArray) -> Gaussians:
    """(m, P) = (Λ⁻¹ η, Λ⁻¹) via Cholesky solves; Λ must be positive definite."""
    L = np.linalg.cholesky(Lam)
    eye = np.broadcast_to(np.eye(Lam.shape[-1]), Lam.shape)
    Linv = np.linalg.solve(L, eye)
    cov = symmetrize(np.swapaxes(Linv, -1, -2) @ Linv)
    return Gaussians(np.einsum("...ij,...j->...i", cov, eta), cov)


def information_update(
    Lam: FloatArray, eta: FloatArray, z: FloatArray, H: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Add the measurement z = H x + w, w ~ N(0, R): Λ += Hᵀ R⁻¹ H, η += Hᵀ R⁻¹ z."""
    Ht = np.swapaxes(H, -1, -2)
    Rinv_H = np.linalg.solve(R, H)
    Rinv_z = np.linalg.solve(R, z[..., None])[..., 0]
    return symmetrize(Lam + Ht @ Rinv_H), eta + np.einsum("...ij,...j->...i", Ht, Rinv_z)


def gaussian_logpdf(residual: FloatArray, cov: FloatArray) -> FloatArray:
    """log N(r; 0, C) for residuals (..., d) and covariances (..., d, d), broadcast."""
    residual, cov = np.broadcast_arrays(residual[..., None], cov)
    residual = residual[..., 0]
    L = np.linalg.cholesky(cov)
    white = np.linalg.solve(L, residual[..., None])[..., 0]       # L⁻¹ r
    log_det = 2.0 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(-1)
    d = residual.shape[-1]
    return -0.5 * (d * _LOG_2PI + log_det + (white**2).sum(-1))
