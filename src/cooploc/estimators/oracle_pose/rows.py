r"""What `oracle-pose` fuses: the rows of a frame tied to their true vehicles, the models, the chains.

Which rows: GNSS rows (identified or anonymous) and radar rows by their true origin
(`AssociationTruth.origin`; clutter, origin −1, is dropped), odometry rows by their
subject (odometry is identified by construction). Rows about a vehicle not present in
the frame are dropped too.

Radar model (Zhang 2016 §3.2, Gulati 2017 §II; `sensors.InfrastructureRadar`): a row
of radar s is

.. math:: z = h(x, b_s) + w = R(\theta_s)^\top (H x - t_s) + w, \quad w \sim N(0, W),

with pose b_s = [t_s; θ_s] and H the sensor's position selection. Its Jacobians:
∂h/∂x = Rᵀ H, ∂h/∂t = −Rᵀ, ∂h/∂θ = (dRᵀ/dθ)(H x − t) = [[−sin θ, cos θ], [−cos θ,
−sin θ]] (H x − t). Everything is vectorised over rows.

`Models` holds the setup's F, Q and the observation matrices; `Chains` numbers one
variable per present vehicle and step (step by step, ids sorted within a step), links
each to the same vehicle's variable at the previous step and records the prior of
every chain's first variable (`base.birth_beliefs`) — the bookkeeping the filter and
the smoother share.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from cooploc.estimators.base import birth_beliefs
from cooploc.geometry import rotation
from cooploc.types import Batch, FloatArray, Frame, IntArray, MotionModel, Setup

__all__ = ["Chains", "FrameRows", "Models", "Rows", "StepRecord", "radar_model"]


@dataclass(frozen=True)
class Rows:
    """Rows of one kind: vehicle position `at` (M,) in the frame's sorted ids, z (M, dz), cov (M, dz, dz).

    `sensor` (M,): the radar id of each row (radar rows), else the measuring vehicle's id.
    """

    at: IntArray
    z: FloatArray
    cov: FloatArray
    sensor: IntArray

    @classmethod
    def of(cls, ids: IntArray, batch: Batch | None, vehicle: IntArray | None) -> Rows:
        """The rows of `batch` whose `vehicle` (M,) (their origin or subject) is in sorted `ids`."""
        if batch is None or not len(batch) or ids.size == 0 or vehicle is None:
            dz = 2 if batch is None else batch.z.shape[1]
            return cls(np.zeros(0, np.int64), np.zeros((0, dz)), np.zeros((0, dz, dz)), np.zeros(0, np.int64))
        vehicle = np.asarray(vehicle, dtype=np.int64)
        at = np.minimum(np.searchsorted(ids, vehicle), ids.size - 1)
        rows = np.flatnonzero(ids[at] == vehicle)
        return cls(at[rows], batch.z[rows], batch.cov[rows], batch.sensor[rows])

    def take(self, rows: np.ndarray) -> Rows:
        return Rows(self.at[rows], self.z[rows], self.cov[rows], self.sensor[rows])

    def __len__(self) -> int:
        return self.at.size


@dataclass(frozen=True)
class FrameRows:
    """The vehicles of a frame (sorted ids) and its GNSS, odometry and radar rows."""

    ids: IntArray
    gnss: Rows
    odometry: Rows
    radar: Rows

    @classmethod
    def of(cls, frame: Frame, origin: Mapping[str, IntArray]) -> FrameRows:
        """Rows of `frame` tied to their vehicles by `origin` (the step's true origins per kind)."""
        ids = np.sort(np.asarray(frame.vehicles, dtype=np.int64))
        b = frame.batches
        odometry = b.get("odometry")
        return cls(ids, Rows.of(ids, b.get("gnss"), origin.get("gnss")),
                   Rows.of(ids, odometry, None if odometry is None else odometry.subject),
                   Rows.of(ids, b.get("radar"), origin.get("radar")))


def radar_model(pose: FloatArray, p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """h = R(θ)ᵀ(p − t) of positions p (M, 2) from poses (M, 3), ∂h/∂p (M, 2, 2), ∂h/∂b (M, 2, 3)."""
    Rt = np.swapaxes(rotation(pose[:, 2]), -1, -2)
    d = p - pose[:, :2]
    h = np.einsum("mij,mj->mi", Rt, d)
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    dtheta = np.stack([-s * d[:, 0] + c * d[:, 1], -c * d[:, 0] - s * d[:, 1]], axis=-1)
    return h, Rt, np.concatenate([-Rt, dtheta[:, :, None]], axis=2)


@dataclass(frozen=True)
class Models:
    """The setup's motion model (F, and `motion` for Q) and the observation matrices H of
    the GNSS, odometry and radar rows (position selection where a sensor is absent)."""

    dim: int
    motion: MotionModel
    dt: float
    F: FloatArray
    H_gnss: FloatArray
    H_odometry: FloatArray
    H_radar: FloatArray

    @classmethod
    def of(cls, setup: Setup) -> Models:
        dx = setup.vehicle_layout.dim
        position = np.eye(dx)[list(setup.vehicle_layout.position)]

        def H_of(kind: str) -> FloatArray:
            model = setup.sensors.get(kind)
            return position if model is None else model.observation_matrix(dx)

        motion = setup.vehicle_motion
        return cls(dx, motion, setup.dt, motion.transition_matrix(setup.dt), H_of("gnss"),
                   H_of("odometry"), H_of("radar"))


@dataclass(frozen=True)
class StepRecord:
    """One step of the chains: the frame's rows, its variables and the chains' starts.

    vars (n,): variable of each present vehicle (sorted ids); previous (n,): the same
    vehicle's variable at the step before, −1 where its chain starts (then born_mean
    (dx,) and born_cov (dx, dx) hold its prior); mean (n, dx): the estimate at this step
    (the smoother's initial guess).
    """

    rows: FrameRows
    vars: IntArray
    previous: IntArray
    born_mean: FloatArray
    born_cov: FloatArray
    mean: FloatArray


class Chains:
    """Variables numbered step by step, linked vehicle by vehicle (module docstring)."""

    def __init__(self, setup: Setup) -> None:
        self.setup = setup
        self.ids = np.zeros(0, np.int64)
        self.vars = np.zeros(0, np.int64)
        self.n_vars = 0
        self.history: list[StepRecord] = []

    def add(self, frame: Frame, rows: FrameRows) -> StepRecord:
        """Number the frame's variables; its record (mean zero until `set_mean`)."""
        new, dx = rows.ids, self.setup.vehicle_layout.dim
        n = new.size
        cont = np.isin(new, self.ids)
        previous = np.full(n, -1, np.int64)
        previous[cont] = self.vars[np.searchsorted(self.ids, new[cont])]
        born_mean, born_cov = np.zeros((n, dx)), np.zeros((n, dx, dx))
        if (~cont).any():
            b = birth_beliefs(self.setup, new[~cont], frame)
            born_mean[~cont], born_cov[~cont] = b.mean, b.cov
        self.ids, self.vars = new, self.n_vars + np.arange(n)
        self.n_vars += n
        record = StepRecord(rows, self.vars, previous, born_mean, born_cov, np.zeros((n, dx)))
        self.history.append(record)
        return record

    def set_mean(self, mean: FloatArray) -> None:
        """Store the estimate (n, dx) of the last step."""
        r = self.history[-1]
        self.history[-1] = StepRecord(r.rows, r.vars, r.previous, r.born_mean, r.born_cov, np.array(mean))
