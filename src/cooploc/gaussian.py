"""Batched Gaussian building blocks: Kalman predict/update and the information form.

All functions are pure and vectorised over a leading batch dimension n (vehicles,
features, hypotheses): means are (n, dx), covariances (n, dx, dx).

Kalman filter (e.g. Bar-Shalom, Li & Kirubarajan 2001, §5.2):

    predict:  m⁻ = F m + B u,            P⁻ = F P Fᵀ + Q
    update:   S  = H P⁻ Hᵀ + R,          K  = P⁻ Hᵀ S⁻¹
              m  = m⁻ + K (z − H m⁻),    P  = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ   (Joseph)

The Joseph form keeps P symmetric positive semi-definite under round-off, which the
short form (I − K H) P⁻ does not guarantee; gains come from `solve`, never an inverse.
It still fails when P⁻ and R differ by more than float64 can hold (P⁻ ≫ R: the
posterior is a small difference of huge numbers; R below the round-off of H P⁻ Hᵀ: S
is singular). `kf_update` then falls back to the square-root (array) form
`kf_update_square_root` (Kaminski, Bryson & Schmidt 1971; Grewal & Andrews §7.5): with
factors P⁻ = Sₚ Sₚᵀ (Cholesky's, or from the eigendecomposition where round-off left P⁻
only semi-definite: `_square_root`), R = Sᵣ Sᵣᵀ, the QR factorisation of the pre-array
[[Sᵣ, H Sₚ], [0, Sₚ]] gives the lower-triangular post-array [[S^½, 0], [K̄, P^½]] with
K = K̄ S^−½ — it never forms S or subtracts, so P stays positive definite. The fallback
runs only when the Joseph form fails, so well-conditioned updates are bit-for-bit the
Joseph ones.

Consistency: the normalised innovation squared NIS = νᵀ S⁻¹ ν of the innovation
ν = z − H m⁻ is χ²(dz) distributed for a consistent filter, and white over time (Bar-Shalom,
Li & Kirubarajan 2001, §5.4). `kf_update_nis` returns it beside the update (from the
Joseph form's ν and S, or as |S^−½ ν|² from the square-root form), computed only there:
`kf_update` costs nothing more for it, and the estimate is the same bit for bit.

Rows relating two states (odometry, z = H x_k − H x_{k−1} + w; Gulati 2017 eq. 20) are
fused exactly by stochastic cloning (Roumeliotis & Burdick 2002), `kf_update_relative`:
the predicted joint of [x_k; x_{k−1}] has mean [F m; m] and covariance
[[F P Fᵀ + Q, F P], [P Fᵀ, P]]; it is updated with H_aug = [H, −H] and x_{k−1} is
marginalised out. Its predictive log-likelihood log N(z; H_aug m_aug, S) weighs mixture
components (`gm-phd`).

Information form: Λ = P⁻¹, η = P⁻¹ m. A measurement z = H x + w, w ~ N(0, R) adds
Hᵀ R⁻¹ H to Λ and Hᵀ R⁻¹ z to η — the product of Gaussian messages is a sum, which is
why Gaussian belief propagation works in this form.

Statistical linear regression (García-Fernández et al., IEEE TSP 2015, the posterior
linearization filter): the best affine fit z ≈ A x + c + e, e ~ N(0, Ω), of a
nonlinear h(x) under x ~ N(x̄, P), computed with sigma points χ⁽ˢ⁾ and weights w⁽ˢ⁾:

    z̄ = Σ w ζ,  Ψ = Σ w (χ − x̄)(ζ − z̄)ᵀ,  Φ = Σ w (ζ − z̄)(ζ − z̄)ᵀ,   ζ = h(χ)
    A = Ψᵀ P⁻¹,  c = z̄ − A x̄,  Ω = Φ − A P Aᵀ

(eqs. 16–22 of 002_dfdb230c2e4252cd.txt, Appendix A). Angular outputs are first put
on the branch nearest a reference angle z (eq. 15): ζ̃ = z + mod(ζ − z + π, 2π) − π,
so that the regression never straddles the ±π cut (Crouse 2015). Sigma points:
`"unscented"` (central weight w₀, default 1/3, spread sqrt(d / (1 − w₀))) or
`"cubature"` (2d points ± sqrt(d) columns of a Cholesky factor, equal weights). Both
integrate polynomials of degree 3 exactly, so an affine h is recovered with Ω = 0.

Small-matrix solves. `to_information`, `from_information`, `gaussian_logpdf` and
`spd_solve` factor each matrix of a stack by Cholesky in compiled loops
(`cooploc._gaussian_kernels`, numba, imported on first use) rather than one LAPACK call
per matrix, whose overhead dominated on stacks of 2 × 2 and 4 × 4 matrices (≈ 1 µs
per matrix against ≈ 0.1 µs). Same formulas; results equal those of `np.linalg` to
round-off (κ ε relative; tests/test_gaussian_kernels.py), Λ and P exactly symmetric; a
matrix that is not positive definite raises `LinAlgError` as `np.linalg.cholesky` does,
and NaN propagates as there.

Complexity: O(n (dx³ + dz³)) per call; SLR O(n (S d dz + d³)) with S = 2d (+1) points.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from cooploc.errors import InvalidInputError
from cooploc.types import FloatArray

__all__ = [
    "SIGMA_POINT_METHODS",
    "Gaussians",
    "block_diagonal",
    "from_information",
    "gaussian_logpdf",
    "information_update",
    "kf_predict",
    "kf_update",
    "kf_update_nis",
    "kf_update_relative",
    "kf_update_square_root",
    "nis",
    "sigma_points",
    "spd_inverse_and_product",
    "spd_solve",
    "statistical_linear_regression",
    "symmetrize",
    "to_information",
]

_LOG_2PI = np.log(2.0 * np.pi)
SIGMA_POINT_METHODS = ("unscented", "cubature")


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
    """Joseph-form Kalman update of every belief (square-root form where it fails).

    Parameters
    ----------
    prior : n beliefs (n, dx), (n, dx, dx).
    z : (n, dz) one measurement per belief.
    H : (dz, dx) or (n, dz, dx).
    R : (dz, dz) or (n, dz, dz).
    """
    return _kf_update(prior, z, H, R)[0]


def kf_update_nis(prior: Gaussians, z: FloatArray, H: FloatArray, R: FloatArray
                  ) -> tuple[Gaussians, FloatArray]:
    """`kf_update` (the same posterior, bit for bit) and the NIS νᵀ S⁻¹ ν of each belief (n,).

    Each NIS has dz degrees of freedom: χ²(dz) for a consistent filter.
    """
    post, nis_of = _kf_update(prior, z, H, R)
    return post, nis_of()


def kf_update_relative(previous: Gaussians, predicted: Gaussians, F: FloatArray, z: FloatArray,
                       H: FloatArray, R: FloatArray) -> tuple[Gaussians, FloatArray, FloatArray]:
    """Update with rows z = H x_k − H x_{k−1} + w by stochastic cloning (module docstring).

    previous : the beliefs of x_{k−1} (n, dx); predicted : of x_k, F·previous plus noise
    (n, dx); F : (dx, dx); z : (n, dz); H : (dz, dx); R : (n, dz, dz). Returns the
    posterior of x_k (Joseph form, as `kf_update`), each row's NIS (n,) and its predictive
    log-likelihood log N(z; H m_k − H m_{k−1}, S) (n,).
    """
    FP = F @ previous.cov                                                 # Cov(x_k, x_{k−1})
    joint = Gaussians(np.concatenate([predicted.mean, previous.mean], axis=-1),
                      np.block([[predicted.cov, FP], [np.swapaxes(FP, -1, -2), previous.cov]]))
    H_aug = np.concatenate([H, -H], axis=-1)                              # z = H x_k − H x_{k−1}
    posterior, nis_of = kf_update_nis(joint, z, H_aug, R)
    S = symmetrize(H_aug @ joint.cov @ H_aug.T + R)
    log_likelihood = -0.5 * (z.shape[-1] * _LOG_2PI + np.linalg.slogdet(S)[1] + nis_of)
    dx = predicted.mean.shape[-1]
    return Gaussians(posterior.mean[:, :dx], posterior.cov[:, :dx, :dx]), nis_of, log_likelihood


def squared_mahalanobis(residual: FloatArray, cov: FloatArray) -> FloatArray:
    """rᵀ P⁻¹ r of residuals (..., d) and covariances (..., d, d), by a solve (no inverse)."""
    return np.einsum("...i,...i->...", residual, np.linalg.solve(cov, residual[..., None])[..., 0])


def nis(innovation: FloatArray, S: FloatArray) -> FloatArray:
    """Normalised innovation squared νᵀ S⁻¹ ν of innovations (..., dz), covariances (..., dz, dz)."""
    return squared_mahalanobis(innovation, S)


def _kf_update(prior: Gaussians, z: FloatArray, H: FloatArray, R: FloatArray
               ) -> tuple[Gaussians, Callable[[], FloatArray]]:
    """The update of `kf_update` and a function computing its NIS (only if called)."""
    try:
        post, innovation, S = _kf_update_joseph(prior, z, H, R)
    except np.linalg.LinAlgError:
        return _kf_update_square_root(prior, z, H, R)
    if not _is_positive_definite(post.cov):  # P⁻ and R too far apart for the Joseph form
        try:
            return _kf_update_square_root(prior, z, H, R)
        except np.linalg.LinAlgError:  # S singular or R not definite: the Joseph result stands
            pass
    return post, lambda: nis(innovation, S)


def _kf_update_joseph(prior: Gaussians, z: FloatArray, H: FloatArray, R: FloatArray
                      ) -> tuple[Gaussians, FloatArray, FloatArray]:
    """The Joseph-form posterior, the innovation ν and its covariance S."""
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
    return Gaussians(mean, symmetrize(cov)), innovation, S


def _is_positive_definite(cov: FloatArray) -> bool:
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return False
    return bool(np.isfinite(cov).all())


def _square_root(P: FloatArray) -> FloatArray:
    """A factor S with S Sᵀ = P for each covariance: Cholesky's, or where float64 cannot
    factor P (semi-definite in round-off: entries 10²⁵ beside 10⁻² after a prediction),
    V diag(√max(λ, 0)) from its eigendecomposition. The array form needs only some S
    with S Sᵀ = P, not a triangular one, and the eigenvalues that round-off pushed below
    zero carry no information: clipping them is the nearest semi-definite P (Higham 1988)."""
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        lam, V = np.linalg.eigh(symmetrize(P))
        return V * np.sqrt(np.maximum(lam, 0.0))[..., None, :]


def kf_update_square_root(prior: Gaussians, z: FloatArray, H: FloatArray, R: FloatArray) -> Gaussians:
    """The Kalman update of `kf_update` in square-root (array) form (module docstring).

    Same arguments; needs R positive definite and P⁻ semi-definite (a P⁻ that float64
    cannot factor by Cholesky is factored by `_square_root`). Raises `LinAlgError` where S is
    singular even so (a zero on the diagonal of S^½).
    """
    return _kf_update_square_root(prior, z, H, R)[0]


def _kf_update_square_root(prior: Gaussians, z: FloatArray, H: FloatArray, R: FloatArray
                           ) -> tuple[Gaussians, Callable[[], FloatArray]]:
    """`kf_update_square_root` and a function giving its NIS |S^−½ ν|²."""
    P = prior.cov
    n_x, n_z = P.shape[-1], np.shape(z)[-1]
    S_p = _square_root(P)                                              # P⁻ = Sₚ Sₚᵀ
    S_r = np.broadcast_to(np.linalg.cholesky(R), (*P.shape[:-2], n_z, n_z))
    H = np.broadcast_to(H, (*P.shape[:-2], n_z, n_x))
    pre = np.zeros((*P.shape[:-2], n_z + n_x, n_z + n_x))
    pre[..., :n_z, :n_z] = S_r
    pre[..., :n_z, n_z:] = H @ S_p
    pre[..., n_z:, n_z:] = S_p
    # pre = L Qᵀ with L lower triangular: the QR factorisation of preᵀ; L Lᵀ = pre preᵀ
    post = np.swapaxes(np.linalg.qr(np.swapaxes(pre, -1, -2), mode="r"), -1, -2)
    S_half, K_bar, P_half = post[..., :n_z, :n_z], post[..., n_z:, :n_z], post[..., n_z:, n_z:]
    if not (np.abs(np.diagonal(S_half, axis1=-2, axis2=-1)) > 0).all():
        raise np.linalg.LinAlgError("the innovation covariance is singular")
    innovation = z - np.einsum("...ij,...j->...i", H, prior.mean)
    white = np.linalg.solve(S_half, innovation[..., None])[..., 0]     # S^−½ (z − H m⁻)
    mean = prior.mean + np.einsum("...ij,...j->...i", K_bar, white)    # m = m⁻ + K̄ S^−½ ν
    posterior = Gaussians(mean, symmetrize(P_half @ np.swapaxes(P_half, -1, -2)))
    return posterior, lambda: (white**2).sum(-1)                            # νᵀ S⁻¹ ν = |S^−½ ν|²


def _flat(a: FloatArray, tail: int, shape: tuple[int, ...] | None = None) -> FloatArray:
    """`a` (broadcast to `shape` if given) as a C-contiguous float64 stack: its last `tail`
    axes behind one batch axis. A broadcast is copied (compiled code gets no read-only
    views)."""
    a = np.asarray(a, dtype=np.float64)
    if shape is not None and a.shape != shape:
        a = np.array(np.broadcast_to(a, shape))
    return np.ascontiguousarray(a).reshape(-1, *a.shape[a.ndim - tail:])


def _require_positive_definite(ok: np.ndarray) -> None:
    if not ok.all():  # as np.linalg.cholesky does
        raise np.linalg.LinAlgError("Matrix is not positive definite")


def spd_inverse_and_product(A: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(A⁻¹, A⁻¹ v) of positive definite A (..., d, d) and vectors v (..., d), by Cholesky
    (compiled, `cooploc._gaussian_kernels`); A⁻¹ is exactly symmetric, A⁻¹ v is the
    matrix A⁻¹ times v. Raises `LinAlgError` if an A is not positive definite."""
    from cooploc._gaussian_kernels import inverse_and_product  # numba, on use

    A, v = np.asarray(A), np.asarray(v)
    inv, prod, ok = inverse_and_product(_flat(A, 2), _flat(v, 1, A.shape[:-1]))
    _require_positive_definite(ok)
    return inv.reshape(A.shape), prod.reshape(A.shape[:-1])


def spd_solve(A: FloatArray, b: FloatArray) -> FloatArray:
    """A⁻¹ b for positive definite A (..., d, d) and b (..., d), by Cholesky (compiled);
    raises `LinAlgError` if an A is not positive definite."""
    from cooploc._gaussian_kernels import solve_stack  # numba, on use

    A, b = np.asarray(A), np.asarray(b)
    x, ok = solve_stack(_flat(A, 2), _flat(b, 1, A.shape[:-1]))
    _require_positive_definite(ok)
    return x.reshape(A.shape[:-1])


def to_information(belief: Gaussians) -> tuple[FloatArray, FloatArray]:
    """(Λ, η) = (P⁻¹, P⁻¹ m) via Cholesky: Λ = L⁻ᵀ L⁻¹ for P = L Lᵀ, exactly symmetric."""
    return spd_inverse_and_product(belief.cov, belief.mean)


def from_information(Lam: FloatArray, eta: FloatArray) -> Gaussians:
    """(m, P) = (Λ⁻¹ η, Λ⁻¹) via Cholesky (P exactly symmetric); Λ must be positive definite."""
    cov, mean = spd_inverse_and_product(Lam, eta)
    return Gaussians(mean, cov)


def information_update(
    Lam: FloatArray, eta: FloatArray, z: FloatArray, H: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Add the measurement z = H x + w, w ~ N(0, R): Λ += Hᵀ R⁻¹ H, η += Hᵀ R⁻¹ z."""
    Ht = np.swapaxes(H, -1, -2)
    Rinv_H = np.linalg.solve(R, H)
    Rinv_z = np.linalg.solve(R, z[..., None])[..., 0]
    return symmetrize(Lam + Ht @ Rinv_H), eta + np.einsum("...ij,...j->...i", Ht, Rinv_z)


def gaussian_logpdf(residual: FloatArray, cov: FloatArray) -> FloatArray:
    """log N(r; 0, C) for residuals (..., d) and covariances (..., d, d), broadcast:
    −½ (d log 2π + 2 Σ log L_jj + |L⁻¹ r|²) with C = L Lᵀ (compiled Cholesky)."""
    from cooploc._gaussian_kernels import logpdf_stack  # numba, on use

    residual, cov = np.asarray(residual), np.asarray(cov)
    batch = np.broadcast_shapes(residual.shape[:-1], cov.shape[:-2])
    d = cov.shape[-1]
    out, ok = logpdf_stack(_flat(residual, 1, (*batch, d)), _flat(cov, 2, (*batch, d, d)))
    _require_positive_definite(ok)
    return out.reshape(batch)


def sigma_points(mean: FloatArray, cov: FloatArray, method: str = "unscented",
                 central_weight: float = 1.0 / 3.0) -> tuple[FloatArray, FloatArray]:
    """Sigma points of a batch of Gaussians: points (n, S, d) and weights (S,).

    `"unscented"`: χ⁰ = x̄ with weight w₀ = `central_weight`, χ^{±k} = x̄ ± sqrt(d/(1−w₀)) L_k
    with weights (1 − w₀)/(2d) (Julier & Uhlmann 2004); `"cubature"`: χ^{±k} = x̄ ± sqrt(d) L_k,
    weights 1/(2d) (Arasaratnam & Haykin 2009). L is the lower Cholesky factor of P, L_k
    its k-th column. All weights are positive, so the weighted covariances are PSD.
    """
    if method not in SIGMA_POINT_METHODS:
        raise InvalidInputError(f"sigma point method must be one of {SIGMA_POINT_METHODS}, got {method!r}")
    d = mean.shape[-1]
    L = np.linalg.cholesky(cov)                                    # (n, d, d)
    columns = np.swapaxes(L, -1, -2)                               # (n, d, d): row k = L_k
    if method == "cubature":
        spread, weights = np.sqrt(d), np.full(2 * d, 1.0 / (2 * d))
        offsets = np.concatenate([columns, -columns], axis=-2)
    else:
        if not 0.0 <= central_weight < 1.0:
            raise InvalidInputError(f"central_weight must lie in [0, 1), got {central_weight!r}")
        spread = np.sqrt(d / (1.0 - central_weight))
        weights = np.r_[central_weight, np.full(2 * d, (1.0 - central_weight) / (2 * d))]
        offsets = np.concatenate([np.zeros_like(columns[..., :1, :]), columns, -columns], axis=-2)
    return mean[..., None, :] + spread * offsets, weights


def statistical_linear_regression(
    mean: FloatArray,
    cov: FloatArray,
    h: Callable[[FloatArray], FloatArray],
    *,
    method: str = "unscented",
    angular: Sequence[bool] | None = None,
    reference: FloatArray | None = None,
    central_weight: float = 1.0 / 3.0,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """SLR of h w.r.t. N(mean, cov): (A (n, dz, d), c (n, dz), Ω (n, dz, dz)).

    Parameters
    ----------
    mean : (n, d), cov : (n, d, d) the Gaussians to linearize with respect to.
    h : vectorised function, points (..., d) → values (..., dz).
    method : `"unscented"` or `"cubature"` sigma points.
    angular : (dz,) which outputs are angles in rad (default: none).
    reference : (n, dz) the angle each angular output is put near (eq. 15), e.g. the
        measurement; default h(mean).
    central_weight : w₀ of the unscented points.

    Returns
    -------
    A, c, Ω
        with z ≈ A x + c + e, e ~ N(0, Ω) (eqs. 17–22).
    """
    chi, w = sigma_points(mean, cov, method, central_weight)      # (n, S, d), (S,)
    zeta = np.asarray(h(chi), dtype=float)                         # (n, S, dz)
    if angular is not None and np.any(angular):
        ang = np.asarray(angular, dtype=bool)
        ref = np.asarray(h(mean), dtype=float) if reference is None else np.asarray(reference, float)
        # eq. (15): ζ̃ = z + mod(ζ − z + π, 2π) − π on the angular outputs
        branch = ref[..., None, :] + np.mod(zeta - ref[..., None, :] + np.pi, 2.0 * np.pi) - np.pi
        zeta = np.where(ang, branch, zeta)
    z_mean = np.einsum("s,nsk->nk", w, zeta)                      # eq. (20): z̄ = Σ w ζ̃
    dchi_w = np.swapaxes(chi - mean[..., None, :], -1, -2) * w     # (n, d, S): w (χ − x̄)
    dzeta = zeta - z_mean[..., None, :]                            # (n, S, dz)
    Psi = dchi_w @ dzeta                                           # eq. (21): Ψ (n, d, dz)
    Phi = (np.swapaxes(dzeta, -1, -2) * w) @ dzeta                 # eq. (22): Φ (n, dz, dz)
    A = np.swapaxes(np.linalg.solve(cov, Psi), -1, -2)             # eq. (17): A = Ψᵀ P⁻¹ (P symmetric)
    c = z_mean - (A @ mean[..., None])[..., 0]                     # eq. (18): c = z̄ − A x̄
    Omega = symmetrize(Phi - A @ cov @ np.swapaxes(A, -1, -2))     # eq. (19): Ω = Φ − A P Aᵀ
    return A, c, Omega
