"""`oracle-kf` in its dense form: one joint Kalman filter, the reference of the component form.

The model is the package's (`cooploc.estimators.oracle_kf`). Per step: vehicles that
leave are marginalised out (their rows and columns dropped), entering vehicles and
newly seen features are appended with their prior (or a broad belief around their
first fix), features unseen for `feature_timeout` steps are dropped; then one joint
prediction and one joint Joseph-form update with all rows stacked (`kf_update_nis`,
square-root form where the Joseph form fails). Odometry rows (Gulati eq. 4) by
stochastic cloning: before the prediction, the clones c = A θ (A picks H x_{k−1} of each
vehicle with a row) are kept beside θ with Cov(c) = A P Aᵀ and Cov(θ, c) = P Aᵀ, which the
prediction turns into F P Aᵀ (c is static) and the births and the sorting follow row by
row; the update is that of [θ; c], with z = H x_k − c + w stacked with the other rows,
and c is then dropped (marginalised out). Cost O(D³ + D² m) for D = 4(S + K)
states and m measurement components, whatever the coupling: the component form
(`components`) gives the same numbers where the coupling is sparse. Kept as the
reference the tests compare with, and selectable with `dense=True`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cooploc.estimators.base import birth_beliefs, checked_states
from cooploc.estimators.oracle_kf.births import feature_births
from cooploc.gaussian import Gaussians, block_diagonal, kf_update_nis, symmetrize
from cooploc.types import AssociationTruth, Estimate, FloatArray, Frame, IntArray, Setup

if TYPE_CHECKING:
    from cooploc.estimators.oracle_kf.params import OracleKFParams

__all__ = ["DenseJointFilter"]


class DenseJointFilter:
    """`oracle-kf` as one dense joint Kalman filter (module docstring): the reference."""

    def __init__(self, setup: Setup, params: OracleKFParams, truth: AssociationTruth) -> None:
        self.name = "oracle-kf"
        self.setup, self.params, self.truth = setup, params, truth
        self.dx = setup.vehicle_layout.dim
        self.df = setup.feature_layout.dim if setup.feature_layout is not None else 0
        self.vehicle_ids: IntArray = np.zeros(0, dtype=np.int64)
        self.feature_ids: IntArray = np.zeros(0, dtype=np.int64)
        self.last_seen: IntArray = np.zeros(0, dtype=np.int64)
        self.mean: FloatArray = np.zeros(0)
        self.cov: FloatArray = np.zeros((0, 0))
        self._Fx = setup.vehicle_motion.transition_matrix(setup.dt)
        self._Ff = (setup.feature_motion.transition_matrix(setup.dt)
                    if setup.feature_motion is not None else None)
        odometry = setup.sensors.get("odometry")
        self._Ho = None if odometry is None else odometry.observation_matrix(self.dx)
        # this step's clones c = H x_{k−1} (stochastic cloning): the vehicles cloned, their
        # mean, covariance and cross-covariance with the state (rows follow the state's order)
        self._clone_ids: IntArray = np.zeros(0, dtype=np.int64)
        self._clone_mean: FloatArray = np.zeros(0)
        self._clone_cov: FloatArray = np.zeros((0, 0))
        self._clone_cross: FloatArray = np.zeros((0, 0))

    # -- state bookkeeping ---------------------------------------------------------

    def _blocks(self) -> tuple[IntArray, IntArray]:
        """Start index of each vehicle and feature block in the stacked state."""
        nv = self.vehicle_ids.size
        return (np.arange(nv) * self.dx, nv * self.dx + np.arange(self.feature_ids.size) * self.df)

    def _keep(self, keep_vehicles: np.ndarray, keep_features: np.ndarray) -> None:
        """Marginalise out the vehicles and features not kept (drop rows and columns)."""
        vstart, fstart = self._blocks()
        idx = np.concatenate([
            (vstart[keep_vehicles, None] + np.arange(self.dx)).ravel(),
            (fstart[keep_features, None] + np.arange(self.df)).ravel(),
        ]).astype(np.int64)
        self.mean, self.cov = self.mean[idx], self.cov[np.ix_(idx, idx)]
        self.vehicle_ids = self.vehicle_ids[keep_vehicles]
        self.feature_ids = self.feature_ids[keep_features]
        self.last_seen = self.last_seen[keep_features]

    def _append(self, vehicles: Gaussians, vehicle_ids: IntArray,
                features: Gaussians, feature_ids: IntArray, k: int) -> None:
        """Append new vehicle and feature blocks, uncorrelated with the rest."""
        nv = self.vehicle_ids.size * self.dx
        mean = np.concatenate([self.mean[:nv], vehicles.mean.ravel(), self.mean[nv:],
                               features.mean.ravel()])
        cov = block_diagonal(self.cov[:nv, :nv][None], vehicles.cov, self.cov[nv:, nv:][None],
                             features.cov)
        n_old_v, n_new_v = nv, vehicles.mean.size
        if self.cov.size:  # keep the old vehicle–feature cross-covariance
            old_f = slice(n_old_v + n_new_v, n_old_v + n_new_v + self.cov.shape[0] - nv)
            cov[:n_old_v, old_f] = self.cov[:nv, nv:]
            cov[old_f, :n_old_v] = self.cov[nv:, :nv]
        self.mean, self.cov = mean, cov
        if self._clone_ids.size:  # the new blocks are uncorrelated with the clones
            cross, width = self._clone_cross, self._clone_cross.shape[1]
            self._clone_cross = np.concatenate([cross[:nv], np.zeros((n_new_v, width)), cross[nv:],
                                                np.zeros((features.mean.size, width))])
        self.vehicle_ids = np.concatenate([self.vehicle_ids, vehicle_ids])
        self.feature_ids = np.concatenate([self.feature_ids, feature_ids])
        self.last_seen = np.concatenate([self.last_seen, np.full(feature_ids.size, k)])

    # -- filter ---------------------------------------------------------------------

    def step(self, frame: Frame) -> Estimate:
        k = frame.k
        origin = self.truth.origin[k]
        present = frame.vehicles

        # vehicles that left, features unseen for too long: marginalise out
        self._keep(np.isin(self.vehicle_ids, present),
                   k - self.last_seen <= self.params.feature_timeout)

        # clone the previous positions of the vehicles with odometry rows, then predict
        # every block already in the state (new ones start at their prior)
        self._clone(frame)
        self._predict()

        # vehicles that entered
        new_v = np.setdiff1d(present, self.vehicle_ids)
        v_birth = birth_beliefs(self.setup, new_v, frame)
        self._append(v_birth, new_v, Gaussians(np.zeros((0, self.df)), np.zeros((0, self.df, self.df))),
                     np.zeros(0, np.int64), k)
        self._sort()

        # features seen for the first time (by a vehicle that is present)
        v2f = frame.batches.get("v2f")
        v2f_rows = np.zeros(0, dtype=np.int64)
        if v2f is not None and len(v2f) and self.df:
            o = origin["v2f"]
            v2f_rows = np.flatnonzero((o >= 0) & np.isin(v2f.sensor, self.vehicle_ids))
            new_f = np.setdiff1d(o[v2f_rows], self.feature_ids)
            if new_f.size:
                first = v2f_rows[np.unique(o[v2f_rows], return_index=True)[1]]
                first = first[np.isin(o[first], new_f)]
                vstart, _ = self._blocks()
                s = np.searchsorted(self.vehicle_ids, v2f.sensor[first])
                sensor_means = self.mean[vstart[s, None] + np.arange(self.dx)]
                f_birth = feature_births(self.setup, frame, new_f, first, sensor_means)
                self._append(Gaussians(np.zeros((0, self.dx)), np.zeros((0, self.dx, self.dx))),
                             np.zeros(0, np.int64), f_birth, new_f, k)
        self._sort()
        return self._estimate(self._update(frame, v2f_rows))

    def _sort(self) -> None:
        """Order blocks by id so that results do not depend on arrival order."""
        vo = np.argsort(self.vehicle_ids, kind="stable")
        fo = np.argsort(self.feature_ids, kind="stable")
        if (vo == np.arange(vo.size)).all() and (fo == np.arange(fo.size)).all():
            return  # already in order (the usual step)
        vstart, fstart = self._blocks()
        idx = np.concatenate([(vstart[vo, None] + np.arange(self.dx)).ravel(),
                              (fstart[fo, None] + np.arange(self.df)).ravel()]).astype(np.int64)
        self.mean, self.cov = self.mean[idx], self.cov[np.ix_(idx, idx)]
        if self._clone_ids.size:
            self._clone_cross = self._clone_cross[idx]
        self.vehicle_ids, self.feature_ids = self.vehicle_ids[vo], self.feature_ids[fo]
        self.last_seen = self.last_seen[fo]

    def _clone(self, frame: Frame) -> None:
        """Stochastic cloning: c = H x_{k−1} of every vehicle in the state with an odometry row,
        kept beside the state with its covariance and its cross-covariance P Aᵀ (c = A θ)."""
        odometry = frame.batches.get("odometry")
        self._clone_ids, self._clone_mean = np.zeros(0, dtype=np.int64), np.zeros(0)
        if self._Ho is None or odometry is None or not len(odometry):
            return
        ids = np.intersect1d(odometry.subject, self.vehicle_ids)   # present at k − 1 and at k
        if not ids.size:
            return
        do, D = self._Ho.shape[0], self.mean.size
        vstart, _ = self._blocks()
        s = np.searchsorted(self.vehicle_ids, ids)
        A = np.zeros((ids.size, do, D))
        A[np.arange(ids.size)[:, None, None], np.arange(do)[None, :, None],
          (vstart[s, None] + np.arange(self.dx))[:, None, :]] = self._Ho
        A = A.reshape(-1, D)
        self._clone_ids = ids
        self._clone_mean = A @ self.mean                            # c = H x_{k−1}
        self._clone_cross = self.cov @ A.T                          # Cov(θ, c) = P Aᵀ
        self._clone_cov = symmetrize(A @ self._clone_cross)         # Cov(c) = A P Aᵀ

    def _predict(self) -> None:
        if self.mean.size == 0:
            return
        dt, nv, nf = self.setup.dt, self.vehicle_ids.size, self.feature_ids.size
        v_means = self.mean[: nv * self.dx].reshape(nv, self.dx)
        Qv = np.broadcast_to(self.setup.vehicle_motion.noise_covariance(dt, v_means),
                             (nv, self.dx, self.dx))
        F_blocks = [np.broadcast_to(self._Fx, (nv, self.dx, self.dx))]
        Q_blocks = [Qv]
        if nf:
            f_means = self.mean[nv * self.dx:].reshape(nf, self.df)
            Q_blocks.append(np.broadcast_to(
                self.setup.feature_motion.noise_covariance(dt, f_means), (nf, self.df, self.df)))
            F_blocks.append(np.broadcast_to(self._Ff, (nf, self.df, self.df)))
        F, Q = block_diagonal(*F_blocks), block_diagonal(*Q_blocks)
        self.mean = F @ self.mean                                  # θ⁻ = F θ
        self.cov = symmetrize(F @ self.cov @ F.T + Q)              # P⁻ = F P Fᵀ + Q
        if self._clone_ids.size:
            self._clone_cross = F @ self._clone_cross               # Cov(θ⁻, c) = F P Aᵀ (c is static)

    def _update(self, frame: Frame, v2f_rows: IntArray) -> tuple[float, int]:
        """One Joseph-form update with every associated row stacked, of the state and this step's
        clones (odometry rows z = H x_k − c + w, c = H x_{k−1}; Gulati eq. 4), which are then
        marginalised out; (its NIS, its dof)."""
        D = self.mean.size + self._clone_mean.size                 # θ, then the clones
        vstart, fstart = self._blocks()
        H_rows, z_rows, R_blocks = [], [], []
        gnss = frame.batches.get("gnss")
        if gnss is not None and len(gnss) and "gnss" in self.setup.sensors:
            rows = np.flatnonzero(np.isin(gnss.subject, self.vehicle_ids))
            if rows.size:
                Hg = self.setup.sensors["gnss"].observation_matrix(self.dx)
                s = np.searchsorted(self.vehicle_ids, gnss.subject[rows])
                H = np.zeros((rows.size, Hg.shape[0], D))
                cols = vstart[s, None] + np.arange(self.dx)                   # (m, dx)
                H[np.arange(rows.size)[:, None, None], np.arange(Hg.shape[0])[None, :, None],
                  cols[:, None, :]] = Hg
                H_rows.append(H.reshape(-1, D))
                z_rows.append(gnss.z[rows].ravel())
                R_blocks.append(gnss.cov[rows])
        if v2f_rows.size:
            v2f = frame.batches["v2f"]
            sensor = self.setup.sensors["v2f"]
            Hx, Hf = sensor.observation_matrix(self.dx), sensor.observation_matrix(self.df)
            origin = self.truth.origin[frame.k]["v2f"][v2f_rows]
            keep = np.isin(origin, self.feature_ids)
            rows, origin = v2f_rows[keep], origin[keep]
            s = np.searchsorted(self.vehicle_ids, v2f.sensor[rows])
            f = np.searchsorted(self.feature_ids, origin)
            self.last_seen[f] = frame.k
            dz = Hx.shape[0]
            H = np.zeros((rows.size, dz, D))
            m_idx = np.arange(rows.size)[:, None, None]
            z_idx = np.arange(dz)[None, :, None]
            H[m_idx, z_idx, (fstart[f, None] + np.arange(self.df))[:, None, :]] = Hf   # + H f
            H[m_idx, z_idx, (vstart[s, None] + np.arange(self.dx))[:, None, :]] = -Hx  # − H x
            H_rows.append(H.reshape(-1, D))
            z_rows.append(v2f.z[rows].ravel())
            R_blocks.append(v2f.cov[rows])
        odometry = frame.batches.get("odometry")
        if self._clone_ids.size:
            rows = np.flatnonzero(np.isin(odometry.subject, self._clone_ids))
            s = np.searchsorted(self.vehicle_ids, odometry.subject[rows])
            c = np.searchsorted(self._clone_ids, odometry.subject[rows])
            do = self._Ho.shape[0]
            H = np.zeros((rows.size, do, D))
            m_idx, z_idx = np.arange(rows.size)[:, None, None], np.arange(do)[None, :, None]
            H[m_idx, z_idx, (vstart[s, None] + np.arange(self.dx))[:, None, :]] = self._Ho   # + H x_k
            H[m_idx, z_idx, (self.mean.size + c[:, None] * do + np.arange(do))[:, None, :]] = (
                -np.eye(do))                                                           # − H x_{k−1}
            H_rows.append(H.reshape(-1, D))
            z_rows.append(odometry.z[rows].ravel())
            R_blocks.append(odometry.cov[rows])
        if not H_rows:
            return 0.0, 0
        H, z, R = np.concatenate(H_rows), np.concatenate(z_rows), block_diagonal(*R_blocks)
        mean, cov = self.mean, self.cov
        if self._clone_ids.size:  # the joint of [θ; c]
            mean = np.concatenate([mean, self._clone_mean])
            cov = np.block([[cov, self._clone_cross], [self._clone_cross.T, self._clone_cov]])
        post, nis = kf_update_nis(Gaussians(mean[None], cov[None]), z[None], H, R)
        n = self.mean.size                                  # the clones marginalised out
        self.mean, self.cov = post.mean[0, :n], post.cov[0, :n, :n]
        return float(nis[0]), z.size

    def _estimate(self, nis: tuple[float, int]) -> Estimate:
        nv, nf = self.vehicle_ids.size, self.feature_ids.size
        vstart, fstart = self._blocks()
        vi = vstart[:, None] + np.arange(self.dx)
        v_cov = self.cov[vi[:, :, None], vi[:, None, :]]
        vehicles = checked_states(self.name, "vehicle", self.vehicle_ids, self.mean[vi].reshape(nv, self.dx),
                                  v_cov)
        features = None
        if self.df:
            fi = fstart[:, None] + np.arange(self.df)
            features = checked_states(self.name, "feature", self.feature_ids,
                                      self.mean[fi].reshape(nf, self.df),
                                      self.cov[fi[:, :, None], fi[:, None, :]])
        return Estimate(vehicles, features, {"state_dim": int(self.mean.size), "nis": nis})
