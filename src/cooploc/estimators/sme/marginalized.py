r"""The linear substate of `sme-pf`'s marginalized (Rao–Blackwellised) particle filter.

Paper: Schön, Gustafsson & Nordlund, "Marginalized particle filters for mixed
linear/nonlinear state-space models", IEEE TSP 53(7), 2005, §II–III (their model (18) with
C_t = 0: the measurement depends on the nonlinear substate only).

Model
-----
Zhang's pseudo-measurements (eqs. 17–19) depend on the positions only, and the GPS rows
of the paper's internal sensor are positions (``scenarios/zhang2016.py``), so each vehicle
block splits into the nonlinear substate xⁿ = p (sampled) and the linear substate
xˡ = v, which enters only through the motion model x_k = A x_{k−1} + w_k (eq. 16). Each
particle i carries its position and the Gaussian p(v_{k−1} | p^i_{0:k−1}, y_{1:k−1}) =
N(m^i, P). Because A and Q do not depend on the particle, P follows the same Riccati
recursion for every particle: one covariance per vehicle, shared.

Per step and vehicle, with the particle's block x̄ = [p^i; m^i] (velocity entries holding
the mean):

.. math:: \begin{bmatrix} p_k \\ v_k \end{bmatrix} \Big|\, p^i_{0:k-1} ∼
          N\big(A x̄,\; J\big), \qquad J = A_{:,v} P A_{:,v}^T + Q,

whose position marginal N(μ_p^i, J_pp) is the prior kernel the particle filter samples
p_k from (Schön et al.'s p(xⁿ_{t+1} | Xⁿ_t, Y_t), their eq. 25a), and whose conditional

.. math:: v_k \mid p_k ∼ N\big(μ_v^i + K (p_k − μ_p^i),\; C\big), \quad
          K = J_{vp} J_{pp}^{-1}, \quad C = J_{vv} − K J_{pv}

is the time update of the linear substate together with its "measurement" by the
sampled motion of xⁿ (their eqs. 22–24: the nonlinear state's dynamics used as a
measurement of the linear one). A vehicle that enters has J = its entry covariance and
the entry mean as μ.

Complexity per step: O(N dx³) for the gains (shared), O(P N dx²) to condition.
"""

from __future__ import annotations

import numpy as np

from cooploc.gaussian import symmetrize
from cooploc.types import FloatArray

__all__ = ["condition_on_positions", "motion_kernel"]


def motion_kernel(joint_cov: FloatArray, pos: list[int], lin: list[int]
                  ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Split the per-vehicle joint predictive covariances J (N, dx, dx) into the position
    marginal J_pp (N, np, np), the gain K = J_vp J_pp⁻¹ (N, nl, np) and the conditional
    covariance C = J_vv − K J_pv (N, nl, nl) of the velocities given the positions."""
    Jpp = joint_cov[:, pos][:, :, pos]
    Jlp = joint_cov[:, lin][:, :, pos]
    Jll = joint_cov[:, lin][:, :, lin]
    K = np.swapaxes(np.linalg.solve(Jpp, np.swapaxes(Jlp, -1, -2)), -1, -2)   # J_vp J_pp⁻¹
    C = symmetrize(Jll - K @ np.swapaxes(Jlp, -1, -2))
    return symmetrize(Jpp), K, C


def condition_on_positions(prior_mean: FloatArray, positions: FloatArray, gain: FloatArray,
                           pos: list[int], lin: list[int]) -> FloatArray:
    """Blocks (P, N, dx) with the sampled positions (P, N, np) and, in the velocity entries,
    E[v_k | p_k] = μ_v + K (p_k − μ_p) of each particle's predictive mean μ (P, N, dx)."""
    out = np.empty_like(prior_mean)
    out[:, :, pos] = positions
    out[:, :, lin] = prior_mean[:, :, lin] + np.einsum(
        "nij,pnj->pni", gain, positions - prior_mean[:, :, pos])
    return out
