r"""The smoother of `oracle-pose`: every state of every step and the radar poses in one least squares.

Unknowns: x_v (dx) for every vehicle and step it is present (numbered step by step,
as `PoseFilter` numbers them), and the border b = [b_1; …; b_P] of the radar poses
the filter estimated. The MAP estimate minimises the sum of whitened squared
residuals (Gaussian factors):

- prior, where a vehicle's chain starts: x_v − m₀ with the `birth_beliefs` covariance;
- motion, between consecutive steps of a vehicle: x_b − F x_a with covariance Q;
- GNSS: H x_v − z; odometry: H x_b − H x_a − z;
- radar: R(θ_s)ᵀ(H x_v − t_s) − z (`rows.radar_model`), or with the pose a constant
  (`known_pose`);
- the diffuse pose prior of the filter: b_s − c_s (`PoseFilter`, step 4).

It is solved by `cooploc.least_squares.solve_lm_bordered` (banded LM with the poses as
border, Schur complement; marginals from the selected inverse), started from the
filtered means and poses, or by `solve_lm` where every pose is known. Exactly the
rows the filter uses are fused, plus the radar rows the filter saw before a radar's
pose entered its state. A motion model without process noise gets Q + 1e-9 I so that
it can be whitened. Cost: O(T n dx u²) per iteration for T steps and bandwidth u ≈
2 n dx, plus O(T n dx u P) for the border.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cooploc.estimators.oracle_pose.rows import Models, StepRecord, radar_model
from cooploc.geometry import fit_pose
from cooploc.least_squares import LMResult, solve_lm, solve_lm_bordered, whitener
from cooploc.types import FloatArray, IntArray

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = ["PoseSmoother", "initial_poses"]

_Q_JITTER = 1e-9


@dataclass(frozen=True)
class _Linear:
    """M factors r = W (Σ_j A_j x_{var_j} − z) on variables of the band, of dz rows each."""

    vars: tuple[IntArray, ...]
    A: tuple[FloatArray, ...]
    z: FloatArray
    W: FloatArray


def initial_poses(history: Sequence[StepRecord], models: Models) -> dict[int, FloatArray]:
    """Radar id → the rigid fit (`geometry.fit_pose`) of all its rows to the positions of
    the initial guess (each record's mean), for radars whose rows are not all one point."""
    local: dict[int, list[FloatArray]] = {}
    world: dict[int, list[FloatArray]] = {}
    for h in history:
        d = h.rows.radar
        p = h.mean[d.at] @ models.H_radar.T
        for sensor in np.unique(d.sensor):
            rows = d.sensor == sensor
            local.setdefault(int(sensor), []).append(d.z[rows])
            world.setdefault(int(sensor), []).append(p[rows])
    out = {}
    for sensor, parts in sorted(local.items()):
        z = np.concatenate(parts)
        if z.shape[0] >= 2 and np.ptp(z, axis=0).max() > 0:
            out[sensor] = fit_pose(np.concatenate(world[sensor]), z)
    return out


class PoseSmoother:
    """The batch problem of the module docstring over the steps of `history`.

    Parameters
    ----------
    history : the chains' records (rows, variables, chain starts, initial guess).
    models : F, Q and the observation matrices.
    poses : radar id → initial pose, for the radars whose pose is estimated.
    centres : radar id → centre of its diffuse prior (default: `poses`).
    pose_prior_cov : (3, 3) that prior's covariance.
    known : radar id → pose held fixed (then `poses` is ignored), or None.
    """

    def __init__(self, history: Sequence[StepRecord], models: Models, poses: dict[int, FloatArray],
                 pose_prior_cov: FloatArray, known: dict[int, FloatArray] | None = None,
                 centres: dict[int, FloatArray] | None = None) -> None:
        dx = models.dim
        self.dx = dx
        self.n_vars = int(sum(h.vars.size for h in history))
        self.known = known
        self.x0 = np.concatenate([h.mean for h in history]) if history else np.zeros((0, dx))
        self.pose_ids = [] if known is not None else sorted(poses)
        self.b0 = np.concatenate([poses[s] for s in self.pose_ids]) if self.pose_ids else np.zeros(0)
        centres = poses if centres is None else centres
        Q = models.motion.noise_covariance(models.dt)
        I = np.eye(dx)
        prior_v, prior_z, prior_cov = [], [], []
        gnss_v, gnss_z, gnss_cov = [], [], []
        motion_a, motion_b = [], []
        odo_a, odo_b, odo_z, odo_cov = [], [], [], []
        radar_v, radar_s, radar_z, radar_cov = [], [], [], []
        index = {s: k for k, s in enumerate(self.pose_ids)}
        known = self.known or {}
        for h in history:
            r = h.rows
            born = h.previous < 0
            prior_v.append(h.vars[born])
            prior_z.append(h.born_mean[born])
            prior_cov.append(h.born_cov[born])
            cont = np.flatnonzero(~born)
            motion_a.append(h.previous[cont])
            motion_b.append(h.vars[cont])
            gnss_v.append(h.vars[r.gnss.at])
            gnss_z.append(r.gnss.z)
            gnss_cov.append(r.gnss.cov)
            o = r.odometry
            ok = h.previous[o.at] >= 0
            odo_a.append(h.previous[o.at[ok]])
            odo_b.append(h.vars[o.at[ok]])
            odo_z.append(o.z[ok])
            odo_cov.append(o.cov[ok])
            d = r.radar
            ok = np.isin(d.sensor, list(known) if self.known is not None else self.pose_ids)
            radar_v.append(h.vars[d.at[ok]])
            radar_s.append(d.sensor[ok])
            radar_z.append(d.z[ok])
            radar_cov.append(d.cov[ok])

        def cat(parts: list[np.ndarray], shape: tuple[int, ...]) -> np.ndarray:
            return np.concatenate(parts) if parts else np.zeros(shape)

        Hg, Ho = models.H_gnss, models.H_odometry
        a, b = cat(motion_a, (0,)).astype(np.int64), cat(motion_b, (0,)).astype(np.int64)
        try:
            W_Q = whitener(np.broadcast_to(Q, (a.size, dx, dx)))
        except np.linalg.LinAlgError:
            W_Q = whitener(np.broadcast_to(Q + _Q_JITTER * I, (a.size, dx, dx)))
        oa, ob = cat(odo_a, (0,)).astype(np.int64), cat(odo_b, (0,)).astype(np.int64)
        gv = cat(gnss_v, (0,)).astype(np.int64)
        pv = cat(prior_v, (0,)).astype(np.int64)
        def each(A: np.ndarray, m: int) -> np.ndarray:
            return np.broadcast_to(A, (m, *A.shape))

        dg, do = Hg.shape[0], Ho.shape[0]
        self.linear = [
            _Linear((pv,), (each(I, pv.size),), cat(prior_z, (0, dx)), whitener(cat(prior_cov, (0, dx, dx)))),
            _Linear((a, b), (each(-models.F, a.size), each(I, a.size)), np.zeros((a.size, dx)), W_Q),
            _Linear((gv,), (each(Hg, gv.size),), cat(gnss_z, (0, dg)), whitener(cat(gnss_cov, (0, dg, dg)))),
            _Linear((oa, ob), (each(-Ho, oa.size), each(Ho, ob.size)), cat(odo_z, (0, do)),
                    whitener(cat(odo_cov, (0, do, do)))),
        ]
        self.H_radar = models.H_radar
        self.radar_v = cat(radar_v, (0,)).astype(np.int64)
        sensors = cat(radar_s, (0,)).astype(np.int64)
        self.radar_k = np.array([index.get(int(s), -1) for s in sensors], dtype=np.int64)
        self.radar_pose = (np.array([known[int(s)] for s in sensors]).reshape(-1, 3)
                           if self.known is not None else None)
        self.radar_z = cat(radar_z, (0, 2))
        self.radar_W = whitener(cat(radar_cov, (0, 2, 2)))
        self.pose_W = whitener(np.broadcast_to(pose_prior_cov, (len(self.pose_ids), 3, 3)))
        self.pose_c = np.array([centres[s] for s in self.pose_ids]).reshape(-1, 3)

    def linearize(self, x: FloatArray, b: FloatArray, jacobian: bool = True
                  ) -> tuple[FloatArray, sp.csr_matrix | None]:
        """Whitened residual (m,) and Jacobian (m, n_vars dx + 3P) at states x (n_vars, dx), poses b (3P,)."""
        import scipy.sparse as sp

        dx = self.dx
        n_x = x.size
        parts, rows, cols, vals = [], [], [], []
        offset = 0

        def block(var_cols: np.ndarray, B: np.ndarray) -> None:
            """COO entries of M factors' blocks B (M, r, c) at columns var_cols (M, c)."""
            M, r, c = B.shape
            at = offset + r * np.arange(M)[:, None, None] + np.arange(r)[None, :, None]
            rows.append(np.broadcast_to(at, (M, r, c)).ravel())
            cols.append(np.broadcast_to(var_cols[:, None, :], (M, r, c)).ravel())
            vals.append(B.ravel())

        for f in self.linear:
            if f.z.shape[0] == 0:
                continue
            pred = sum(np.einsum("mij,mj->mi", A, x[v]) for v, A in zip(f.vars, f.A, strict=True))
            parts.append(np.einsum("mij,mj->mi", f.W, pred - f.z).ravel())
            if jacobian:
                for v, A in zip(f.vars, f.A, strict=True):
                    block(dx * v[:, None] + np.arange(dx), f.W @ A)
            offset += f.z.size
        if self.radar_v.size:
            p = x[self.radar_v] @ self.H_radar.T
            pose = self.radar_pose if self.radar_pose is not None else \
                b[3 * self.radar_k[:, None] + np.arange(3)]
            h, dp, db = radar_model(pose, p)
            parts.append(np.einsum("mij,mj->mi", self.radar_W, h - self.radar_z).ravel())
            if jacobian:
                block(dx * self.radar_v[:, None] + np.arange(dx), self.radar_W @ dp @ self.H_radar)
                if self.radar_pose is None:
                    block(n_x + 3 * self.radar_k[:, None] + np.arange(3), self.radar_W @ db)
            offset += self.radar_z.size
        if self.pose_c.shape[0] and self.radar_pose is None:
            parts.append(np.einsum("mij,mj->mi", self.pose_W, b.reshape(-1, 3) - self.pose_c).ravel())
            if jacobian:
                block(n_x + 3 * np.arange(self.pose_c.shape[0])[:, None] + np.arange(3), self.pose_W)
            offset += self.pose_c.size
        r = np.concatenate(parts) if parts else np.zeros(0)
        if not jacobian:
            return r, None
        n_cols = n_x + (b.size if self.radar_pose is None else 0)
        J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(offset, n_cols))
        return r, J

    def solve(self, **settings: float) -> LMResult:
        """The MAP states and poses with their marginal covariances (`LMResult.border`: the poses)."""
        if self.radar_pose is not None or self.b0.size == 0:
            return solve_lm(lambda x, jac: self.linearize(x, self.b0, jac), self.x0, **settings)
        return solve_lm_bordered(self.linearize, self.x0, self.b0, **settings)
