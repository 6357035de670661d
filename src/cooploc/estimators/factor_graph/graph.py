r"""The factor graph of Gulati et al. 2017 as arrays, and its linearisation for `least_squares`.

Paper: Gulati et al., "Graph Based Vehicle Infrastructure Cooperative Localization"
(IV 2017), §III: eqs. 1–3 (the graph and its MAP estimate), 4–7 (odometry and GPS
factors), 8–16 (topology factors, `factors.py`; derivation: docs/factor_graph.md),
17–18 (the whitened least squares and its Jacobians).

Model
-----
One variable per vehicle and step: its 2-D position p_t^i (no velocity and no motion
model, as in the paper). Factors, each a Gaussian residual:

- prior (unary): the first variable of every vehicle's chain gets its prior position
  (the vehicle prior of the setup, or a broad one centred on its first GPS fix:
  `base.birth_beliefs`);
- GPS (unary, eqs. 6–7): p_t^i − z_t^g, covariance of the fix; the paper's GPS measures
  the position only. Where the setup's GNSS rows hold more (`sumo-*`'s z = [p, v] + w),
  the factor takes each row's exact position marginal, z_p = p + w_p with the position
  block of its covariance (`base.position_fixes`);
- GNSS velocity (between, not in the paper): where the rows also hold the velocity
  (`sumo-*`, σ_v ≈ 0.1–0.45 m/s against σ_p = 3–15 m), a vehicle with one row at t − 1
  and at t gets the displacement the setup's motion model predicts from the two
  velocities, E[p_t − p_{t−1} | v_{t−1}, v_t] = A v_{t−1} + G v_t with
  G = Q_pv Q_vv⁻¹ and A = F_pv − G F_vv (constant velocity: the trapezoid
  T (v_{t−1} + v_t)/2), covariance Q_pp − G Q_vp (CV: q T³/12 I) plus the rows'
  velocity noise A R_{t−1} Aᵀ + G R_t Gᵀ — doubled, because each row enters the two
  factors on either side of it (its information split between them keeps the graph
  from counting it twice). Needs a motion model whose positions integrate the
  velocities (F_pp = I, F_vp = 0); rows whose position and velocity noise are
  correlated give none (the factor would be correlated with the GPS factor); off with
  `gnss_velocity=False`. Without these factors the graph had
  only odometry (σ = 1 m per step on `sumo-*`) between steps, and the filtered
  `fg-isam2` was worse than `gnss-kf`, which uses the velocity;
- odometry (between, eqs. 4–5): (p_t^i − p_{t−1}^i) − δ_t^i, covariance of the row;
  where a vehicle present at t − 1 and t has neither an odometry row nor a velocity
  factor, a *gap* factor with zero displacement and covariance `gap_variance` · I keeps
  its chain connected;
- topology (one scalar factor per radar and step, `factors.py`). In the papers' setup
  (one radar, unbounded all-around field: `road_radars.sees_every_vehicle`) the factor
  joins every present vehicle and is left out at every step where the radar does not
  report exactly as many rows as there are vehicles present (the paper's "plug and
  play" remark, §IV-B; missed detections and clutter are its future work); the new
  factor is also left out where a vehicle has no single odometry row (first step, a
  vehicle that just entered).
- per-radar topology (traffic, `sumo-*`: several radars of finite range, each seeing a
  few vehicles; `add_radar_topology`): the factor of each radar joins the vehicles *it*
  sees, found by `road_radars.RadarFields` from the estimator's beliefs of the step
  (the linear part's filter, never the truth): the radar's unknown pose registered and
  tracked from its rows, the in-view set taken only when it is the right one with
  probability ≥ `view_confidence`, and the measured topology within the χ²₁ gate
  (`gate_probability`) of its prediction (`road_radars.topology_nis`). A radar is
  skipped, with the reason in `radar_skipped` (``Estimate.info["radar_skipped"]``),
  when its set is uncertain, has fewer than two vehicles, fails the gate, or (new
  factor) holds a vehicle without a single odometry row. Vehicles that enter start a
  chain (prior and GPS) and join factors once seen; those that leave end theirs.

The problem, the values and the optimizer are kept apart as in GTSAM: `GraphData` is
the growing graph (one `FrameFactors` per frame); `GraphProblem` is its residuals in
arrays, whitened (eq. 17), with the `linearize` callable `cooploc.least_squares.solve_lm`
takes; the values are a plain (n_vars, 2) array of positions.

Variables are numbered step by step, so JᵀJ is banded (bandwidth < 2N per variable
block). `add_frame` is O(N) per step; `linearize` evaluates all factors of a kind in one
vectorised NumPy expression, O(T N) for T steps. The robust option (`huber` > 0,
threshold in σ units) applies the Huber loss to the topology factors only.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from cooploc.estimators.base import birth_beliefs, gnss_position_part, position_fixes
from cooploc.estimators.factor_graph.factors import (
    NEW,
    OLD,
    bilinear_topology,
    odometry_topology_variance,
    radar_topology,
    squared_topology,
    topology_jacobians,
)
from cooploc.estimators.road_radars import RadarFields, sees_every_vehicle, topology_nis
from cooploc.least_squares import huber_cost_residual, huber_sqrt_weights, whitener
from cooploc.sensors import InfrastructureRadar
from cooploc.types import Batch, FloatArray, Frame, IntArray, Setup

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = ["FrameFactors", "GraphData", "GraphProblem", "velocity_factor_model"]

_I2 = np.eye(2)


@dataclass(frozen=True)
class FrameFactors:
    """The variables and factors one frame adds to the graph (rows are factors).

    vars, ids, previous (n,): new variable per present vehicle (by id), its id, and the
    variable of the same vehicle at the previous step (−1: a new chain).
    delta (n, 2): the vehicle's odometry row, NaN unless it has exactly one.
    unary_*: priors and GPS (M,), (M, 2), (M, 2, 2); between_*: odometry and gaps.
    topology_*: K factors of this frame, each over the m_k vehicles its radar sees
    (every present vehicle in the papers' setup): current, previous (K tuples of (m_k,)),
    delta (K tuples of (m_k, 2)), s (K,), sigma (K,).
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
    topology_current: tuple[IntArray, ...]
    topology_previous: tuple[IntArray, ...]
    topology_delta: tuple[FloatArray, ...]
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

    Parameters
    ----------
    setup : the recording's setup (vehicle layout, priors).
    kind : `OLD` or `NEW` topology factor.
    gap_variance : m², between-factor covariance per axis where odometry is missing.
    odometry_noise : new factor only — add `odometry_topology_variance` to σ_s².
    gnss_velocity : add the GNSS velocity factors where the rows hold the velocity.
    view_confidence, gate_probability : per-radar mode (module docstring): least
        probability of a radar's in-view set; χ² gate of a row against a belief and of
        the measured topology against its prediction.
    keep_frames : how many of the latest frames' factors `frames` keeps: None (every
        frame) for the batch solvers, which re-solve the whole graph; a window for an
        incremental solver that hands each frame to its backend once — memory then stays
        flat over a long run.
    """

    def __init__(self, setup: Setup, kind: str, gap_variance: float,
                 odometry_noise: bool = False, name: str = "the factor graph",
                 gnss_velocity: bool = True, view_confidence: float = 0.9,
                 gate_probability: float = 0.9999, keep_frames: int | None = None) -> None:
        self.setup, self.kind, self.gap_variance = setup, kind, gap_variance
        self.keep_frames = keep_frames
        self.odometry_noise = odometry_noise and kind == NEW
        self.frames: list[FrameFactors] = []
        self.n_vars = 0
        self.n_topology = 0
        self._ids = np.zeros(0, np.int64)
        self._vars = np.zeros(0, np.int64)
        self._pos = np.array(setup.vehicle_layout.position)
        self._gnss_part = gnss_position_part(setup, name)
        self._velocity = velocity_factor_model(setup) if gnss_velocity else None
        radar = setup.sensors.get("radar")
        #: per-radar mode (traffic): the radars' estimated poses and in-view sets
        from scipy.stats import chi2  # here, not at import: `import cooploc` stays light

        self.fields = (RadarFields(radar, chi2.ppf(gate_probability, df=2), view_confidence)
                       if isinstance(radar, InfrastructureRadar) and not sees_every_vehicle(setup) else None)
        self._gate_1 = chi2.ppf(gate_probability, df=1)
        self.radar_skipped: dict[int, str] = {}   # of the last frame: radar id → why
        self._v = np.zeros((0, 2))           # each present vehicle's GNSS velocity (NaN: none)
        self._v_cov = np.zeros((0, 2, 2))

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
        gnss = position_fixes(frame.batches.get("gnss"), self._gnss_part)
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
        v_at, v_z, v_cov = self._velocity_factors(ids, cont, frame.batches.get("gnss"))
        gap = np.flatnonzero(cont & (count == 0) & ~np.isin(np.arange(n), v_at))
        b_a = np.concatenate([prev[at], prev[v_at], prev[gap]])
        b_b = np.concatenate([new_vars[at], new_vars[v_at], new_vars[gap]])
        b_z = np.concatenate([odometry.z[rows] if rows.size else np.zeros((0, 2)), v_z,
                              np.zeros((gap.size, 2))])
        b_cov = np.concatenate([odometry.cov[rows] if rows.size else np.zeros((0, 2, 2)), v_cov,
                                np.broadcast_to(self.gap_variance * _I2, (gap.size, 2, 2))])
        # topology (eqs. 8 / 11–16): left out unless a radar reports exactly n rows
        t_s, t_sigma = [], []
        radar = frame.batches.get("radar")
        usable = n >= 2 and (self.kind == OLD or bool(cont.all() and (count == 1).all()))
        if self.fields is None and usable and radar is not None and len(radar):
            for sensor in np.unique(radar.sensor):
                rows = radar.sensor == sensor
                if rows.sum() != n:
                    continue
                s, var = radar_topology(radar.z[rows], radar.cov[rows])
                if self.odometry_noise:
                    var += odometry_topology_variance(radar.z[rows], odometry.cov[rows_odometry])
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
            (new_vars,) * K, ((prev if self.kind == NEW else new_vars),) * K,
            (np.nan_to_num(delta),) * K, np.array(t_s, float), np.array(t_sigma, float),
        )
        self.frames.append(factors)
        if self.keep_frames is not None and len(self.frames) > self.keep_frames:
            del self.frames[:-self.keep_frames]
        self._ids, self._vars = ids, new_vars
        return factors

    def add_radar_topology(self, frame: Frame, mean: FloatArray, cov: FloatArray) -> FrameFactors:
        """Per-radar mode (traffic, module docstring): add to the last frame one topology
        factor per radar over the vehicles it sees, found from the estimator's beliefs of
        the frame's vehicles, mean (n, 2) and cov (n, 2, 2) (never the truth); the frame's
        factors. Radars left out and why: `radar_skipped`. No-op in the papers' setup."""
        f = self.frames[-1]
        self.radar_skipped = {}
        radar = frame.batches.get("radar")
        if self.fields is None or radar is None or not len(radar) or f.vars.size == 0:
            return f
        var = np.einsum("nii->n", cov) / 2
        odometry_cov = None
        if self.odometry_noise:
            odometry = frame.batches.get("odometry")
            odometry_cov = odometry.cov if odometry is not None and len(odometry) else None
        chained = (f.previous >= 0) & np.isfinite(f.delta).all(axis=1)
        current, previous, deltas, t_s, t_sigma = [], [], [], [], []
        for sensor in np.unique(radar.sensor).tolist():
            rows = radar.sensor == sensor
            q = radar.z[rows]
            seen, reason = self.fields.in_view(sensor, q, mean, var)
            if seen is not None and seen.size < 2:
                seen, reason = None, "fewer than two vehicles in view (the topology is then 0)"
            if seen is not None and self.kind == NEW and not chained[seen].all():
                seen, reason = None, "a vehicle it sees has no single odometry row (new factor)"
            if seen is not None:
                s, s_var = radar_topology(q, radar.cov[rows])
                radar_var = float(np.einsum("mii->m", radar.cov[rows]).mean() / 2)
                if topology_nis(mean[seen], var[seen], s, radar_var) > self._gate_1:
                    seen, reason = None, "its topology lies outside the gate of the beliefs"
            if seen is None:
                self.radar_skipped[sensor] = reason
                continue
            if odometry_cov is not None:
                s_var += odometry_topology_variance(q, odometry_cov)
            if s_var <= 0:
                continue
            current.append(f.vars[seen])
            previous.append(f.previous[seen] if self.kind == NEW else f.vars[seen])
            deltas.append(np.nan_to_num(f.delta[seen]))
            t_s.append(s)
            t_sigma.append(np.sqrt(s_var))
        if not t_s:
            return f
        self.n_topology += len(t_s)
        f = dataclasses.replace(
            f, topology_current=f.topology_current + tuple(current),
            topology_previous=f.topology_previous + tuple(previous),
            topology_delta=f.topology_delta + tuple(deltas),
            topology_s=np.concatenate([f.topology_s, t_s]),
            topology_sigma=np.concatenate([f.topology_sigma, t_sigma]))
        self.frames[-1] = f
        return f

    def _velocity_factors(self, ids: IntArray, cont: npt.NDArray[np.bool_], gnss: Batch | None
                          ) -> tuple[IntArray, FloatArray, FloatArray]:
        """The GNSS velocity factors of this frame (module docstring): the vehicles (positions
        in `ids`) that get one, their displacements (m, 2) and covariances (m, 2, 2)."""
        n = ids.size
        v, v_cov = np.full((n, 2), np.nan), np.zeros((n, 2, 2))
        if self._velocity is not None:
            part = self._velocity[0]
            rows, at = _rows_of(ids, gnss)
            once = np.bincount(at, minlength=n)[at] == 1
            if once.any():  # rows with position-velocity cross terms would correlate the factors
                assert gnss is not None
                p_part = np.setdiff1d(np.arange(gnss.z.shape[1]), part)
                once &= ~gnss.cov[rows][:, p_part[:, None], part[None, :]].any(axis=(1, 2))
            if once.any():
                assert gnss is not None
                fixes = gnss.components(part)
                v[at[once]], v_cov[at[once]] = fixes.z[rows[once]], fixes.cov[rows[once]]
        before = np.full((n, 2), np.nan)
        before_cov = np.zeros((n, 2, 2))
        if cont.any() and self._v.size:
            i = np.searchsorted(self._ids, ids[cont])
            before[cont], before_cov[cont] = self._v[i], self._v_cov[i]
        self._v, self._v_cov = v, v_cov
        use = np.flatnonzero(np.isfinite(v).all(1) & np.isfinite(before).all(1))
        if use.size == 0:
            return use, np.zeros((0, 2)), np.zeros((0, 2, 2))
        _, A, G, Q_c = self._velocity  # type: ignore[misc]
        z = before[use] @ A.T + v[use] @ G.T
        # each velocity row is in two factors: its information is split between them (×2)
        cov = Q_c + 2.0 * (A @ before_cov[use] @ A.T + G @ v_cov[use] @ G.T)
        return use, z, cov


def velocity_factor_model(setup: Setup) -> tuple[IntArray, FloatArray, FloatArray, FloatArray] | None:
    """What the GNSS velocity factors need (module docstring), or None where they do not apply:
    the velocity components of the GNSS rows, A, G (2, 2) and the conditional Q_pp − G Q_vp.

    None where the rows hold no velocity, the layout has none, the motion model's positions
    do not integrate its velocities (F_pp = I, F_vp = 0) or its noise is state dependent.
    """
    layout, sensor = setup.vehicle_layout, setup.sensors.get("gnss")
    if layout.velocity is None or sensor is None:
        return None
    cols = list(getattr(sensor, "state_indices", layout.position))
    pos, vel = list(layout.position), list(layout.velocity)
    if not set(vel) <= set(cols) or not set(pos) <= set(cols):
        return None
    F = setup.vehicle_motion.transition_matrix(setup.dt)
    Q = setup.vehicle_motion.noise_covariance(setup.dt)
    if Q.ndim != 2 or not (np.array_equal(F[np.ix_(pos, pos)], _I2) and not F[np.ix_(vel, pos)].any()):
        return None
    part = np.array([cols.index(c) for c in vel], dtype=np.int64)
    Q_vv, Q_pv = Q[np.ix_(vel, vel)], Q[np.ix_(pos, vel)]
    G = np.linalg.solve(Q_vv.T, Q_pv.T).T                                   # Q_pv Q_vv⁻¹
    A = F[np.ix_(pos, vel)] - G @ F[np.ix_(vel, vel)]
    return part, A, G, Q[np.ix_(pos, pos)] - G @ Q_pv.T


@dataclass(frozen=True)
class GraphProblem:
    """The graph of `GraphData` as whitened arrays (topology grouped by N), ready to linearise.

    `GraphProblem.of(data, huber).linearize` is the problem `least_squares.solve_lm` takes.
    """

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
    def of(cls, data: GraphData, huber: float = 0.0) -> GraphProblem:
        """The problem of every frame of `data`; `huber` > 0: Huber loss on topology factors (σ)."""
        frames = data.frames

        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(f, name) for f in frames])

        # factors grouped by how many vehicles they join, each group stacked (K_m, m)
        groups: dict[int, list[tuple]] = {}
        for f in frames:
            for k in range(f.topology_s.size):
                groups.setdefault(f.topology_current[k].size, []).append(
                    (f.topology_current[k], f.topology_previous[k], f.topology_delta[k],
                     f.topology_s[k], f.topology_sigma[k]))
        topology = tuple(tuple(np.array(part) for part in zip(*group, strict=True))
                         for group in groups.values())
        return cls(data.n_vars, cat("unary_var"), cat("unary_z"), whitener(cat("unary_cov")),
                   cat("between_a"), cat("between_b"), cat("between_z"),
                   whitener(cat("between_cov")), topology, data.kind, huber)  # type: ignore[arg-type]

    def linearize(self, x: FloatArray, jacobian: bool = True) -> tuple[FloatArray, sp.csr_matrix | None]:
        """Whitened residual r and sparse Jacobian J (rows × 2 n_vars) at positions x (n_vars, 2).

        `jacobian=False`: the cost-equivalent residual (Huber on topology rows) and None,
        the contract of `cooploc.least_squares.Linearize`.
        """
        import scipy.sparse as sp

        parts_r, rows, cols, vals = [], [], [], []
        offset = 0
        # unary (priors, GPS): r = W (x_v − z)                              eq. (7)
        if self.u_var.size:
            r = np.einsum("mij,mj->mi", self.u_W, x[self.u_var] - self.u_z)
            parts_r.append(r.ravel())
            if jacobian:
                m = self.u_var.size
                rr = offset + 2 * np.arange(m)[:, None, None] + np.arange(2)[None, :, None]
                cc = 2 * self.u_var[:, None, None] + np.arange(2)[None, None, :]
                rows.append(np.broadcast_to(rr, (m, 2, 2)).ravel())
                cols.append(np.broadcast_to(cc, (m, 2, 2)).ravel())
                vals.append(self.u_W.ravel())
            offset += 2 * self.u_var.size
        # between: r = W (x_b − x_a − z)                                    eq. (5)
        if self.b_a.size:
            r = np.einsum("mij,mj->mi", self.b_W, x[self.b_b] - x[self.b_a] - self.b_z)
            parts_r.append(r.ravel())
            if jacobian:
                m = self.b_a.size
                rr = np.broadcast_to(offset + 2 * np.arange(m)[:, None, None]
                                     + np.arange(2)[None, :, None], (m, 2, 2)).ravel()
                for var, sign in ((self.b_a, -1.0), (self.b_b, 1.0)):
                    cc = 2 * var[:, None, None] + np.arange(2)[None, None, :]
                    rows.append(rr)
                    cols.append(np.broadcast_to(cc, (m, 2, 2)).ravel())
                    vals.append(sign * self.b_W.ravel())
            offset += 2 * self.b_a.size
        # topology: r = (S(p_t) − s)/σ or (B(p_t, p_{t−1} + δ) − s)/σ, scaled by Huber weights
        for current, previous, delta, s, sigma in self.topology:
            p = x[current]
            if self.kind == OLD:
                q = None
                r = (squared_topology(p) - s) / sigma                      # eq. (8)
            else:
                q = x[previous] + delta
                r = (bilinear_topology(p, q) - s) / sigma                  # eqs. (11)–(13)
            w = huber_sqrt_weights(r, self.huber)
            if jacobian:
                parts_r.append(w * r)  # IRLS: √w r and √w J give the Huber gradient and Hessian
            else:
                parts_r.append(huber_cost_residual(r, self.huber))
            if jacobian:
                K, n = current.shape
                J_cur, J_prev = topology_jacobians(self.kind, p, q)
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
                          shape=(offset, 2 * self.n_vars))
        return r, J
