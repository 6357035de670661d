r"""The filter of `oracle-pose`: an iterated EKF over every vehicle and every radar pose, jointly.

State: one Gaussian over θ = [b_1; …; b_P; x_1; …; x_n] — the poses b_s = [t_s; θ_s] of
the radars met so far and the states of the vehicles present — with one dense
covariance (the poses couple every vehicle they see).

Per step k:

1. *Traffic*: vehicles that left are marginalised out (their rows and columns
   dropped); vehicles that enter start from `base.birth_beliefs`, uncorrelated.
2. *Prediction* of the continuing vehicles, x_k = F x_{k−1} + v, v ~ N(0, Q); poses
   are static. A continuing vehicle with odometry rows has its previous position
   H x_{k−1} *cloned* into the state first (stochastic cloning, as `gnss-kf`), so
   that the odometry row z = H x_k − H x_{k−1} + w is a linear row of the joint state.
3. *Update* with every row at once — GNSS (z = H x + w), odometry and the rows of
   every radar whose pose is in the state (`rows.radar_model`) — by Gauss–Newton
   iterations of the iterated EKF: x⁽ⁱ⁺¹⁾ = x̄ + K_i (z − h(x⁽ⁱ⁾) − H_i (x̄ − x⁽ⁱ⁾)),
   K_i = Σ H_iᵀ (H_i Σ H_iᵀ + R)⁻¹, until the step is below `tolerance`; the
   covariance is the Joseph form at the last linearisation. Without radar rows this
   is one exact Kalman update.
4. *A radar seen for the first time* joins the state once one frame has its rows of
   at least two distinct vehicles: its pose starts at the rigid fit of those rows to
   the vehicles' updated positions (`geometry.fit_pose`) with a diffuse prior
   (`pose_prior_position_std`, `pose_prior_yaw_std`) centred there, and its rows are
   then fused by step 3. Rows of a radar not yet in the state are not used by the
   filter (the smoother uses them).
5. The clones are marginalised out.

With known poses (`known_pose`) the radar rows are linear (the pose is a constant)
and the filter is the exact Kalman filter of the joint state. Cost per step:
O(D³ + D² m) for D = 3P + dx n + 2 n_odometry state components and m rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cooploc.errors import EstimatorError
from cooploc.estimators.oracle_pose.rows import Chains, FrameRows, Models, Rows, radar_model
from cooploc.geometry import fit_pose
from cooploc.types import FloatArray, Frame, IntArray, Setup

__all__ = ["PoseFilter", "PoseState"]

_NO_RADAR = Rows(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0, np.int64))


def _block_diagonal(blocks: list[FloatArray]) -> FloatArray:
    """The block-diagonal matrix of stacks of square blocks [(M_i, d_i, d_i)]."""
    stack = [b for s in blocks for b in s]
    size = sum(b.shape[0] for b in stack)
    out = np.zeros((size, size))
    at = 0
    for b in stack:
        d = b.shape[0]
        out[at:at + d, at:at + d] = b
        at += d
    return out


@dataclass
class PoseState:
    """The radars whose pose is in the state (ids in state order) and the centres of their priors."""

    ids: list[int] = field(default_factory=list)
    centres: list[FloatArray] = field(default_factory=list)


class PoseFilter:
    """The joint iterated EKF of the module docstring.

    Parameters
    ----------
    setup : the recording's setup (motion model, sensors, priors).
    name : the estimator's name, for its errors.
    pose_prior_cov : (3, 3) diffuse prior of a pose at its first fit.
    known_poses : radar id → pose [x, y, θ] held fixed (None: every pose is estimated).
    max_iterations, tolerance : Gauss–Newton iterations of one update, and the step
        (∞-norm of the state change) below which they stop.
    """

    def __init__(self, setup: Setup, name: str, pose_prior_cov: FloatArray,
                 known_poses: dict[int, FloatArray] | None, max_iterations: int, tolerance: float) -> None:
        self.setup, self.name = setup, name
        self.models = Models.of(setup)
        self.dx = self.models.dim
        self.chains = Chains(setup)
        self.pose_prior_cov = pose_prior_cov
        self.known = known_poses
        self.max_iterations, self.tolerance = max_iterations, tolerance
        self.poses = PoseState()
        self.ids = np.zeros(0, np.int64)
        self.mean = np.zeros(0)
        self.cov = np.zeros((0, 0))
        self.nis = (0.0, 0)

    @property
    def n_poses(self) -> int:
        return len(self.poses.ids)

    def pose_estimates(self) -> dict[int, tuple[FloatArray, FloatArray]]:
        """Radar id → (pose [x, y, θ] with θ wrapped to [−π, π), its 3 × 3 covariance)."""
        out = {}
        for s, sensor in enumerate(self.poses.ids):
            b = self.mean[3 * s:3 * s + 3].copy()
            b[2] = (b[2] + np.pi) % (2 * np.pi) - np.pi
            out[sensor] = (b, self.cov[3 * s:3 * s + 3, 3 * s:3 * s + 3].copy())
        return out

    # -- one step -------------------------------------------------------------------

    def step(self, frame: Frame, rows: FrameRows) -> tuple[FloatArray, FloatArray]:
        """Filter one frame; the vehicles' means (n, dx) and covariances (n, dx, dx), sorted ids."""
        clone_of = self._predict(frame, rows)
        self.nis = (0.0, 0)
        # the linear rows in one exact update, then Gauss–Newton on the radar rows alone:
        # the same MAP, since the first update is the exact Gaussian prior × linear rows
        self._update(rows, clone_of, _NO_RADAR)
        self._update(rows, clone_of, rows.radar, linear_rows=False)
        fresh = self._new_poses(rows)
        if fresh is not None:
            self._update(rows, clone_of, fresh, linear_rows=False)
        keep = 3 * self.n_poses + self.dx * rows.ids.size
        self.mean, self.cov = self.mean[:keep], self.cov[:keep, :keep]
        n, dx = rows.ids.size, self.dx
        v = 3 * self.n_poses
        mean = self.mean[v:].reshape(n, dx)
        blocks = self.cov[v:, v:].reshape(n, dx, n, dx)
        cov = blocks[np.arange(n), :, np.arange(n), :]
        self.chains.set_mean(mean)
        return mean, cov

    def _predict(self, frame: Frame, rows: FrameRows) -> IntArray:
        """Traffic, prediction and clones (steps 1–2); returns, per vehicle (sorted ids),
        its clone's index among the clones or −1."""
        old, new = self.ids, rows.ids
        n, dx, P = new.size, self.dx, 3 * self.n_poses
        cont = np.isin(new, old)
        old_at = np.searchsorted(old, new[cont])
        record = self.chains.add(frame, rows)
        odometry_vehicles = np.unique(rows.odometry.at)
        cloned = odometry_vehicles[cont[odometry_vehicles]] if odometry_vehicles.size else odometry_vehicles
        clone_of = np.full(n, -1, np.int64)
        clone_of[cloned] = np.arange(cloned.size)
        H_o, F = self.models.H_odometry, self.models.F
        do = H_o.shape[0]
        D = P + dx * n + do * cloned.size
        # θ_k = M θ_{k−1} (+ births): poses kept, continuing vehicles moved by F, clones H x_{k−1}
        M = np.zeros((D, self.mean.size))
        M[:P, :P] = np.eye(P)
        j = np.flatnonzero(cont)
        for jj, i in zip(j, old_at, strict=True):
            M[P + dx * jj:P + dx * (jj + 1), P + dx * i:P + dx * (i + 1)] = F
        for c, jj in enumerate(cloned):
            i = old_at[np.searchsorted(j, jj)]
            M[P + dx * n + do * c:P + dx * n + do * (c + 1), P + dx * i:P + dx * (i + 1)] = H_o
        mean = M @ self.mean
        cov = M @ self.cov @ M.T
        if j.size:
            Q = self.models.motion.noise_covariance(self.models.dt, mean[P:P + dx * n].reshape(n, dx)[j])
            Q = np.broadcast_to(Q, (j.size, dx, dx))
            for q, jj in zip(Q, j, strict=True):
                cov[P + dx * jj:P + dx * (jj + 1), P + dx * jj:P + dx * (jj + 1)] += q
        for jj in np.flatnonzero(~cont):
            s = slice(P + dx * jj, P + dx * (jj + 1))
            mean[s], cov[s, s] = record.born_mean[jj], record.born_cov[jj]
        self.ids, self.mean, self.cov = new, mean, 0.5 * (cov + cov.T)
        return clone_of

    def _rows_model(self, x: FloatArray, rows: FrameRows, clone_of: IntArray, radar: Rows,
                    linear_rows: bool) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, bool]:
        """Stacked z (m,), h(x) (m,), H (m, D), R (m, m) of the rows at x; whether any is nonlinear."""
        dx, n, P, D = self.dx, rows.ids.size, 3 * self.n_poses, x.size
        zs, hs, Hs, Rs = [], [], [], []
        nonlinear = False

        def vehicle_cols(at: IntArray) -> FloatArray:
            return P + dx * at[:, None] + np.arange(dx)

        def add(z: FloatArray, h: FloatArray, cols: list[tuple[IntArray, FloatArray]], R: FloatArray) -> None:
            m, dz = z.shape
            H = np.zeros((m, dz, D))
            for c, block in cols:  # the blocks of one row touch distinct columns
                H[np.arange(m)[:, None, None], np.arange(dz)[None, :, None], c[:, None, :]] = block
            zs.append(z.ravel())
            hs.append(h.ravel())
            Hs.append(H.reshape(m * dz, D))
            Rs.append(R)

        if linear_rows:
            g = rows.gnss
            if len(g):
                Hg = np.broadcast_to(self.models.H_gnss, (len(g), *self.models.H_gnss.shape))
                add(g.z, x[vehicle_cols(g.at)] @ self.models.H_gnss.T, [(vehicle_cols(g.at), Hg)], g.cov)
            o = rows.odometry
            keep = clone_of[o.at] >= 0 if len(o) else np.zeros(0, bool)
            if keep.any():
                o = o.take(np.flatnonzero(keep))
                Ho = np.broadcast_to(self.models.H_odometry, (len(o), *self.models.H_odometry.shape))
                do = self.models.H_odometry.shape[0]
                clone_cols = P + dx * n + do * clone_of[o.at][:, None] + np.arange(do)
                h = x[vehicle_cols(o.at)] @ self.models.H_odometry.T - x[clone_cols]
                add(o.z, h, [(vehicle_cols(o.at), Ho),
                             (clone_cols, np.broadcast_to(-np.eye(do), (len(o), do, do)))], o.cov)
        if len(radar):
            Hr = self.models.H_radar
            p = x[vehicle_cols(radar.at)] @ Hr.T
            if self.known is not None:
                use = np.isin(radar.sensor, list(self.known))
                r = radar.take(np.flatnonzero(use))
                pose = np.array([self.known[int(s)] for s in r.sensor]).reshape(-1, 3)
                h, dp, _ = radar_model(pose, p[use])
                add(r.z, h, [(vehicle_cols(r.at), dp @ Hr)], r.cov)
            else:
                index = {s: k for k, s in enumerate(self.poses.ids)}
                use = np.isin(radar.sensor, self.poses.ids)
                r = radar.take(np.flatnonzero(use))
                k = np.array([index[int(s)] for s in r.sensor], dtype=np.int64)
                pose_cols = 3 * k[:, None] + np.arange(3)
                h, dp, db = radar_model(x[pose_cols], p[use])
                add(r.z, h, [(vehicle_cols(r.at), dp @ Hr), (pose_cols, db)], r.cov)
                nonlinear = len(r) > 0
        if not zs:
            return np.zeros(0), np.zeros(0), np.zeros((0, D)), np.zeros((0, 0)), False
        return np.concatenate(zs), np.concatenate(hs), np.concatenate(Hs), _block_diagonal(Rs), nonlinear

    def _update(self, rows: FrameRows, clone_of: IntArray, radar: Rows, linear_rows: bool = True) -> None:
        """Step 3 of the module docstring with the frame's linear rows (if asked) and `radar`."""
        from scipy.linalg import cho_factor, cho_solve

        prior, Sigma = self.mean, self.cov
        x = prior.copy()
        for _ in range(self.max_iterations):
            z, h, H, R, nonlinear = self._rows_model(x, rows, clone_of, radar, linear_rows)
            if z.size == 0:
                return
            y = z - h - H @ (prior - x)                     # innovation at the linearisation point
            PHt = Sigma @ H.T
            S = H @ PHt + R
            try:
                factor = cho_factor(0.5 * (S + S.T))
            except np.linalg.LinAlgError:
                raise EstimatorError(self.name, "the innovation covariance of the rows is not positive "
                                     "definite") from None
            K = cho_solve(factor, PHt.T).T                 # K = Σ Hᵀ S⁻¹
            x_new = prior + K @ y
            moved = float(np.max(np.abs(x_new - x))) if x.size else 0.0
            x = x_new
            if not nonlinear or moved < self.tolerance:
                break
        A = np.eye(prior.size) - K @ H                      # Joseph form: (I − KH) Σ (I − KH)ᵀ + K R Kᵀ
        cov = A @ Sigma @ A.T + K @ R @ K.T
        self.mean, self.cov = x, 0.5 * (cov + cov.T)
        self.nis = (self.nis[0] + float(y @ cho_solve(factor, y)), self.nis[1] + y.size)

    def _new_poses(self, rows: FrameRows) -> Rows | None:
        """Step 4: add the radars first met now (with rows of ≥ 2 vehicles); their rows, or None."""
        radar = rows.radar
        if self.known is not None or not len(radar):
            return None
        fresh = [int(s) for s in np.unique(radar.sensor) if int(s) not in self.poses.ids]
        added = []
        P, dx = 3 * self.n_poses, self.dx
        for sensor in fresh:
            r = radar.take(np.flatnonzero(radar.sensor == sensor))
            if np.unique(r.at).size < 2 or np.ptp(r.z, axis=0).max() <= 0:
                continue  # one vehicle cannot fix a yaw
            p = self.mean[P + dx * r.at[:, None] + np.arange(dx)] @ self.models.H_radar.T
            centre = fit_pose(p, r.z)
            self._insert_pose(centre)
            self.poses.ids.append(sensor)
            self.poses.centres.append(centre)
            P += 3
            added.append(sensor)
        if not added:
            return None
        return radar.take(np.flatnonzero(np.isin(radar.sensor, added)))

    def _insert_pose(self, centre: FloatArray) -> None:
        """Append a pose (diffuse prior at `centre`, uncorrelated) after the poses in the state."""
        P = 3 * self.n_poses
        D = self.mean.size
        mean = np.concatenate([self.mean[:P], centre, self.mean[P:]])
        cov = np.zeros((D + 3, D + 3))
        keep = np.r_[np.arange(P), np.arange(P + 3, D + 3)]
        cov[np.ix_(keep, keep)] = self.cov
        cov[P:P + 3, P:P + 3] = self.pose_prior_cov
        self.mean, self.cov = mean, cov
