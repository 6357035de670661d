"""Plane geometry shared by sensors, estimators and metrics: angles, rotations, frames.

- `wrap_angle`: angles wrapped to [−π, π) — the one convention for every bearing,
  heading and heading error in cooploc.
- `rotation`: R(θ) = [[cos θ, −sin θ], [sin θ, cos θ]], which turns vectors of a frame
  rotated by θ into the global frame (batched over leading dimensions).
- `to_local`: global points seen from a sensor at pose [x, y, θ]: R(θ)ᵀ (p − t).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from cooploc.types import FloatArray

__all__ = ["rotation", "to_local", "wrap_angle"]


def wrap_angle(angle: npt.ArrayLike) -> FloatArray:
    """Angles (rad) wrapped to [−π, π)."""
    return (np.asarray(angle, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def rotation(yaw: npt.ArrayLike) -> FloatArray:
    """2-D rotation matrices R(θ) (..., 2, 2) that turn sensor-frame vectors into the global frame."""
    yaw = np.asarray(yaw, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def to_local(pose: npt.ArrayLike, points: FloatArray) -> FloatArray:
    """Points (n, 2) in the global frame seen from a sensor at pose [x, y, yaw]: R(θ)ᵀ (p − t)."""
    pose = np.asarray(pose, dtype=float)
    return (np.asarray(points, dtype=float) - pose[:2]) @ rotation(pose[2])
