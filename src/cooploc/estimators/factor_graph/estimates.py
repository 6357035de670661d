"""What the factor-graph estimators return per step: the linear part's filter and the Estimate layout.

Paper: Gulati et al. 2017 estimate positions by batch smoothing (eq. 17) only; an
estimator here must also answer every `step`. `PositionFilter` is the Kalman filter of
the graph's linear part per vehicle — odometry p_t = p_{t−1} + δ_t + n (eqs. 4–5) and
GPS (eqs. 6–7), without topology — whose estimate the batch estimators return from
`step` and which gives the smoother its initial guess. O(N) per step, batched over
vehicles.

`EstimateLayout` writes positions into the scenario's state layout. The graph has no
velocity (as in the paper); the velocity reported beside it is δ_t / T where a vehicle
has one odometry row (filtered) or the finite difference of smoothed positions
(smoothed), with a block-diagonal covariance (cross terms dropped). Components the
graph does not estimate get a broad covariance.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cooploc.estimators.base import checked_states
from cooploc.estimators.factor_graph.graph import FrameFactors
from cooploc.gaussian import Gaussians, kf_update
from cooploc.types import Estimate, FloatArray, IntArray, Setup

__all__ = ["EstimateLayout", "PositionFilter"]

_I2 = np.eye(2)


class PositionFilter:
    """Kalman filter of the graph's linear part per vehicle: p_t = p_{t−1} + δ_t + n, GPS.

    A vehicle with several between rows in one step (odometry and the GNSS velocity
    factor, `graph.py`) is predicted with their fusion: independent measurements of the
    same displacement, so one row with the summed information is exact.
    """

    def __init__(self) -> None:
        self.vars = np.zeros(0, np.int64)
        self.mean = np.zeros((0, 2))
        self.cov = np.zeros((0, 2, 2))

    def step(self, f: FrameFactors) -> Gaussians:
        """Filtered positions of the frame's variables after its between and unary rows."""
        n = f.vars.size
        mean, cov = np.zeros((n, 2)), np.zeros((n, 2, 2))
        cont = f.previous >= 0
        if cont.any():
            at = np.searchsorted(self.vars, f.previous[cont])
            mean[cont], cov[cont] = self.mean[at], self.cov[at]
        # predict with the between rows of this frame: p_t = p_{t−1} + δ_t, P += R
        b = f.between_b - (f.vars[0] if n else 0)
        if np.array_equal(b, np.arange(n)):  # one row per vehicle, in order: the usual step
            mean += f.between_z
            cov += f.between_cov
        elif b.size:
            info = np.linalg.inv(f.between_cov)
            total, weighted = np.zeros((n, 2, 2)), np.zeros((n, 2))
            np.add.at(total, b, info)
            np.add.at(weighted, b, np.einsum("mij,mj->mi", info, f.between_z))
            i = np.unique(b)
            fused = np.linalg.inv(total[i])
            mean[i] += np.einsum("mij,mj->mi", fused, weighted[i])
            cov[i] += fused
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


class EstimateLayout:
    """Builds `Estimate`s in the setup's layout: positions, velocities, block-diagonal cov."""

    def __init__(self, setup: Setup, estimator: str) -> None:
        self.estimator = estimator  # names the estimator in its EstimatorError
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
        """The `Estimate` of vehicles `ids` (n,) from positions (n, 2) and velocities (n, 2)."""
        n = ids.size
        mean = np.zeros((n, self.dim))
        cov = np.repeat(self.base_cov[None], n, axis=0)
        mean[:, self.pos] = pos
        cov[:, self.pos[:, None], self.pos[None, :]] = pos_cov
        if self.vel is not None:
            mean[:, self.vel] = vel
            cov[:, self.vel[:, None], self.vel[None, :]] = vel_cov
        return Estimate(checked_states(self.estimator, "vehicle", ids, mean, cov), info=info)
