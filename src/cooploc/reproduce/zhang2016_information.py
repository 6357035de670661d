r"""How much the topology T can add to a known-association Kalman filter (Zhang 2016 §4.1).

The SME filter of Zhang et al. 2016 sees the anonymous GPS rows (eq. 17) and one scalar
per step from the radar, the topology T of eq. (18); `kf-known-da` sees the GPS rows
*with* their association and no radar. Anything SME gains over `kf-known-da` must come
from T, and anything it loses from the association it does not know. So the most SME
can gain is what T adds to a Kalman filter that already knows the association — this
module computes that, exactly, without Monte Carlo.

Model
-----
The joint state of the N vehicles (4N components) follows the estimators' model
x_k = A x_{k−1} + w_k (eq. 16, `Setup.vehicle_motion`); GPS gives y = H x + v,
v ~ N(0, r I) per vehicle (eq. 9 with the association known); the radar adds

.. math:: T = N \sum_i \lVert q_i - \bar q \rVert^2, \qquad
          \nabla_{p_i} T = 2 N (p_i - \bar p), \qquad \operatorname{Var} T \text{ from `topology_moments`},

linearized at the *true* positions — the information T carries about x, as a posterior
Cramér–Rao bound takes it (Tichavský, Muravchik & Nehorai 1998). T constrains one
direction of the 2N positions (the radial scale of the configuration: its gradient is
the centred configuration itself) with variance Var T / ‖∇T‖² = d (the radar's per-axis
variance), against GPS's r in every direction.

Both filters (with and without the T row) run their Kalman gains K_k on that model;
their *actual* error is propagated exactly along the recorded true trajectory:

.. math:: e_k^- = A e_{k−1} − u_k, \quad u_k = x_k − A x_{k−1}, \qquad
          e_k = (I − K_k H_k) e_k^- + K_k v_k,

mean b_k and covariance C_k, so that E Σ_i ‖p̂_i − p_i‖² = tr_pos(C_k + b_k b_kᵀ) at
each step. u_k is zero where the truth follows the model's mean (the noise-free CV
paths); it is the turn the CV model does not know in the CT scenarios. The prior mean is
the true initial state (as in `cooploc.scenarios.zhang2016`), so e_{−1} = 0.

The expected total error of eq. (20) is then sqrt(mean_k E Σ_i ‖e_i‖²) (Jensen's gap to
E sqrt(·) is negligible over 100 steps × 2N coordinates).

Complexity: O(K (4N)³) for K steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.estimators.sme.pseudo_measurement import topology_moments
from cooploc.gaussian import symmetrize
from cooploc.types import FloatArray, Recording

__all__ = ["TopologyGain", "expected_squared_error", "topology_gain"]


@dataclass(frozen=True)
class TopologyGain:
    """What T adds to a known-association Kalman filter on one recording's trajectory.

    Attributes
    ----------
    kf_per_step : (K,) E Σ_i ‖p̂_i − p_i‖² (m²) of the known-association KF, GPS only.
    kf_topology_per_step : (K,) the same for the filter with the T row.
    """

    kf_per_step: FloatArray
    kf_topology_per_step: FloatArray

    @property
    def kf(self) -> float:
        """Expected total error (eq. 20, m) of the known-association KF, GPS only."""
        return float(np.sqrt(self.kf_per_step.mean()))

    @property
    def kf_topology(self) -> float:
        """Expected total error (eq. 20, m) of the known-association KF with the T row."""
        return float(np.sqrt(self.kf_topology_per_step.mean()))

    @property
    def ratio(self) -> float:
        """kf_topology / kf: the smallest total error SME can reach, relative to the KF's."""
        return self.kf_topology / self.kf

    @property
    def gain(self) -> float:
        """1 − ratio: the largest relative gain SME can have over the known-association KF."""
        return 1.0 - self.ratio


def _variance(setup_sensor: object, fallback: str) -> float:
    cov = getattr(setup_sensor, "default_cov", None)
    if cov is None:
        raise ValueError(f"the {fallback} sensor has no default_cov")
    return float(np.trace(np.asarray(cov)) / 2)


def expected_squared_error(recording: Recording, use_topology: bool) -> FloatArray:
    """E Σ_i ‖p̂_i − p_i‖² per step (K,) of the known-association KF (with the T row or not)."""
    setup = recording.setup
    states = recording.truth.vehicle_states                               # (K, N, dx)
    K_steps, N, dx = states.shape
    pos = list(setup.vehicle_layout.position)
    d = N * dx
    F = np.kron(np.eye(N), setup.vehicle_motion.transition_matrix(setup.dt))
    Q = setup.vehicle_motion.noise_covariance(setup.dt)
    Q = np.kron(np.eye(N), Q[0] if Q.ndim == 3 else Q)
    r = _variance(setup.sensors["gnss"], "gnss")
    radar_var = _variance(setup.sensors["radar"], "radar")
    prior = setup.vehicle_prior.take(recording.truth.vehicle_ids)
    P = np.zeros((d, d))
    for n in range(N):
        P[n * dx:(n + 1) * dx, n * dx:(n + 1) * dx] = prior.cov[n]
    cols = (np.arange(N)[:, None] * dx + np.array(pos)).ravel()           # p_x, p_y of each vehicle
    H_gps = np.zeros((2 * N, d))
    H_gps[np.arange(2 * N), cols] = 1.0
    b = np.zeros(d)                                                       # error mean
    C = np.zeros((d, d))                                                  # error covariance
    out = np.empty(K_steps)
    for k in range(K_steps):
        x = states[k].ravel()
        if k:
            P = symmetrize(F @ P @ F.T + Q)                               # P⁻ = A P Aᵀ + Q
            u = x - F @ states[k - 1].ravel()                             # what the model misses
            b = F @ b - u
            C = F @ C @ F.T
        H, R = H_gps, r * np.eye(2 * N)
        if use_topology and N >= 2:
            p = states[k][:, pos]
            grad = np.zeros(d)
            grad[cols] = (2.0 * N * (p - p.mean(0))).ravel()              # ∇T at the truth
            _, var_T = topology_moments(p, np.full(N, radar_var))
            H = np.vstack([H_gps, grad])
            R = np.zeros((2 * N + 1, 2 * N + 1))
            R[:2 * N, :2 * N] = r * np.eye(2 * N)
            R[-1, -1] = float(var_T)
        S = symmetrize(H @ P @ H.T + R)
        G = np.linalg.solve(S, H @ P).T                                    # K = P Hᵀ S⁻¹
        I_GH = np.eye(d) - G @ H
        P = symmetrize(I_GH @ P @ I_GH.T + G @ R @ G.T)
        b = I_GH @ b
        C = symmetrize(I_GH @ C @ I_GH.T + G @ R @ G.T)
        out[k] = float(np.trace(C[np.ix_(cols, cols)]) + b[cols] @ b[cols])
    return out


def topology_gain(recording: Recording) -> TopologyGain:
    """Expected eq. (20) total errors of the known-association KF without and with T."""
    return TopologyGain(expected_squared_error(recording, False), expected_squared_error(recording, True))
