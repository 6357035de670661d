"""`gnss-kf`: the non-cooperative baseline — one Kalman filter per vehicle from GNSS only.

Model: the vehicle motion model of the scenario (`Setup.vehicle_motion`, e.g. the CV
model of Fröhle eqs. (28)–(29)) and the GNSS model z = H x + w, w ~ N(0, W_s)
(eq. 30). Every paper uses this filter as the reference without cooperation; in
Fröhle Fig. 5 it is the K = 0 point.

Each step: drop vehicles that left, start entering ones from their prior, predict all
others, and update every vehicle with its own GNSS rows (`subject` = its id). Rows with
an unknown subject (anonymous GNSS) are ignored: this filter cannot associate them;
`Estimate.info["gnss_rows_unused"]` counts them (with rows naming an absent vehicle). A
vehicle with no fix this step is only predicted.

Odometry (where the scenario has an ``odometry`` sensor and batch, e.g. Gulati §IV-A,
the Kalman baseline of eq. 20): the row z_k = H x_k − H x_{k−1} + w relates two
states, so it is fused exactly by stochastic cloning (`gaussian.kf_update_relative`:
the joint of [x_k; x_{k−1}] updated with H_aug = [H, −H], x_{k−1} marginalised out). This runs
before the GNSS update, only for vehicles with exactly one odometry row that were
also present at k − 1. Scenarios without odometry are filtered exactly as before.

All vehicles are filtered together as one batch (`gaussian.kf_predict/kf_update`), so
a step costs O(n dx³) in NumPy calls whose number does not grow with n.

`Estimate.info["nis"]`: the NIS of this step's odometry and GNSS updates, summed, with
their degrees of freedom (`gaussian.kf_update_nis`; `types.Estimate`).

The model and the stochastic cloning written out: docs/gnss_kf.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cooploc.estimators.base import VehicleBeliefs, checked_states
from cooploc.gaussian import Gaussians, kf_predict, kf_update_nis, kf_update_relative
from cooploc.params import Params
from cooploc.registry import register_estimator
from cooploc.types import Batch, Estimate, Frame, Setup

__all__ = ["GnssKF", "GnssKFParams"]


@dataclass(frozen=True)
class GnssKFParams(Params):
    """`gnss-kf` has no tuning parameters: it uses the scenario's models as given."""


@register_estimator
class GnssKF:
    """Kalman filter per vehicle from its own GNSS fixes (batched over vehicles).

    Uses: identified GNSS rows (``gnss``, `GnssPosition`: `subject` names the vehicle) and
    odometry. Anonymous GNSS rows it cannot use: a scenario with only those is refused
    (`usable_sensors`); V2F, radar and AoA rows are left aside (the run's report says so).
    """

    name: ClassVar[str] = "gnss-kf"
    bound: ClassVar[str | None] = "kf-known-da"
    summary: ClassVar[str] = "non-cooperative Kalman filter per vehicle from GNSS (+ odometry), baseline"
    Params: ClassVar[type[Params]] = GnssKFParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "froehle2018"
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "gnss": ("gnss-position",), "odometry": ("odometry",)}

    def __init__(self, setup: Setup, params: GnssKFParams, rng: np.random.Generator) -> None:
        self.setup = setup
        self.params = params
        self.vehicles = VehicleBeliefs(setup)
        dx = setup.vehicle_layout.dim
        self._F = setup.vehicle_motion.transition_matrix(setup.dt)
        self._H = setup.sensors["gnss"].observation_matrix(dx) if "gnss" in setup.sensors else None
        odometry = setup.sensors.get("odometry")
        self._H_odo = None if odometry is None else odometry.observation_matrix(dx)
        motion = setup.vehicle_motion
        self._Q = None if motion.state_dependent_noise else motion.noise_covariance(setup.dt)
        self._started = False
        self._nis = (0.0, 0)  # this step's (Σ NIS, Σ dof)

    def _update_nis(self, prior: Gaussians, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> Gaussians:
        """`kf_update`, adding the update's NIS and degrees of freedom to this step's."""
        posterior, nis = kf_update_nis(prior, z, H, R)
        self._nis = (self._nis[0] + float(nis.sum()), self._nis[1] + z.size)
        return posterior

    def step(self, frame: Frame) -> Estimate:
        born = self.vehicles.sync(frame)
        self._nis = (0.0, 0)
        beliefs = self.vehicles.beliefs
        moving = ~born
        previous = beliefs
        if self._started and moving.any():
            Q = self._Q if self._Q is not None else (
                self.setup.vehicle_motion.noise_covariance(self.setup.dt, beliefs.mean[moving]))
            if moving.all():
                beliefs = kf_predict(beliefs, self._F, Q)
            else:
                predicted = kf_predict(beliefs.take(moving), self._F, Q)
                mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
                mean[moving], cov[moving] = predicted.mean, predicted.cov
                beliefs = Gaussians(mean, cov)
        odometry = frame.batches.get("odometry")
        if self._started and self._H_odo is not None and odometry is not None and len(odometry):
            beliefs = self._update_odometry(beliefs, previous, moving, odometry)
        self._started = True
        gnss = frame.batches.get("gnss")
        if gnss is not None and len(gnss) and self._H is not None:
            beliefs = self._update(beliefs, gnss)
        self.vehicles.beliefs = beliefs
        ids = self.vehicles.ids
        # rows naming no present vehicle (anonymous ones among them) are said, not hidden
        unused = 0 if gnss is None else int((~np.isin(gnss.subject, ids)).sum())
        return Estimate(checked_states(self.name, "vehicle", ids, beliefs.mean, beliefs.cov),
                        info={"gnss_rows_unused": unused, "nis": self._nis})

    def _update_odometry(self, beliefs: Gaussians, previous: Gaussians, moving: np.ndarray,
                         odometry: Batch) -> Gaussians:
        """Stochastic-cloning update with odometry rows (module docstring), batched."""
        ids = self.vehicles.ids
        pos = np.minimum(np.searchsorted(ids, odometry.subject), max(ids.size - 1, 0))
        ok = (ids.size > 0) & (ids[pos] == odometry.subject)
        rows, target = np.flatnonzero(ok), pos[ok]
        once = np.bincount(target, minlength=ids.size) == 1
        keep = once[target] & moving[target]
        rows, target = rows[keep], target[keep]
        if rows.size == 0:
            return beliefs
        updated, nis, _ = kf_update_relative(previous.take(target), beliefs.take(target), self._F,
                                             odometry.z[rows], self._H_odo, odometry.cov[rows])
        self._nis = (self._nis[0] + float(nis.sum()), self._nis[1] + odometry.z[rows].size)
        mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
        mean[target], cov[target] = updated.mean, updated.cov
        return Gaussians(mean, cov)

    def _update(self, beliefs: Gaussians, gnss: Batch) -> Gaussians:
        ids = self.vehicles.ids  # sorted
        if ids.size == 0:
            return beliefs
        pos = np.minimum(np.searchsorted(ids, gnss.subject), ids.size - 1)
        rows = np.flatnonzero(ids[pos] == gnss.subject)  # rows about a vehicle present
        if rows.size == 0:
            return beliefs
        target = pos[rows]
        if target.size == ids.size and np.array_equal(target, np.arange(ids.size)):
            # usual step: one fix per vehicle, in order — one batched update, no copies
            return self._update_nis(beliefs, gnss.z[rows], self._H, gnss.cov[rows])
        # A vehicle with several fixes in one step is updated once per fix, in rounds
        # of distinct vehicles so that each round is one batched update.
        order = np.argsort(target, kind="stable")
        rows, target = rows[order], target[order]
        first = np.r_[0, np.flatnonzero(np.diff(target)) + 1]
        rank = np.arange(target.size) - np.repeat(first, np.diff(np.r_[first, target.size]))
        mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
        for r in range(int(rank.max()) + 1):
            sel = rank == r
            t = target[sel]
            updated = self._update_nis(Gaussians(mean[t], cov[t]), gnss.z[rows[sel]], self._H,
                                    gnss.cov[rows[sel]])
            mean[t], cov[t] = updated.mean, updated.cov
        return Gaussians(mean, cov)
