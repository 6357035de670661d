r"""`fg-topology-old`, `fg-topology-new`, `fg-isam2`: factor graphs with topology factors.

Paper: Gulati, Zhang, Malovetz, Clarke, Hinz & Knoll, "Graph Based Vehicle
Infrastructure Cooperative Localization" (IV 2017), §III (eqs. 1–19).

Model
-----
One variable per vehicle and step: its 2-D position p_t^i (the graph has no velocity
and no motion model, as in the paper). Factors, each a Gaussian residual:

- GPS (unary, eqs. 6–7): p_t^i − z_t^g, covariance of the fix.
- Odometry (between, eqs. 4–5): (p_t^i − p_{t−1}^i) − δ_t^i, covariance of the row.
- Topology. The radar reports the N vehicles in its own frame, anonymously; its
  *squared topology* (eq. 8)

  .. math:: s_t = \sum_{i<j} \|r^i_t - r^j_t\|^2 = N \sum_i \|r^i_t - \bar r_t\|^2

  does not depend on the radar pose (rotation and translation) nor on the order of
  the rows, so it needs neither registration nor data association.

  * *old* factor (eq. 8, the N-ary factor of Gulati 2016): S(p_t) − s_t with
    S(p) = Σ_{i<j} ‖p^i − p^j‖².
  * *new* factor (eqs. 9–13, 2N-ary), derived below.

Derivation of the new factor's residual
---------------------------------------
The paper substitutes p_t = p_{t−1} + δ_t (eq. 10) into eq. 8 and obtains eq. 11,
S(p_{t−1} + δ_t); it then says the factor joins the states at t *and* t − 1 (eq. 12,
Fig. 2) and gives as Jacobian (eq. 19) the gradient of eq. 11,
2 Σ_j (q^i − q^j) with q = p_{t−1} + δ_t. Eq. 11 alone does not contain p_t, so the
factor would only touch t − 1. We make the factor depend on both by substituting eq. 10
into *one* of the two factors of each squared difference in eq. 8, i.e. we use the
polarisation of the quadratic form S, the symmetric bilinear form

.. math::

    B(p, q) = \sum_{i<j} (p^i - p^j)^T (q^i - q^j)
            = N \sum_i (p^i - \bar p)^T (q^i - \bar q),  \qquad S(p) = B(p, p),

with p = p_t (current states) and q = p_{t−1} + δ_t (the topology predicted from the
previous states and odometry). The residual of the new factor is

.. math:: e^{new}_t = B(p_t,\; p_{t-1} + \delta_t) - s_t .

Properties: (a) it equals eq. 11 wherever the state agrees with odometry
(p_t = p_{t−1} + δ_t) and eq. 8 wherever p_{t−1} + δ_t = p_t; (b) it is invariant to
any rigid motion of the global frame applied to p_t and q together and to a common
permutation of the vehicles (as s_t is to the radar pose and row order); (c) its
Jacobian blocks are

.. math::

    \partial e / \partial p_t^i = N (q^i - \bar q), \qquad
    \partial e / \partial p_{t-1}^i = N (p_t^i - \bar p_t),

and moving p_t and p_{t−1} together by the same increment gives their sum,
2N(q^i − q̄) = 2 Σ_j (q^i − q^j) at p_t = q: exactly eq. 19. So the residual reproduces
eqs. 11, 12 and 19 of the paper at once. (Old factor: ∂e/∂p_t^i = 2N(p_t^i − p̄_t).)

Topology noise (eqs. 14–16): first-order propagation of the radar noise through s_t,
σ_s² = M Cov M' with M = ∂s/∂r = [2N(r^i − r̄)]_i, evaluated at the measured rows:
σ_s² = 4N² Σ_i (r^i − r̄)ᵀ R_i (r^i − r̄)  (= 4N σ_r² s_t for R_i = σ_r² I). Like the
paper we propagate only the radar noise by default (the odometry in the new factor is
taken as exact, as in eq. 12 where n^top is the radar's noise). The option
`topology_odometry_noise` adds the odometry's share, Σ_i gᵢᵀ R_odo gᵢ with
gᵢ = ∂B/∂δ^i = N(p_t^i − p̄_t), evaluated at the radar rows with the isotropic part of
the odometry covariance (the radar frame's rotation is unknown, its rows anonymous).

Old or new? The old factor is the first-order likelihood of s_t given p_t; the new one
uses each odometry row a second time (it is also in its between factor), so it cannot
carry more information. On gulati-2v (10 runs, seed 9) the eq. 21 error was 2.14 m
(old), 2.20 m (new, this residual), 2.19 m (new with `topology_odometry_noise`) and
2.32 m for the literal reading of eq. 11 (S(p_{t−1} + δ_t) − s_t, touching t − 1
only) — the reason we chose the bilinear residual, and why our Table I does not show
the paper's gain of the new factor over the old one.

Missed detections and clutter (paper's future work)
---------------------------------------------------
s_t is only meaningful if the radar rows are exactly the N vehicles of the graph.
A topology factor is therefore **left out** at every step where a radar does not
report exactly as many rows as there are vehicles present (the paper's "plug and play"
remark, §IV-B); the new factor is also left out where a vehicle has no single odometry
row (first step, a vehicle that just entered). The factor count is `info["topology"]`.
With clutter *and* misses a wrong row can replace a missed one at equal count; the
robust option `huber` (> 0: Huber loss with that threshold in σ units, GTSAM's
`noiseModel.Robust` + `mEstimator.Huber`) bounds the influence of such factors.

Gaps: where a vehicle present at t − 1 and t has no odometry row, a between factor
with zero displacement and covariance `gap_variance` · I keeps the chain connected.
The first variable of every vehicle's chain gets its prior position (the vehicle prior
of the setup, or a broad one centred on the first GPS fix: `base.birth_beliefs`).

Solvers and what `step` returns
-------------------------------
- `fg-topology-old` / `fg-topology-new`: batch smoothing by Levenberg–Marquardt, as the
  paper. `step` appends the frame's factors and returns the *filtered* estimate of the
  graph's linear part (GPS and odometry, a position Kalman filter), in O(N) per step;
  `smooth()` solves the whole graph and returns the smoothed estimate of every step.
  `experiment.run_one` calls `smooth()` at the end of a run when an estimator has it
  and scores those estimates (as the paper), counting its time as step time.
  The default solver (`solver="sparse"`) is our own LM on the sparse whitened Jacobian
  with all factors of a kind evaluated in one vectorised NumPy expression; variables
  are ordered by step, so JᵀJ is banded (bandwidth < 2N per variable block) and each
  iteration is one banded Cholesky, O(T N³). Marginal covariances come from the
  banded selected inverse (Takahashi recursion, numba), O(T N³). `solver="gtsam"`
  builds the same graph in GTSAM (`PriorFactorPoint2`, `BetweenFactorPoint2` and one
  Python `CustomFactor` per topology factor) and runs GTSAM's LM: the reference the
  tests check our solver against, and the "before" of benchmarks/factor_graph.py.
  Damping follows GTSAM's default (λ I, λ₀ = 1e-5, ×10 / ÷10).
- `fg-isam2`: the new-factor graph updated incrementally with GTSAM's iSAM2 each step;
  `step` returns the filtered (current) estimate and marginal covariance. GPS and
  odometry are native GTSAM factors; the topology factor is one `CustomFactor` per step
  whose error and Jacobian are plain arithmetic on the 2N positions (no NumPy call
  per vehicle), so the GIL-bound Python cost per relinearisation stays small; variables
  are relinearised at most every `relinearize_skip` = 10 updates (GTSAM's default).

Measured (benchmarks/factor_graph.py, 250 steps, CPU time on a shared 2-core machine):
one LM solve of the gulati-2v graph takes 8–14 ms with our solver against 0.32–0.52 s
with GTSAM's LM and a NumPy `CustomFactor` (23–68×; GTSAM without topology factors:
10–28 ms); GTSAM's time grows faster than linearly with the horizon (0.10 / 0.27 /
0.83 / 3.2 s for 125 / 250 / 500 / 1000 steps; ours 5 / 7 / 11 / 20 ms). iSAM2:
1.1–1.5 ms per step for 2–4 vehicles (before: 2.6–3.7 ms with the NumPy factor
relinearised every step).

Velocity in the `Estimate` (the scenario's state is [p, v]): smoothed, the finite
difference of smoothed positions (p_t − p_{t−1}) / T; filtered, δ_t / T. Its
covariance is block-diagonal beside the position block (cross terms dropped).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numba
import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_solve_banded, cholesky_banded

from cooploc.estimators.base import birth_beliefs
from cooploc.gaussian import Gaussians, kf_update
from cooploc.params import Params, param
from cooploc.registry import register_estimator
from cooploc.types import Batch, Estimate, FloatArray, Frame, IntArray, Setup, StateSet

__all__ = [
    "FactorGraphParams",
    "FgIsam2",
    "FgTopologyNew",
    "FgTopologyOld",
    "FrameFactors",
    "GraphData",
    "ISAM2Params",
    "bilinear_topology",
    "gtsam_graph",
    "radar_topology",
    "solve_lm",
    "squared_topology",
    "topology_jacobians",
]

OLD, NEW = "old", "new"
_I2 = np.eye(2)


# ----------------------------------------------------------------------------
# topology: measurement, prediction, Jacobians (vectorised over factors)
# ----------------------------------------------------------------------------


def squared_topology(points: FloatArray) -> FloatArray:
    """S(p) = Σ_{i<j} ‖p^i − p^j‖² = N Σ_i ‖p^i − p̄‖² (eq. 8) of points (..., N, 2) → (...)."""
    centred = points - points.mean(axis=-2, keepdims=True)
    return points.shape[-2] * np.einsum("...nd,...nd->...", centred, centred)


def bilinear_topology(p: FloatArray, q: FloatArray) -> FloatArray:
    """B(p, q) = Σ_{i<j} (p^i − p^j)ᵀ(q^i − q^j) (polarisation of eq. 8), (..., N, 2) → (...)."""
    pc = p - p.mean(axis=-2, keepdims=True)
    return p.shape[-2] * np.einsum("...nd,...nd->...", pc, q - q.mean(axis=-2, keepdims=True))


def radar_topology(z: FloatArray, cov: FloatArray) -> tuple[float, float]:
    """Squared topology s (eq. 8) of radar rows z (N, 2) and its variance (eqs. 14–16).

    σ_s² = M Cov Mᵀ with M = ∂s/∂r = [2N(r^i − r̄)]_i (first-order propagation).
    """
    n = z.shape[0]
    centred = z - z.mean(axis=0)
    M = 2.0 * n * centred                                                   # eq. (16)
    return float(n * np.sum(centred**2)), float(np.einsum("ni,nij,nj->", M, cov, M))  # eq. (15)


def topology_jacobians(kind: str, p: FloatArray, q: FloatArray | None = None
                       ) -> tuple[FloatArray, FloatArray | None]:
    """Residual Jacobians of K topology factors: p, q (K, N, 2) → (K, N, 2) blocks.

    old: ∂S/∂p^i = 2N(p^i − p̄), second block None.
    new: ∂B/∂p_t^i = N(q^i − q̄) and ∂B/∂p_{t−1}^i = N(p_t^i − p̄_t), q = p_{t−1} + δ_t.
    """
    n = p.shape[-2]
    pc = p - p.mean(axis=-2, keepdims=True)
    if kind == OLD:
        return 2.0 * n * pc, None
    assert q is not None
    return n * (q - q.mean(axis=-2, keepdims=True)), n * pc


# ----------------------------------------------------------------------------
# the graph as arrays
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class FrameFactors:
    """The variables and factors one frame adds to the graph (rows are factors).

    vars, ids, previous (n,): new variable per present vehicle (by id), its id, and the
    variable of the same vehicle at the previous step (−1: a new chain).
    delta (n, 2): the vehicle's odometry row, NaN unless it has exactly one.
    unary_*: priors and GPS (M,), (M, 2), (M, 2, 2); between_*: odometry and gaps.
    topology_*: K factors of this frame: current (K, n), previous (K, n), delta
    (K, n, 2), s (K,), sigma (K,).
    """

    vars: IntArray
    ids: IntArray
    previous: IntArray
    delta: FloatArray
    unary_var: IntArray
    unary_z: FloatArray
    unary_cov: FloatArray
    between_a: IntArray
    between_b: IntArray
    between_z: FloatArray
    between_cov: FloatArray
    topology_current: IntArray
    topology_previous: IntArray
    topology_delta: FloatArray
    topology_s: FloatArray
    topology_sigma: FloatArray


def _rows_of(ids: IntArray, batch: Batch | None) -> tuple[IntArray, IntArray]:
    """(rows, vehicle position in `ids`) of the rows of `batch` whose subject is in sorted `ids`."""
    if batch is None or not len(batch) or ids.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    at = np.minimum(np.searchsorted(ids, batch.subject), ids.size - 1)
    rows = np.flatnonzero(ids[at] == batch.subject)
    return rows, at[rows]


class GraphData:
    """A growing factor graph stored as one `FrameFactors` per frame.

    Variables are numbered in the order they are created (step by step, vehicles by id
    within a step). `add_frame` builds one frame's factors with array operations.
    """

    def __init__(self, setup: Setup, kind: str, gap_variance: float,
                 odometry_noise: bool = False) -> None:
        self.setup, self.kind, self.gap_variance = setup, kind, gap_variance
        self.odometry_noise = odometry_noise and kind == NEW
        self.frames: list[FrameFactors] = []
        self.n_vars = 0
        self.n_topology = 0
        self._ids = np.zeros(0, np.int64)
        self._vars = np.zeros(0, np.int64)
        self._pos = np.array(setup.vehicle_layout.position)

    def add_frame(self, frame: Frame) -> FrameFactors:
        """Append the variables and factors of `frame` (see the module docstring)."""
        ids = np.sort(frame.vehicles)
        n = ids.size
        new_vars = self.n_vars + np.arange(n)
        self.n_vars += n
        if np.array_equal(ids, self._ids):  # the usual step: the same vehicles as before
            cont, prev = np.ones(n, bool), self._vars
        else:
            cont = np.isin(ids, self._ids)
            prev = np.full(n, -1, np.int64)
            prev[cont] = self._vars[np.searchsorted(self._ids, ids[cont])]
        # unary: prior on the first variable of each chain, then GPS (eq. 7)
        u_var, u_z, u_cov = [], [], []
        if (~cont).any():
            born = birth_beliefs(self.setup, ids[~cont], frame)
            u_var.append(new_vars[~cont])
            u_z.append(born.mean[:, self._pos])
            u_cov.append(born.cov[:, self._pos[:, None], self._pos[None, :]])
        gnss = frame.batches.get("gnss")
        rows, at = _rows_of(ids, gnss)
        if rows.size:
            u_var.append(new_vars[at])
            u_z.append(gnss.z[rows])
            u_cov.append(gnss.cov[rows])
        # between: odometry of continuing vehicles (eq. 5), a gap factor where there is none
        odometry = frame.batches.get("odometry")
        rows, at = _rows_of(ids, odometry)
        keep = cont[at]
        rows, at = rows[keep], at[keep]
        rows_odometry = rows
        count = np.bincount(at, minlength=n)
        delta = np.full((n, 2), np.nan)
        once = count[at] == 1
        delta[at[once]] = odometry.z[rows[once]] if rows.size else 0.0
        gap = np.flatnonzero(cont & (count == 0))
        b_a = np.concatenate([prev[at], prev[gap]])
        b_b = np.concatenate([new_vars[at], new_vars[gap]])
        b_z = np.concatenate([odometry.z[rows] if rows.size else np.zeros((0, 2)),
                              np.zeros((gap.size, 2))])
        b_cov = np.concatenate([odometry.cov[rows] if rows.size else np.zeros((0, 2, 2)),
                                np.broadcast_to(self.gap_variance * _I2, (gap.size, 2, 2))])
        # topology (eqs. 8 / 11–16): left out unless a radar reports exactly n rows
        t_s, t_sigma = [], []
        radar = frame.batches.get("radar")
        usable = n >= 2 and (self.kind == OLD or bool(cont.all() and (count == 1).all()))
        if usable and radar is not None and len(radar):
            for sensor in np.unique(radar.sensor):
                rows = radar.sensor == sensor
                if rows.sum() != n:
                    continue
                s, var = radar_topology(radar.z[rows], radar.cov[rows])
                if self.odometry_noise:
                    # + Σ_i gᵢᵀ R_odo,i gᵢ, gᵢ = ∂B/∂δ^i = N(p_t^i − p̄_t) ≈ N(r^i − r̄) in the
                    # radar frame; its unknown rotation keeps only the isotropic part tr(R)/2
                    iso = np.trace(odometry.cov[rows_odometry], axis1=1, axis2=2) / 2.0
                    centred = radar.z[rows] - radar.z[rows].mean(axis=0)
                    var += n**2 * float(np.sum(centred**2) * iso.mean())
                if var > 0:
                    t_s.append(s)
                    t_sigma.append(np.sqrt(var))
        K = len(t_s)
        self.n_topology += K
        factors = FrameFactors(
            new_vars, ids, prev, delta,
            np.concatenate(u_var) if u_var else np.zeros(0, np.int64),
            np.concatenate(u_z) if u_z else np.zeros((0, 2)),
            np.concatenate(u_cov) if u_cov else np.zeros((0, 2, 2)),
            b_a, b_b, b_z, b_cov,
            np.repeat(new_vars[None], K, 0),
            np.repeat((prev if self.kind == NEW else new_vars)[None], K, 0),
            np.repeat(np.nan_to_num(delta)[None], K, 0),
            np.array(t_s, float), np.array(t_sigma, float),
        )
        self.frames.append(factors)
        self._ids, self._vars = ids, new_vars
        return factors


def _whitener(cov: FloatArray) -> FloatArray:
    """W (M, 2, 2) with WᵀW = cov⁻¹: W = L⁻¹ for cov = L Lᵀ (triangular solve)."""
    if cov.shape[0] == 0:
        return np.zeros((0, 2, 2))
    L = np.linalg.cholesky(cov)
    return np.linalg.solve(L, np.broadcast_to(_I2, L.shape))


@dataclass(frozen=True)
class _Problem:
    """The graph of `GraphData` as arrays ready for the solver (topology grouped by N)."""

    n_vars: int
    u_var: IntArray
    u_z: FloatArray
    u_W: FloatArray
    b_a: IntArray
    b_b: IntArray
    b_z: FloatArray
    b_W: FloatArray
    topology: tuple[tuple[IntArray, IntArray, FloatArray, FloatArray, FloatArray], ...]
    kind: str
    huber: float

    @classmethod
    def of(cls, data: GraphData, huber: float = 0.0) -> _Problem:
        frames = data.frames

        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(f, name) for f in frames])

        groups: dict[int, list[FrameFactors]] = {}
        for f in frames:
            if f.topology_s.size:
                groups.setdefault(f.vars.size, []).append(f)
        topology = tuple(
            tuple(np.concatenate([getattr(f, "topology_" + part) for f in group])
                  for part in ("current", "previous", "delta", "s", "sigma"))
            for group in groups.values())
        return cls(data.n_vars, cat("unary_var"), cat("unary_z"), _whitener(cat("unary_cov")),
                   cat("between_a"), cat("between_b"), cat("between_z"),
                   _whitener(cat("between_cov")), topology, data.kind, huber)  # type: ignore[arg-type]


def _huber_weights(r: FloatArray, k: float) -> FloatArray:
    """√w of the Huber loss for whitened residuals r (IRLS): 1 inside |r| ≤ k, √(k/|r|) outside."""
    if k <= 0:
        return np.ones_like(r)
    a = np.abs(r)
    return np.where(a <= k, 1.0, np.sqrt(k / np.maximum(a, k)))


def _linearize(problem: _Problem, x: FloatArray, jacobian: bool = True
               ) -> tuple[FloatArray, sp.csr_matrix | None]:
    """Whitened residual r and sparse Jacobian J (rows × 2 n_vars) at positions x (n_vars, 2)."""
    parts_r, rows, cols, vals = [], [], [], []
    offset = 0
    # unary: r = W (x_v − z)
    if problem.u_var.size:
        r = np.einsum("mij,mj->mi", problem.u_W, x[problem.u_var] - problem.u_z)
        parts_r.append(r.ravel())
        if jacobian:
            m = problem.u_var.size
            rr = offset + 2 * np.arange(m)[:, None, None] + np.arange(2)[None, :, None]
            cc = 2 * problem.u_var[:, None, None] + np.arange(2)[None, None, :]
            rows.append(np.broadcast_to(rr, (m, 2, 2)).ravel())
            cols.append(np.broadcast_to(cc, (m, 2, 2)).ravel())
            vals.append(problem.u_W.ravel())
        offset += 2 * problem.u_var.size
    # between: r = W (x_b − x_a − z)
    if problem.b_a.size:
        r = np.einsum("mij,mj->mi", problem.b_W, x[problem.b_b] - x[problem.b_a] - problem.b_z)
        parts_r.append(r.ravel())
        if jacobian:
            m = problem.b_a.size
            rr = np.broadcast_to(offset + 2 * np.arange(m)[:, None, None]
                                 + np.arange(2)[None, :, None], (m, 2, 2)).ravel()
            for var, sign in ((problem.b_a, -1.0), (problem.b_b, 1.0)):
                cc = 2 * var[:, None, None] + np.arange(2)[None, None, :]
                rows.append(rr)
                cols.append(np.broadcast_to(cc, (m, 2, 2)).ravel())
                vals.append(sign * problem.b_W.ravel())
        offset += 2 * problem.b_a.size
    # topology: r = (S(p_t) − s)/σ or (B(p_t, p_{t−1} + δ) − s)/σ, scaled by Huber weights
    for current, previous, delta, s, sigma in problem.topology:
        p = x[current]
        if problem.kind == OLD:
            q = None
            r = (squared_topology(p) - s) / sigma
        else:
            q = x[previous] + delta
            r = (bilinear_topology(p, q) - s) / sigma
        w = _huber_weights(r, problem.huber)
        if jacobian:
            parts_r.append(w * r)  # IRLS: √w r and √w J give the Huber gradient and Hessian
        else:
            # cost-equivalent residual: ½ r_eff² = ρ(r), the Huber loss (k|r| − k²/2 outside)
            k = problem.huber
            outside = (k > 0) & (np.abs(r) > k)
            parts_r.append(np.where(outside, np.sqrt(np.maximum(2 * k * np.abs(r) - k * k, 0.0)), r))
        if jacobian:
            K, n = current.shape
            J_cur, J_prev = topology_jacobians(problem.kind, p, q)
            scale = (w / sigma)[:, None, None]
            rr = np.broadcast_to(offset + np.arange(K)[:, None, None], (K, n, 2)).ravel()
            blocks = [(current, J_cur)] + ([(previous, J_prev)] if J_prev is not None else [])
            for var, J in blocks:
                rows.append(rr)
                cols.append((2 * var[:, :, None] + np.arange(2)).ravel())
                vals.append((scale * J).ravel())
        offset += s.size
    r = np.concatenate(parts_r) if parts_r else np.zeros(0)
    if not jacobian:
        return r, None
    J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(offset, 2 * problem.n_vars))
    return r, J


def _banded(H: sp.spmatrix) -> FloatArray:
    """Upper banded storage ab[u + i − j, j] = H[i, j] (i ≤ j) of a symmetric sparse H."""
    coo = H.tocoo()
    upper = coo.col >= coo.row
    row, col, val = coo.row[upper], coo.col[upper], coo.data[upper]
    u = int((col - row).max()) if row.size else 0
    ab = np.zeros((u + 1, H.shape[0]))
    np.add.at(ab, (u + row - col, col), val)
    return ab


@numba.njit(cache=True)
def _banded_inverse(U: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """Entries of Σ = (UᵀU)⁻¹ inside the band (Takahashi recursion), same storage as U.

    Σ_ij = (δ_ij / U_ii − Σ_{k>i} U_ik Σ_kj) / U_ii for j ≥ i, from the last row up.
    """
    u = U.shape[0] - 1
    n = U.shape[1]
    S = np.zeros_like(U)
    for i in range(n - 1, -1, -1):
        last = min(n - 1, i + u)
        d = U[u, i]
        for j in range(last, i - 1, -1):
            acc = 0.0
            for k in range(i + 1, last + 1):
                a, b = (k, j) if k <= j else (j, k)
                if b - a <= u:
                    acc += U[u + i - k, k] * S[u + a - b, b]
            S[u + i - j, j] = ((1.0 / d if j == i else 0.0) - acc) / d
    return S


@dataclass(frozen=True)
class LMResult:
    """Solution of `solve_lm`: positions (n_vars, 2), marginal covariances (n_vars, 2, 2)."""

    x: FloatArray
    cov: FloatArray | None
    iterations: int
    cost: float


def solve_lm(problem: _Problem, x0: FloatArray, *, max_iterations: int = 100,
             relative_tolerance: float = 1e-5, absolute_tolerance: float = 1e-5,
             lambda_initial: float = 1e-5, covariances: bool = True) -> LMResult:
    """Levenberg–Marquardt on the whitened least squares ½‖r(x)‖² (eq. 17), GTSAM-style.

    Each iteration solves (JᵀJ + λI) Δ = −Jᵀr with one banded Cholesky; a step is kept
    if it lowers the cost (λ ÷ 10), otherwise λ × 10. Stops like GTSAM's defaults: when
    the cost falls by less than `relative_tolerance` (relative) or `absolute_tolerance`.
    """
    x = np.array(x0, dtype=float)
    lam = lambda_initial
    r, J = _linearize(problem, x)

    def cost_at(y: FloatArray) -> float:  # ½ Σ r² with the Huber loss on topology rows
        e = _linearize(problem, y, jacobian=False)[0]
        return 0.5 * float(e @ e)

    cost = cost_at(x)
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 - reported
        H = (J.T @ J).tocsr()
        g = J.T @ r
        ab = _banded(H)
        u = ab.shape[0] - 1
        improved = False
        while lam < 1e10:
            damped = ab.copy()
            damped[u] += lam
            try:
                U = cholesky_banded(damped)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            step = -cho_solve_banded((U, False), g).reshape(-1, 2)
            cost_new = cost_at(x + step)
            if cost_new <= cost:
                x += step
                decrease = cost - cost_new
                cost = cost_new
                lam = max(lam / 10.0, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved:
            break
        r, J = _linearize(problem, x)
        if decrease <= absolute_tolerance or decrease <= relative_tolerance * max(cost, 1e-300):
            break
    cov = None
    if covariances:
        H = (J.T @ J).tocsr()
        U = cholesky_banded(_banded(H))
        S = _banded_inverse(U)
        u = S.shape[0] - 1
        i = np.arange(problem.n_vars)
        cov = np.empty((problem.n_vars, 2, 2))
        cov[:, 0, 0] = S[u, 2 * i]
        cov[:, 1, 1] = S[u, 2 * i + 1]
        cov[:, 0, 1] = cov[:, 1, 0] = S[u - 1, 2 * i + 1]
    return LMResult(x, cov, iterations, cost)


# ----------------------------------------------------------------------------
# GTSAM: the same graph with native factors and Python CustomFactors
# ----------------------------------------------------------------------------


def _topology_custom_factor(kind: str, keys_t: list[int], keys_prev: list[int],
                            delta: FloatArray, s: float, sigma: float, huber: float = 0.0):
    """One GTSAM `CustomFactor` of the old or new topology residual (scalar arithmetic)."""
    import gtsam

    n = len(keys_t)
    dx = [float(v) for v in delta[:, 0]]
    dy = [float(v) for v in delta[:, 1]]
    keys = list(keys_t) + (list(keys_prev) if kind == NEW else [])
    noise = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
    if huber > 0:
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(huber), noise)

    def error(this, values, jacobians):
        px, py = [], []
        for key in keys_t:
            p = values.atPoint2(key)
            px.append(p[0])
            py.append(p[1])
        mpx, mpy = sum(px) / n, sum(py) / n
        if kind == OLD:
            e = n * sum((a - mpx) ** 2 + (b - mpy) ** 2 for a, b in zip(px, py, strict=True)) - s
            if jacobians is not None:
                for i in range(n):
                    jacobians[i] = np.array([[2 * n * (px[i] - mpx), 2 * n * (py[i] - mpy)]])
            return np.array([e])
        qx, qy = [], []
        for i, key in enumerate(keys_prev):
            p = values.atPoint2(key)
            qx.append(p[0] + dx[i])
            qy.append(p[1] + dy[i])
        mqx, mqy = sum(qx) / n, sum(qy) / n
        e = n * sum((px[i] - mpx) * (qx[i] - mqx) + (py[i] - mpy) * (qy[i] - mqy)
                    for i in range(n)) - s
        if jacobians is not None:
            for i in range(n):
                jacobians[i] = np.array([[n * (qx[i] - mqx), n * (qy[i] - mqy)]])
                jacobians[n + i] = np.array([[n * (px[i] - mpx), n * (py[i] - mpy)]])
        return np.array([e])

    return gtsam.CustomFactor(noise, keys, error)


def gtsam_factors(data: GraphData, frames: list[FrameFactors] | None = None, huber: float = 0.0):
    """GTSAM factors of `frames` (default: every frame of `data`) as a NonlinearFactorGraph."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    Gaussian = gtsam.noiseModel.Gaussian.Covariance
    for f in data.frames if frames is None else frames:
        for v, z, cov in zip(f.unary_var.tolist(), f.unary_z, f.unary_cov, strict=True):
            graph.add(gtsam.PriorFactorPoint2(v, z, Gaussian(cov)))
        for a, b, z, cov in zip(f.between_a.tolist(), f.between_b.tolist(), f.between_z,
                                f.between_cov, strict=True):
            graph.add(gtsam.BetweenFactorPoint2(a, b, z, Gaussian(cov)))
        for k in range(f.topology_s.size):
            graph.add(_topology_custom_factor(
                data.kind, f.topology_current[k].tolist(), f.topology_previous[k].tolist(),
                f.topology_delta[k], float(f.topology_s[k]), float(f.topology_sigma[k]), huber))
    return graph


def gtsam_graph(data: GraphData, huber: float = 0.0):
    """The whole graph of `data` as a GTSAM `NonlinearFactorGraph` (reference solver)."""
    return gtsam_factors(data, None, huber)


def _gtsam_values(x: FloatArray):
    import gtsam

    values = gtsam.Values()
    for v, p in enumerate(x):
        values.insert(v, np.asarray(p, float))
    return values


def solve_gtsam(data: GraphData, x0: FloatArray, params: FactorGraphParams,
                covariances: bool = True) -> LMResult:
    """GTSAM's Levenberg–Marquardt on the same graph (Python CustomFactor topology)."""
    import gtsam

    graph = gtsam_graph(data, params.huber)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(params.max_iterations)
    lm.setRelativeErrorTol(params.relative_tolerance)
    lm.setAbsoluteErrorTol(params.absolute_tolerance)
    lm.setlambdaInitial(params.lambda_initial)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, _gtsam_values(x0), lm)
    result = optimizer.optimize()
    x = np.array([result.atPoint2(v) for v in range(data.n_vars)])
    cov = None
    if covariances:
        marginals = gtsam.Marginals(graph, result)
        cov = np.array([marginals.marginalCovariance(v) for v in range(data.n_vars)])
    return LMResult(x, cov, int(optimizer.iterations()), float(graph.error(result)))


# ----------------------------------------------------------------------------
# the per-step filter of the linear part (GPS + odometry), and estimates
# ----------------------------------------------------------------------------


class _PositionFilter:
    """Kalman filter of the graph's linear part per vehicle: p_t = p_{t−1} + δ_t + n, GPS.

    It gives the filtered estimate `step` returns for the batch methods and the initial
    guess of the smoother. A vehicle with several odometry rows in one step is
    predicted with its first row. Cost O(N) per step, batched over vehicles.
    """

    def __init__(self) -> None:
        self.vars = np.zeros(0, np.int64)
        self.mean = np.zeros((0, 2))
        self.cov = np.zeros((0, 2, 2))

    def step(self, f: FrameFactors) -> Gaussians:
        n = f.vars.size
        mean, cov = np.zeros((n, 2)), np.zeros((n, 2, 2))
        cont = f.previous >= 0
        if cont.any():
            at = np.searchsorted(self.vars, f.previous[cont])
            mean[cont], cov[cont] = self.mean[at], self.cov[at]
        # predict with the between rows of this frame: p_t = p_{t−1} + δ_t, P += R
        b = f.between_b - (f.vars[0] if n else 0)
        first = slice(None) if np.array_equal(b, np.arange(n)) else np.unique(b, return_index=True)[1]
        mean[b[first]] += f.between_z[first]
        cov[b[first]] += f.between_cov[first]
        # unary rows: the first row of a new chain is its birth prior (the belief); the
        # other rows (GPS) update it, in rounds of distinct vehicles (one round usually)
        target = f.unary_var - (f.vars[0] if n else 0)
        if cont.all() and np.array_equal(target, np.arange(n)):  # one fix per vehicle, in order
            upd = kf_update(Gaussians(mean, cov), f.unary_z, _I2, f.unary_cov)
            self.vars, self.mean, self.cov = f.vars, upd.mean, upd.cov
            return upd
        rows = np.arange(target.size)
        born = ~cont[target]
        if born.any():
            first = np.unique(target[born], return_index=True)[1]
            prior_rows = rows[born][first]
            mean[target[prior_rows]] = f.unary_z[prior_rows]
            cov[target[prior_rows]] = f.unary_cov[prior_rows]
            rows = np.setdiff1d(rows, prior_rows)
        while rows.size:
            i, first = np.unique(target[rows], return_index=True)
            r = rows[first]
            upd = kf_update(Gaussians(mean[i], cov[i]), f.unary_z[r], _I2, f.unary_cov[r])
            mean[i], cov[i] = upd.mean, upd.cov
            rows = np.setdiff1d(rows, r)
        self.vars, self.mean, self.cov = f.vars, mean, cov
        return Gaussians(mean, cov)


class _Estimates:
    """Builds `Estimate`s in the setup's layout: positions, velocities, block-diagonal cov."""

    def __init__(self, setup: Setup) -> None:
        layout = setup.vehicle_layout
        self.dim, self.dt = layout.dim, setup.dt
        self.pos = np.array(layout.position)
        self.vel = None if layout.velocity is None else np.array(layout.velocity)
        odometry = setup.sensors.get("odometry")
        R = getattr(odometry, "default_cov", None)
        self.odometry_cov = _I2 if R is None else np.asarray(R)
        self.base_cov = 1e4 * np.eye(self.dim)  # components the graph does not estimate

    def filtered_velocity(self, delta: FloatArray) -> tuple[FloatArray, FloatArray]:
        """δ_t / T with R_odo / T² where a vehicle has one odometry row; 0, broad otherwise."""
        have = np.isfinite(delta).all(axis=1)
        vel = np.where(have[:, None], delta / self.dt, 0.0)
        cov = np.where(have[:, None, None], self.odometry_cov / self.dt**2, 100.0 * _I2)
        return vel, cov

    def build(self, ids: IntArray, pos: FloatArray, pos_cov: FloatArray, vel: FloatArray,
              vel_cov: FloatArray, info: dict[str, Any]) -> Estimate:
        n = ids.size
        mean = np.zeros((n, self.dim))
        cov = np.repeat(self.base_cov[None], n, axis=0)
        mean[:, self.pos] = pos
        cov[:, self.pos[:, None], self.pos[None, :]] = pos_cov
        if self.vel is not None:
            mean[:, self.vel] = vel
            cov[:, self.vel[:, None], self.vel[None, :]] = vel_cov
        return Estimate(StateSet(ids, mean, cov), info=info)


# ----------------------------------------------------------------------------
# estimators
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class FactorGraphParams(Params):
    """Batch factor-graph settings (defaults: GTSAM's LM defaults).

    Attributes
    ----------
    solver : "sparse" (our banded LM, default) or "gtsam" (GTSAM's LM with Python
        CustomFactors: the reference, slower).
    max_iterations, relative_tolerance, absolute_tolerance, lambda_initial : LM settings.
    gap_variance : m², between-factor covariance per axis where odometry is missing.
    huber : Huber threshold (σ units) on topology factors; 0 = plain Gaussian (paper).
    topology_odometry_noise : new factor only — add the odometry noise to σ_s (module
        docstring); False = radar noise only (paper, eqs. 14–16).
    """

    solver: str = param("sparse", choices=("sparse", "gtsam"))
    max_iterations: int = param(100, ge=1)
    relative_tolerance: float = param(1e-5, gt=0)
    absolute_tolerance: float = param(1e-5, gt=0)
    lambda_initial: float = param(1e-5, gt=0)
    gap_variance: float = param(900.0, gt=0)
    huber: float = param(0.0, ge=0)
    topology_odometry_noise: bool = False


class _BatchGraph:
    """Shared body of the two batch estimators (see the module docstring)."""

    kind: ClassVar[str]
    Params: ClassVar[type[Params]] = FactorGraphParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "gulati-2v"
    required_sensors: ClassVar[tuple[str, ...]] = ("gnss", "odometry")

    def __init__(self, setup: Setup, params: FactorGraphParams, rng: np.random.Generator) -> None:
        self.setup, self.params = setup, params
        _banded_inverse(np.ones((1, 1)))  # compile (or load from cache) here, not in smooth()
        self.data = GraphData(setup, self.kind, params.gap_variance, params.topology_odometry_noise)
        self.filter = _PositionFilter()
        self.estimates = _Estimates(setup)
        self.initial: list[FloatArray] = []   # filtered positions: the smoother's start

    def step(self, frame: Frame) -> Estimate:
        """Add the frame's factors; return the filtered estimate of GPS + odometry."""
        f = self.data.add_frame(frame)
        belief = self.filter.step(f)
        self.initial.append(belief.mean)
        vel, vel_cov = self.estimates.filtered_velocity(f.delta)
        return self.estimates.build(f.ids, belief.mean, belief.cov, vel, vel_cov,
                                    {"filtered": True, "topology": self.data.n_topology})

    def solve(self) -> LMResult:
        """Solve the whole graph (positions and marginal covariances of every variable)."""
        x0 = np.concatenate(self.initial) if self.initial else np.zeros((0, 2))
        p = self.params
        if self.data.n_vars == 0:
            return LMResult(x0, np.zeros((0, 2, 2)), 0, 0.0)
        if p.solver == "gtsam":
            return solve_gtsam(self.data, x0, p)
        return solve_lm(_Problem.of(self.data, p.huber), x0, max_iterations=p.max_iterations,
                        relative_tolerance=p.relative_tolerance,
                        absolute_tolerance=p.absolute_tolerance, lambda_initial=p.lambda_initial)

    def smooth(self) -> list[Estimate]:
        """Smoothed estimate of every step so far (one LM solve of the whole graph)."""
        result = self.solve()
        x, cov = result.x, result.cov
        assert cov is not None
        info = {"smoothed": True, "iterations": result.iterations, "cost": result.cost,
                "topology": self.data.n_topology}
        out = []
        dt = self.setup.dt
        for f in self.data.frames:
            vel, vel_cov = self.estimates.filtered_velocity(f.delta)
            cont = f.previous >= 0  # finite difference of smoothed positions
            vel[cont] = (x[f.vars[cont]] - x[f.previous[cont]]) / dt
            vel_cov[cont] = (cov[f.vars[cont]] + cov[f.previous[cont]]) / dt**2
            out.append(self.estimates.build(f.ids, x[f.vars], cov[f.vars], vel, vel_cov, info))
        return out


@dataclass(frozen=True)
class FgTopologyOldParams(FactorGraphParams):
    """`fg-topology-old` settings (see `FactorGraphParams`)."""


@dataclass(frozen=True)
class FgTopologyNewParams(FactorGraphParams):
    """`fg-topology-new` settings (see `FactorGraphParams`)."""


@register_estimator
class FgTopologyOld(_BatchGraph):
    """Batch LM on GPS, odometry and the old topology factor (eq. 8, Gulati 2016)."""

    name: ClassVar[str] = "fg-topology-old"
    Params: ClassVar[type[Params]] = FgTopologyOldParams
    summary: ClassVar[str] = "factor graph, GPS + odometry + old topology factor (eq. 8), batch LM"
    kind: ClassVar[str] = OLD


@register_estimator
class FgTopologyNew(_BatchGraph):
    """Batch LM on GPS, odometry and the new topology factor (eqs. 9–16)."""

    name: ClassVar[str] = "fg-topology-new"
    Params: ClassVar[type[Params]] = FgTopologyNewParams
    summary: ClassVar[str] = "factor graph, GPS + odometry + new topology factor (eqs. 9–16), batch LM"
    kind: ClassVar[str] = NEW


@dataclass(frozen=True)
class ISAM2Params(Params):
    """iSAM2 settings (defaults: GTSAM's).

    Attributes
    ----------
    relinearize_threshold : relinearise a variable whose update exceeds this (m).
    relinearize_skip : check for relinearisation every this many updates.
    gap_variance, huber, topology_odometry_noise : as for the batch estimators.
    """

    relinearize_threshold: float = param(0.1, gt=0)
    relinearize_skip: int = param(10, ge=1)
    gap_variance: float = param(900.0, gt=0)
    huber: float = param(0.0, ge=0)
    topology_odometry_noise: bool = False


@register_estimator
class FgIsam2:
    """The new-factor graph, updated incrementally with GTSAM's iSAM2; filtered estimates."""

    name: ClassVar[str] = "fg-isam2"
    summary: ClassVar[str] = "factor graph with the new topology factor, incremental iSAM2 (filtered)"
    Params: ClassVar[type[Params]] = ISAM2Params
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "gulati-2v"
    required_sensors: ClassVar[tuple[str, ...]] = ("gnss", "odometry")

    def __init__(self, setup: Setup, params: ISAM2Params, rng: np.random.Generator) -> None:
        import gtsam

        self.setup, self.params = setup, params
        self.data = GraphData(setup, NEW, params.gap_variance, params.topology_odometry_noise)
        self.estimates = _Estimates(setup)
        isam_params = gtsam.ISAM2Params()
        isam_params.setRelinearizeThreshold(params.relinearize_threshold)
        isam_params.relinearizeSkip = params.relinearize_skip
        self.isam = gtsam.ISAM2(isam_params)
        self._gtsam = gtsam
        self._last_vars = np.zeros(0, np.int64)
        self._last = np.zeros((0, 2))

    def step(self, frame: Frame) -> Estimate:
        f = self.data.add_frame(frame)
        vel, vel_cov = self.estimates.filtered_velocity(f.delta)
        n = f.vars.size
        if n == 0:
            return self.estimates.build(f.ids, np.zeros((0, 2)), np.zeros((0, 2, 2)), vel, vel_cov,
                                        {"filtered": True})
        # initial guess: last estimate + odometry; else the last unary row (GPS or prior)
        initial = np.zeros((n, 2))
        cont = f.previous >= 0
        if cont.any():
            initial[cont] = self._last[np.searchsorted(self._last_vars, f.previous[cont])]
        initial += np.nan_to_num(f.delta)
        unary = f.unary_var - f.vars[0]
        no_odometry = ~np.isfinite(f.delta).all(axis=1)
        rows = np.flatnonzero(no_odometry[unary])
        initial[unary[rows]] = f.unary_z[rows]
        values = self._gtsam.Values()
        for v, p in zip(f.vars.tolist(), initial, strict=True):
            values.insert(v, p)
        self.isam.update(gtsam_factors(self.data, [f], self.params.huber), values)
        keys = f.vars.tolist()
        pos = np.array([self.isam.calculateEstimatePoint2(v) for v in keys])
        cov = np.array([self.isam.marginalCovariance(v) for v in keys])
        cov = 0.5 * (cov + cov.transpose(0, 2, 1))
        self._last_vars, self._last = f.vars, pos
        return self.estimates.build(f.ids, pos, cov, vel, vel_cov,
                                    {"filtered": True, "topology": self.data.n_topology})
