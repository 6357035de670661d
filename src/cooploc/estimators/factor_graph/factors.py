r"""The topology factors of Gulati et al. 2017: measurement, prediction, Jacobians, noise.

Paper: Gulati, Zhang, Malovetz, Clarke, Hinz & Knoll, "Graph Based Vehicle
Infrastructure Cooperative Localization" (IV 2017), §III, eqs. 8–16 and 19.
Derivation of the new factor's residual: docs/factor_graph.md.

Model
-----
A radar reports the N vehicles in its own unknown frame, anonymously. Their squared
topology (eq. 8)

.. math:: s_t = \sum_{i<j} \|r^i_t - r^j_t\|^2 = N \sum_i \|r^i_t - \bar r_t\|^2

depends neither on the radar pose nor on the row order. One scalar factor per step:

- *old* (eq. 8, Gulati 2016): e = S(p_t) − s_t, S(p) = Σ_{i<j} ‖p^i − p^j‖²,
  an N-ary factor on the positions p_t;
- *new* (eqs. 9–13): e = B(p_t, p_{t−1} + δ_t) − s_t with B the polarisation of S
  (B(p, p) = S(p)), a 2N-ary factor on the positions at t and t − 1 and the odometry
  δ_t; its Jacobian reproduces eq. 19.

Noise (eqs. 14–16): σ_s² = M Cov Mᵀ, M = ∂s/∂r = [2N(r^i − r̄)]_i at the radar rows.
Choice the paper leaves open: the odometry in the new factor is exact by default (as
eq. 12, whose n^top is the radar's noise); `odometry_topology_variance` is the
optional odometry share.

Every function is vectorised over factors (leading axes); cost O(N) per factor.
"""

from __future__ import annotations

import numpy as np

from cooploc.types import FloatArray

__all__ = [
    "NEW",
    "OLD",
    "bilinear_topology",
    "odometry_topology_variance",
    "radar_topology",
    "squared_topology",
    "topology_jacobians",
]

#: the two factor kinds: eq. 8 (Gulati 2016) and eqs. 9–13 (Gulati 2017)
OLD, NEW = "old", "new"


def squared_topology(points: FloatArray) -> FloatArray:
    """S(p) = Σ_{i<j} ‖p^i − p^j‖² = N Σ_i ‖p^i − p̄‖² (eq. 8) of points (..., N, 2) → (...)."""
    centred = points - points.mean(axis=-2, keepdims=True)
    return points.shape[-2] * np.einsum("...nd,...nd->...", centred, centred)


def bilinear_topology(p: FloatArray, q: FloatArray) -> FloatArray:
    """B(p, q) = Σ_{i<j} (p^i − p^j)ᵀ(q^i − q^j) (polarisation of eq. 8), (..., N, 2) → (...)."""
    pc = p - p.mean(axis=-2, keepdims=True)
    return p.shape[-2] * np.einsum("...nd,...nd->...", pc, q - q.mean(axis=-2, keepdims=True))


def radar_topology(z: FloatArray, cov: FloatArray) -> tuple[float, float]:
    """Squared topology s (eq. 8) of radar rows z (N, 2) with covariances (N, 2, 2), and its variance.

    σ_s² = M Cov Mᵀ with M = ∂s/∂r = [2N(r^i − r̄)]_i (eqs. 14–16, first-order propagation).
    """
    n = z.shape[0]
    centred = z - z.mean(axis=0)
    M = 2.0 * n * centred                                                   # eq. (16)
    return float(n * np.sum(centred**2)), float(np.einsum("ni,nij,nj->", M, cov, M))  # eq. (15)


def odometry_topology_variance(z: FloatArray, odometry_cov: FloatArray) -> float:
    """The odometry's share of the new factor's variance: Σ_i gᵢᵀ R_odo,i gᵢ (m⁴).

    gᵢ = ∂B/∂δ^i = N(p_t^i − p̄_t) ≈ N(r^i − r̄) at the radar rows z (N, 2); the radar
    frame's rotation is unknown and its rows anonymous, so only the isotropic part
    tr(R)/2 of the odometry covariances (M, 2, 2), averaged, is used.
    """
    n = z.shape[0]
    iso = np.trace(odometry_cov, axis1=1, axis2=2) / 2.0
    centred = z - z.mean(axis=0)
    return n**2 * float(np.sum(centred**2) * iso.mean())


def topology_jacobians(kind: str, p: FloatArray, q: FloatArray | None = None
                       ) -> tuple[FloatArray, FloatArray | None]:
    """Residual Jacobians of K topology factors: p, q (K, N, 2) → (K, N, 2) blocks.

    old: ∂S/∂p^i = 2N(p^i − p̄), second block None.
    new: ∂B/∂p_t^i = N(q^i − q̄) and ∂B/∂p_{t−1}^i = N(p_t^i − p̄_t), q = p_{t−1} + δ_t;
    their sum at p_t = q is eq. 19.
    """
    n = p.shape[-2]
    pc = p - p.mean(axis=-2, keepdims=True)
    if kind == OLD:
        return 2.0 * n * pc, None
    assert q is not None
    return n * (q - q.mean(axis=-2, keepdims=True)), n * pc
