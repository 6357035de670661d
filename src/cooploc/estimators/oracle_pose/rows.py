r"""The rows of one frame that `oracle-pose` fuses, each tied to its true vehicle, and the radar model.

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
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from cooploc.geometry import rotation
from cooploc.types import Batch, FloatArray, Frame, IntArray

__all__ = ["FrameRows", "Rows", "radar_model"]


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
