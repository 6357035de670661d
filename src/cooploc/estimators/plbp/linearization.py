"""Posterior linearization of an AoA link: statistical linear regression of its two bearings.

Paper: "Cooperative Localization with Angular Measurements and Posterior Linearization"
(`papers/002_dfdb230c2e4252cd.txt`, `papers/plbp_model_notes.md`), after
García-Fernández, Svensson & Särkkä, IEEE TSP 2015 (the posterior linearization filter).

Model
-----
A link (a, b) measures h(y) = [θ_{a←b}, θ_{b←a}] of the joint y = [x_a; x_b], with
θ_{i←j} = wrap(atan2(p_j − p_i) − α_i) + w, w ~ N(0, σ²_θ) (eqs. 2–5). With respect to
a Gaussian N(ȳ, P) of y, the SLR (eqs. 11–22) gives

    z ≈ A y + c + e,   e ~ N(0, R + Ω)

from sigma points χ of N(ȳ, P): ζ = h(χ) moved onto the branch nearest the
measurement, ζ̃ = z + mod(ζ − z + π, 2π) − π (eq. 15); z̄ = Σ w ζ̃,
Ψ = Σ w (χ − ȳ)(ζ̃ − z̄)ᵀ, Φ = Σ w (ζ̃ − z̄)(ζ̃ − z̄)ᵀ; A = Ψᵀ P⁻¹, c = z̄ − A ȳ,
Ω = Φ − A P Aᵀ.

*Posterior* linearization (eq. 10) takes N(ȳ, P) as the current BP approximation of
the link's joint posterior: the product of its two cavities, Kalman-updated (Joseph
form) with the link's current linearized likelihood; at the first iteration, the
product of the cavities alone (then the priors). `prior-lbp` stops there.

Choices the paper leaves open: the sigma points (unscented with central weight 1/3 by
default, or cubature = unscented with weight 0); z̃ of eq. (24), the measurement moved
onto the branch nearest the SLR prediction c + A ȳ; an end that did not measure gets a
zero model row (A = 0, c = 0, Ω = 0, z̃ = 0), so that its unit-variance row of
`LinkFactors.R` carries no information.

Complexity: O(F (2dx)³) per linearization for F links, in the fused numba kernel
`plbp._kernels.aoa_joint_slr`; `_linearize_reference` computes the same with the
general NumPy building blocks (`gaussian.statistical_linear_regression`), for tests.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cooploc.estimators.plbp.links import LinkFactors
from cooploc.gaussian import Gaussians, kf_update, statistical_linear_regression, symmetrize
from cooploc.geometry import wrap_angle
from cooploc.sensors import AngleOfArrival
from cooploc.types import FloatArray, IntArray

__all__ = ["LinearizedLinks", "linearize_links"]


@dataclass(frozen=True, slots=True)
class LinearizedLinks:
    """The linear-Gaussian model z̃ = A [x_a; x_b] + c + e, e ~ N(0, noise), of every link.

    Attributes
    ----------
    A : (F, 2, 2dx); c : (F, 2); noise : (F, 2, 2) R + Ω (symmetrised);
    z : (F, 2) z̃, the measurement on the branch nearest its prediction (rad).
    Rows of an end that did not measure are zero (noise: its unit variance).
    """

    A: FloatArray
    c: FloatArray
    noise: FloatArray
    z: FloatArray


def linearize_links(cavities: tuple[FloatArray, FloatArray, FloatArray, FloatArray], links: LinkFactors,
                    previous: LinearizedLinks | None, index: IntArray, central_weight: float
                    ) -> LinearizedLinks:
    """SLR of every link w.r.t. its joint posterior approximation (eq. 10).

    cavities : (μ_a, Σ_a, μ_b, Σ_b) of every link's two cavities.
    previous : the links' current linearization, which updates the product of the
        cavities; None: the product of the cavities alone.
    index : positions of (p_x, p_y, α) in the state; central_weight : w₀ (0: cubature).
    """
    from cooploc.estimators.plbp import _kernels

    F, dx = cavities[0].shape
    missing = ~links.measured
    if previous is None:
        A0 = np.zeros((F, 2, 2 * dx))
        update = (A0, A0[..., 0], A0[..., :2])
    else:
        update = (previous.A, previous.z - previous.c, previous.noise)
    A, c, Omega, joint_mean = _kernels.aoa_joint_slr(*cavities, *update, previous is not None, links.z,
                                                     index, central_weight)
    A = np.where(missing[..., None], 0.0, A)
    c = np.where(missing, 0.0, c)
    Omega = np.where(missing[:, :, None] | missing[:, None, :], 0.0, Omega)
    noise = symmetrize(links.R + Omega)
    predicted = c + (A @ joint_mean[..., None])[..., 0]
    z = np.where(missing, 0.0, predicted + wrap_angle(links.z - predicted))   # z̃ of eq. (24)
    return LinearizedLinks(A, c, noise, z)


def _link_model(sensor: AngleOfArrival, dx: int) -> Callable[[FloatArray], FloatArray]:
    """h(y) = [θ_{a←b}, θ_{b←a}] of the joint y = [x_a; x_b] (..., 2dx) → (..., 2)."""

    def h(y: FloatArray) -> FloatArray:
        xa, xb = y[..., :dx], y[..., dx:]
        return np.stack([sensor.bearing(xa, xb), sensor.bearing(xb, xa)], axis=-1)

    return h


def _linearize_reference(cavities: tuple[FloatArray, ...], previous: tuple[FloatArray, ...] | None,
                         z: FloatArray, sensor: AngleOfArrival, method: str = "unscented",
                         central_weight: float = 1.0 / 3.0
                         ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """What `_kernels.aoa_joint_slr` computes, with the general NumPy building blocks (for tests).

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
