r"""What SME's information allows: a multiple-hypothesis Kalman filter of the anonymous rows.

`sme-pf` and `sme-ukf` see the GPS rows of the N vehicles *without* their association and
the topology T of eq. (18); `kf-known-da` sees the rows *with* their association and no
radar (Zhang et al. 2016 §4.1). `zhang2016_information` bounds what T can add to a
filter that knows the association. This module measures the other side: what not
knowing the association costs, with a filter that is not SME — so that a difference
between `sme-pf` and `kf-known-da` can be split into what the information allows and
what the SME filter's approximations (particles, proposal, relabelling, the Gaussian
shape of the pseudo-noise) lose.

Model
-----
The joint state x (N·dx) follows x_k = A x_{k−1} + w_k, w_k ~ N(0, blockdiag Q) (eq. 16,
`Setup.vehicle_motion`), prior N(m₀, blockdiag P₀) (`Setup.vehicle_prior`). The GPS rows
are z_i = p_{σ(i)} + v_i, v_i ~ N(0, r I₂), with σ an unknown permutation, uniform and
independent per step, so the exact likelihood of the rows is the mixture

.. math:: p(z \mid x) = \frac{1}{N!} \sum_{\sigma} \mathcal N(z_\sigma;\, H x,\, r I),

z_σ the rows reordered so that vehicle v gets row σ(v). The exact posterior is therefore a
Gaussian mixture with one component per history of permutations (Reid 1979). Its
components share the covariance update: S_σ = Π S Πᵀ and K_σ = P Hᵀ S⁻¹ Πᵀ, so
P⁺ = P − P Hᵀ S⁻¹ H P is the same for every σ; only the mean, x + P Hᵀ S⁻¹ (z_σ − H x),
and the weight, w · N(z_σ; H x, S), differ. Each step every component is split into its
N! children and the `max_hypotheses` heaviest are kept (the only approximation of the
GPS part: pruning; with vehicles apart one child holds nearly all the weight).

The topology T = N Σ_i ‖q_i − q̄‖² of the radar rows enters every kept child as one
extended-Kalman row: E[T | x] and Var[T | x] from `topology_moments` (exact for
Gaussian radar noise), gradient ∇_{p_i} T = 2N (p_i − p̄), linearized at the child's
mean (the formation spans tens of metres against a radar noise of 0.3 m, so T is
nearly linear over a component), and the child's weight multiplied by its predictive
likelihood N(T; E[T | x̂], g P gᵀ + Var T).

The point estimate is the MMOSPA-style mean that `sme-pf` also takes: every component's
vehicle blocks permuted to best match the heaviest component's, then the weighted mean.
Scoring, as for the set-valued filters (`cooploc.metrics.evaluate`): Σ_v ‖p̂ − p‖² after
the optimal assignment at each step.

Complexity per step: O(C N! N) to score the children (C = `max_hypotheses`, a shared
(2N)² Cholesky per component) and O(C (N dx)³) for the updates; N! = 120 for the
paper's five vehicles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.errors import InvalidInputError
from cooploc.estimators.sme.pseudo_measurement import permutations, topology_moments
from cooploc.gaussian import Gaussians, block_diagonal, gaussian_logpdf, kf_predict, kf_update
from cooploc.particles import log_sum_exp
from cooploc.types import FloatArray, IntArray, Recording

__all__ = ["MAX_HYPOTHESES", "AnonymousModel", "gps_update", "hypothesis_filter", "permutations",
           "recording_inputs", "set_squared_errors", "topology_update"]

MAX_HYPOTHESES = 64   # components kept per step (the children of all components, heaviest first)


@dataclass(frozen=True)
class AnonymousModel:
    """The linear-Gaussian model of N vehicles seen by anonymous GPS rows (and T).

    Attributes
    ----------
    F, Q : (dx, dx) one vehicle's transition and process noise (eq. 16).
    position : (2,) the position components of a vehicle's state.
    prior_mean : (N, dx), prior_cov : (N, dx, dx) at the first step.
    gnss_var : per-axis variance r of a GPS row (m²).
    radar_var : per-axis variance d of a radar row (m²), None without the topology.
    """

    F: FloatArray
    Q: FloatArray
    position: IntArray
    prior_mean: FloatArray
    prior_cov: FloatArray
    gnss_var: float
    radar_var: float | None = None

    @property
    def n(self) -> int:
        return self.prior_mean.shape[0]

    @property
    def dx(self) -> int:
        return self.prior_mean.shape[1]

    def position_columns(self) -> IntArray:
        """(2N,) the joint-state columns of p_x, p_y of each vehicle, vehicle-major."""
        return (np.arange(self.n)[:, None] * self.dx + np.asarray(self.position)[None]).ravel()


def gps_update(belief: Gaussians, log_w: FloatArray, rows: FloatArray, model: AnonymousModel,
               perms: IntArray, keep: int) -> tuple[Gaussians, FloatArray]:
    """Every component × every association σ of the rows; the `keep` heaviest, updated.

    belief : C components of the joint state, (C, N dx), (C, N dx, N dx); log_w (C,).
    rows : (N, 2) the GPS rows in any order. Returns the kept children and their
    (unnormalised) log-weights, heaviest first.
    """
    cols = model.position_columns()
    H = np.zeros((cols.size, belief.mean.shape[1]))
    H[np.arange(cols.size), cols] = 1.0
    R = model.gnss_var * np.eye(cols.size)
    z = rows[perms].reshape(perms.shape[0], -1)                   # (N!, 2N): vehicle v gets row σ(v)
    S = H @ belief.cov @ H.T + R                                  # (C, 2N, 2N), the same for every σ
    innovation = z[None] - belief.mean[:, None, cols]             # (C, N!, 2N)
    # w_{c,σ} ∝ w_c N(z_σ; H x_c, S_c)
    log_child = log_w[:, None] + gaussian_logpdf(innovation, S[:, None])
    flat = log_child.ravel()
    best = np.argsort(flat)[::-1][:keep]
    parent, sigma = np.divmod(best, perms.shape[0])
    children = kf_update(belief.take(parent), z[sigma], H, R)
    return children, flat[best]


def topology_update(belief: Gaussians, log_w: FloatArray, T: float, model: AnonymousModel
                     ) -> tuple[Gaussians, FloatArray]:
    """One extended-Kalman row of the measured T (m²) per component, linearized at its
    mean; each log-weight gains log N(T; E[T | x̂], g P gᵀ + Var T)."""
    cols = model.position_columns()
    p = belief.mean[:, cols].reshape(-1, model.n, 2)              # (C, N, 2)
    expected, var_T = topology_moments(p, np.full(model.n, model.radar_var))
    g = np.zeros_like(belief.mean)
    g[:, cols] = (2.0 * model.n * (p - p.mean(1, keepdims=True))).reshape(p.shape[0], -1)   # ∇T
    H = g[:, None, :]                                             # (C, 1, d)
    R = var_T[:, None, None]
    s = np.einsum("ci,cij,cj->c", g, belief.cov, g) + var_T      # predictive variance of T
    log_w = log_w - 0.5 * (np.log(2 * np.pi * s) + (T - expected) ** 2 / s)
    # T ≈ E[T | x̂] + g (x − x̂): the linearized row measures g x with z = T − E[T | x̂] + g x̂
    z = (T - expected + np.einsum("ci,ci->c", g, belief.mean))[:, None]
    return kf_update(belief, z, H, R), log_w


def _aligned_mean(belief: Gaussians, log_w: FloatArray, model: AnonymousModel, perms: IntArray
                  ) -> FloatArray:
    """(N, 2) the weighted mean of the components' positions, each component's vehicles
    first permuted to best match the heaviest component's (MMOSPA-style)."""
    cols = model.position_columns()
    p = belief.mean[:, cols].reshape(-1, model.n, 2)              # (C, N, 2)
    reference = p[np.argmax(log_w)]
    cost = ((p[:, perms] - reference[None, None]) ** 2).sum((-1, -2))   # (C, N!)
    aligned = p[np.arange(p.shape[0])[:, None], perms[np.argmin(cost, axis=1)]]
    w = np.exp(log_w - log_sum_exp(log_w, axis=None))
    return np.einsum("c,cij->ij", w, aligned)


def hypothesis_filter(model: AnonymousModel, gnss: FloatArray, topology: FloatArray | None = None,
                      max_hypotheses: int = MAX_HYPOTHESES) -> FloatArray:
    """Position estimates (K, N, 2) from anonymous GPS rows and, if given, T.

    Parameters
    ----------
    model : the vehicles' model; ``radar_var`` is needed with `topology`.
    gnss : (K, N, 2) the rows of each step, in any order (m).
    topology : (K,) the measured T of each step (m²), NaN where there is none; None: no T.
    max_hypotheses : components kept per step.
    """
    if topology is not None and model.radar_var is None:
        raise InvalidInputError("hypothesis_filter: the topology needs model.radar_var")
    perms = permutations(model.n)
    d = model.n * model.dx
    belief = Gaussians(model.prior_mean.reshape(1, d), block_diagonal(model.prior_cov)[None])
    log_w = np.zeros(1)
    F = block_diagonal(np.repeat(model.F[None], model.n, 0))
    Q = block_diagonal(np.repeat(model.Q[None], model.n, 0))
    out = np.empty((gnss.shape[0], model.n, 2))
    for k in range(gnss.shape[0]):
        if k:
            belief = kf_predict(belief, F, Q)                     # x_k = A x_{k−1} + w_k
        belief, log_w = gps_update(belief, log_w, gnss[k], model, perms, max_hypotheses)
        if topology is not None and np.isfinite(topology[k]):
            belief, log_w = topology_update(belief, log_w, float(topology[k]), model)
        log_w = log_w - log_sum_exp(log_w, axis=None)
        out[k] = _aligned_mean(belief, log_w, model, perms)
    return out


def recording_inputs(recording: Recording) -> tuple[AnonymousModel, FloatArray, FloatArray]:
    """The model, the GPS rows (K, N, 2) and the measured T (K,) of a Zhang recording.

    Raises InvalidInputError where the recording is not the paper's case: every vehicle present
    at every step, one GPS row and one radar row per vehicle, equal row covariances.
    """
    setup, truth = recording.setup, recording.truth
    if not truth.vehicle_present.all():
        raise InvalidInputError("hypothesis filter: every vehicle must be present at every step")
    n = truth.vehicle_ids.size
    gnss, topology = [], []
    variances = {}
    for frame in recording.frames:
        for kind in ("gnss", "radar"):
            batch = frame.batches.get(kind)
            if batch is None or batch.z.shape[0] != n:
                raise InvalidInputError(f"hypothesis filter: step {frame.k} has no {kind} row per vehicle")
            var = np.trace(batch.cov, axis1=1, axis2=2) / 2
            if not np.allclose(var, var[0]) or not np.allclose(var, variances.setdefault(kind, var[0])):
                raise InvalidInputError(f"hypothesis filter: the {kind} rows must share one variance")
        gnss.append(frame.batches["gnss"].z[:, :2])
        q = frame.batches["radar"].z[:, :2]
        topology.append(n * ((q - q.mean(0)) ** 2).sum())        # T = N Σ ‖q_i − q̄‖² (eq. 18)
    prior = setup.vehicle_prior.take(truth.vehicle_ids)
    Q = setup.vehicle_motion.noise_covariance(setup.dt)
    model = AnonymousModel(F=setup.vehicle_motion.transition_matrix(setup.dt), Q=Q[0] if Q.ndim == 3 else Q,
                           position=np.asarray(setup.vehicle_layout.position), prior_mean=prior.mean,
                           prior_cov=prior.cov, gnss_var=float(variances["gnss"]),
                           radar_var=float(variances["radar"]))
    return model, np.array(gnss), np.array(topology)


def set_squared_errors(estimates: FloatArray, truth: FloatArray) -> FloatArray:
    """(K,) Σ_v ‖p̂ − p‖² after the optimal assignment per step (`metrics.set_errors`, as
    the set-valued filters are scored); estimates, truth (K, N, 2)."""
    from cooploc.metrics import set_errors

    return np.array([(set_errors(e, t) ** 2).sum() for e, t in zip(estimates, truth, strict=True)])
