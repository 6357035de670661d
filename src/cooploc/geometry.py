"""Plane geometry shared by sensors, estimators and metrics: angles, rotations, frames.

- `wrap_angle`: angles wrapped to [−π, π) — the one convention for every bearing,
  heading and heading error in cooploc.
- `rotation`: R(θ) = [[cos θ, −sin θ], [sin θ, cos θ]], which turns vectors of a frame
  rotated by θ into the global frame (batched over leading dimensions).
- `to_local`: global points seen from a sensor at pose [x, y, θ]: R(θ)ᵀ (p − t).
- `fit_pose`: the pose [x, y, θ] that best maps matched sensor-frame points onto
  global ones (least-squares rigid registration in closed form, no scale).
- `links_within`: the pairs of points within a distance of each other (V2V links
  within the communication range), from a k-d tree in O(n log n + E) for n points and
  E pairs — never an n × n distance matrix, so a frame of thousands of vehicles costs
  what its links cost.
- `close_pairs`: the (i, j) pairs of two point sets within a distance (who senses
  what), from a k-d tree over the second set.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from cooploc.types import FloatArray, IntArray

__all__ = ["close_pairs", "fit_pose", "links_within", "rotation", "to_local", "wrap_angle"]


def wrap_angle(angle: npt.ArrayLike) -> FloatArray:
    """Angles (rad) wrapped to [−π, π)."""
    return (np.asarray(angle, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def rotation(yaw: npt.ArrayLike) -> FloatArray:
    """2-D rotation matrices R(θ) (..., 2, 2) that turn sensor-frame vectors into the global frame."""
    yaw = np.asarray(yaw, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def to_local(pose: npt.ArrayLike, points: FloatArray) -> FloatArray:
    """Points (n, 2) in the global frame seen from a sensor at pose [x, y, yaw]: R(θ)ᵀ (p − t).

    Several poses (..., 3) give the points seen from each, (..., n, 2).
    """
    pose = np.asarray(pose, dtype=float)
    return (np.asarray(points, dtype=float) - pose[..., None, :2]) @ rotation(pose[..., 2])


def fit_pose(world: FloatArray, local: FloatArray) -> FloatArray:
    """The pose [x, y, θ] minimising Σ_i ‖t + R(θ) l_i − w_i‖² over matched points (n, 2).

    Closed form (2-D Procrustes without scale): with centred points, θ = atan2(Σ l × w,
    Σ l · w) and t = w̄ − R(θ) l̄. Needs n ≥ 2 distinct points for θ to be determined.
    """
    world, local = np.asarray(world, dtype=float), np.asarray(local, dtype=float)
    w, l = world - world.mean(axis=0), local - local.mean(axis=0)
    theta = np.arctan2(np.sum(l[:, 0] * w[:, 1] - l[:, 1] * w[:, 0]), np.sum(l * w))
    t = world.mean(axis=0) - rotation(theta) @ local.mean(axis=0)
    return np.array([t[0], t[1], theta])


# a k-d tree's distance test and np.hypot may disagree in the last bits; candidates are
# taken a hair wider and the exact test below decides, so the pairs are those of
# `np.hypot(p_i − p_j) <= radius` to the bit
_CANDIDATE_MARGIN = 1e-9


def _candidate_radius(radius: float) -> float:
    return radius * (1.0 + _CANDIDATE_MARGIN) + _CANDIDATE_MARGIN


def links_within(ids: npt.ArrayLike, positions: FloatArray, radius: float, *,
                 tree_order: bool = False) -> IntArray:
    """(E, 2) id pairs (ids[i], ids[j]), i < j, of the points with ‖p_i − p_j‖ <= `radius`.

    Parameters
    ----------
    ids : (n,) ids of the points, in the order of `positions`.
    positions : (n, 2) positions (m).
    radius : distance (m).
    tree_order : return the pairs in the k-d tree's own order, with its own distance
        test (`scipy.spatial.cKDTree.query_pairs`), as `aoa-grid` has always drawn its
        links — kept so that its recordings stay what they were. The default sorts the
        pairs by (i, j), the order of the upper triangle of a distance matrix, and tests
        with ``np.hypot``.
    """
    from scipy.spatial import cKDTree

    ids = np.asarray(ids, dtype=np.int64)
    positions = np.asarray(positions, dtype=float).reshape(ids.size, 2)
    if ids.size < 2:
        return np.zeros((0, 2), dtype=np.int64)
    tree = cKDTree(positions)
    if tree_order:
        return ids[tree.query_pairs(radius, output_type="ndarray").reshape(-1, 2)]
    pairs = tree.query_pairs(_candidate_radius(radius), output_type="ndarray").reshape(-1, 2)
    i, j = pairs[:, 0], pairs[:, 1]  # i < j (query_pairs' contract)
    gap = positions[i] - positions[j]
    close = np.hypot(gap[:, 0], gap[:, 1]) <= radius
    # one int64 key per pair sorts faster than a lexsort of two columns
    key = i[close] * ids.size + j[close]
    key.sort()
    return ids[np.stack([key // ids.size, key % ids.size], axis=1)]


def close_pairs(a: FloatArray, b: FloatArray, radius: float) -> tuple[IntArray, IntArray]:
    """Indices (i, j), sorted by (i, j), of the points a[i] (n, 2) and b[j] (K, 2) with
    ‖a_i − b_j‖ <= `radius` (the test of ``np.hypot``, as a dense n × K matrix would do)."""
    from scipy.spatial import cKDTree

    a = np.asarray(a, dtype=float).reshape(-1, 2)
    b = np.asarray(b, dtype=float).reshape(-1, 2)
    if a.shape[0] == 0 or b.shape[0] == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    found = cKDTree(a).sparse_distance_matrix(cKDTree(b), _candidate_radius(radius),
                                              output_type="ndarray")
    i, j = found["i"].astype(np.int64), found["j"].astype(np.int64)
    close = np.hypot(*(a[i] - b[j]).T) <= radius
    i, j = i[close], j[close]
    order = np.lexsort((j, i))
    return i[order], j[order]
