r"""Road-side radars of unknown pose in traffic: which vehicles each one sees, from the beliefs.

Papers: Zhang et al., GeoInformatica 2016 (SME, eq. 18) and Gulati et al., IV 2017
(factor graphs, eqs. 8–16) both take the squared topology of *one* radar's anonymous
rows, which needs neither its pose nor the row order, and both assume the radar sees
every vehicle (N known). In traffic (`sumo-*`) several radars stand at junctions, each
sees the few vehicles within its range and field of view, and vehicles enter and leave.
The topology is then that of the vehicles *that radar* sees; this module finds them,
for `cooploc.estimators.sme` (per-radar mode) and `cooploc.estimators.factor_graph`
(per-radar topology factors) alike.

Which vehicles a radar sees (`RadarFields`)
--------------------------------------------
Eq. (18) needs the set of vehicles behind the rows, never their order. The set follows
from the radar's pose, which is unknown but static, and from the vehicles' beliefs; the
estimator estimates the pose itself, never reading it from the truth:

1. Registration (first rows, or when the pose no longer explains the rows). The two
   rows farthest apart, q_i and q_j, are matched to every ordered pair of predicted
   vehicles (a, b) whose distance agrees with ‖q_i − q_j‖ within 3σ; each pair gives a
   rigid pose (the rotation of q_j − q_i onto p_b − p_a, the translation of the
   midpoints). Each candidate is scored by Σ_rows min(min_vehicles d², g) — d² the
   squared Mahalanobis distance of the row, mapped to the global frame, to a predicted
   vehicle, g the χ²₂ gate — plus g per vehicle the field would hold beyond the row
   count. The best is refined by `geometry.fit_pose` on its nearest matches and
   accepted if every row lies within the gate of a vehicle. It is used only once it has
   explained the rows of `_CONFIRM` steps (a formation along one road also fits its
   mirror image); a pose that fails before, or `_MAX_MISSES` steps in a row after, is
   dropped and registered anew.
2. Tracking: while the pose explains every row (each within the gate), it is refined by
   the Procrustes fit of the step's nearest matches, averaged with the previous
   estimate (weights: steps seen, at most `_POSE_MEMORY`) — the radar does not move.
3. In view: with the pose, each vehicle's probability of lying inside the field is
   Φ((R − d)/σ) (d its predicted distance from the radar, σ² its position variance plus
   `_POSE_VARIANCE`; times the like factor of the bearing when the field of view is
   not all around). The M rows say M vehicles are seen: the set is the M most probable
   ones, used only when the probability that exactly these are in view,
   Π_in p · Π_out (1 − p), is at least `view_confidence`; otherwise that radar is
   skipped this step with the reason in ``info["radar_skipped"]``.

`sees_every_vehicle`: whether the setup is the papers' (one radar, unbounded range,
all-around field), where the joint model applies. `topology_nis`: the normalised
innovation of a radar's measured topology against its prediction from the beliefs
(linearised, one degree of freedom), to refuse an in-view set the rows contradict.

Complexity per radar and step: registration O(N² + C M N) for C candidate pairs (only
when the pose is lost), tracking and the in-view test O(M N).
"""

from __future__ import annotations

import numpy as np

from cooploc.geometry import fit_pose, rotation, to_local
from cooploc.sensors import InfrastructureRadar
from cooploc.types import FloatArray, IntArray, Setup

__all__ = ["RadarFields", "sees_every_vehicle", "topology_nis"]

#: steps of pose fits the running average of a radar's pose remembers
_POSE_MEMORY = 50
#: steps a registered pose must explain the rows before its in-view sets are used
_CONFIRM = 3
#: steps in a row a confirmed pose may fail to explain the rows before it is registered anew
_MAX_MISSES = 5
#: variance (m²) of the pose estimate's position, added to each vehicle's for the in-view test
_POSE_VARIANCE = 1.0


def _squared_distances(points: FloatArray, mean: FloatArray, var: FloatArray) -> FloatArray:
    """‖points − mean‖² / var for points (..., M, 2) against vehicles (N, 2), var (N,): (..., M, N)."""
    diff = points[..., :, None, :] - mean
    return (diff**2).sum(-1) / var


class RadarFields:
    """The estimated poses of the road-side radars and the vehicles each sees (module docstring).

    model : the setup's radar model (range and field of view); gate : the χ²₂ gate of a row
    against a predicted vehicle; view_confidence : least probability of the in-view set.
    """

    def __init__(self, model: InfrastructureRadar, gate: float, view_confidence: float) -> None:
        self.model = model
        self.gate = gate
        self.view_confidence = view_confidence
        self.poses: dict[int, FloatArray] = {}
        self._seen: dict[int, int] = {}
        self._misses: dict[int, int] = {}

    def _nearest(self, pose: FloatArray, q: FloatArray, p: FloatArray, var: FloatArray
                 ) -> tuple[IntArray, FloatArray]:
        """Each row's nearest predicted vehicle and its squared distance in σ: (M,), (M,)."""
        g = q @ rotation(pose[2]).T + pose[:2]
        d2 = _squared_distances(g, p, var)
        nearest = d2.argmin(-1)
        return nearest, d2[np.arange(q.shape[0]), nearest]

    def _search(self, q: FloatArray, p: FloatArray, var: FloatArray) -> FloatArray | None:
        """Registration of the rows q (M, 2) on the vehicles p (N, 2): a pose, or None."""
        M, N = q.shape[0], p.shape[0]
        dq = np.linalg.norm(q[:, None] - q[None], axis=-1)
        i, j = np.unravel_index(np.argmax(dq), dq.shape)
        dp = p[None, :, :] - p[:, None, :]                                   # (a, b): p_b − p_a
        tol = 3.0 * np.sqrt(var[:, None] + var[None, :])
        a, b = np.nonzero((np.abs(np.linalg.norm(dp, axis=-1) - dq[i, j]) <= tol) & ~np.eye(N, dtype=bool))
        if a.size == 0:
            return None
        theta = (np.arctan2(dp[a, b, 1], dp[a, b, 0])
                 - np.arctan2(q[j, 1] - q[i, 1], q[j, 0] - q[i, 0]))
        R = rotation(theta)                                                  # (C, 2, 2)
        t = 0.5 * (p[a] + p[b]) - R @ (0.5 * (q[i] + q[j]))
        g = np.einsum("cij,mj->cmi", R, q) + t[:, None, :]                   # (C, M, 2)
        cost = np.minimum(_squared_distances(g, p, var).min(-1), self.gate).sum(-1)
        poses = np.column_stack([t, theta])
        cost = cost + self.gate * np.maximum(self._count_in_view(poses, p) - M, 0)
        pose = poses[np.argmin(cost)]
        nearest, d2 = self._nearest(pose, q, p, var)
        if np.unique(nearest).size == M:
            pose = fit_pose(p[nearest], q)
            nearest, d2 = self._nearest(pose, q, p, var)
        return pose if (d2 <= self.gate).all() else None

    def _count_in_view(self, poses: FloatArray, p: FloatArray) -> IntArray:
        """How many of the points p (N, 2) each pose (C, 3) would see: (C,)."""
        local = to_local(poses, p)                                           # (C, N, 2)
        seen = np.hypot(local[..., 0], local[..., 1]) <= self.model.max_range
        if self.model.field_of_view < np.pi:
            seen &= np.abs(np.arctan2(local[..., 1], local[..., 0])) <= self.model.field_of_view
        return seen.sum(-1)

    def _track(self, radar: int, q: FloatArray, p: FloatArray, var: FloatArray) -> FloatArray | None:
        """The radar's pose this step, once confirmed (None before): tracked while it explains
        the rows; a pose that fails before it is confirmed, or `_MAX_MISSES` steps in a row
        after, is dropped and the rows are registered anew."""
        pose = self.poses.get(radar)
        if pose is not None:
            nearest, d2 = self._nearest(pose, q, p, var)
            if (d2 <= self.gate).all():
                self._misses[radar] = 0
                if q.shape[0] >= 2 and np.unique(nearest).size == q.shape[0]:
                    fit = fit_pose(p[nearest], q)
                    n = min(self._seen[radar], _POSE_MEMORY)
                    # running average of a static pose; the angle through its wrapped difference
                    turn = np.angle(np.exp(1j * (fit[2] - pose[2])))
                    pose = np.r_[(n * pose[:2] + fit[:2]) / (n + 1), pose[2] + turn / (n + 1)]
                    self.poses[radar] = pose
                    self._seen[radar] += 1
            else:
                self._misses[radar] += 1
                if self._seen[radar] < _CONFIRM or self._misses[radar] > _MAX_MISSES:
                    del self.poses[radar]
                    pose = None
        if pose is None and q.shape[0] >= 2:
            pose = self._search(q, p, var)
            if pose is not None:
                self.poses[radar], self._seen[radar], self._misses[radar] = pose, 1, 0
        return pose if pose is not None and self._seen[radar] >= _CONFIRM else None

    def in_view(self, radar: int, q: FloatArray, p: FloatArray, var: FloatArray
                ) -> tuple[IntArray | None, str]:
        """Indices of the vehicles radar `radar` sees, from its rows q (M, 2) and the predicted
        positions p (N, 2) with isotropic variances var (N,); or None and the reason."""
        M = q.shape[0]
        if M > p.shape[0]:
            return None, f"{M} rows but {p.shape[0]} vehicles present"
        pose = self._track(radar, q, p, var)
        if pose is None:
            return None, "its pose is not registered yet (or not confirmed)"
        local = to_local(pose, p)
        dist = np.hypot(local[:, 0], local[:, 1])
        sigma = np.sqrt(var + _POSE_VARIANCE)
        from scipy.special import ndtr  # here, not at import: `import cooploc` stays light

        prob = ndtr((self.model.max_range - dist) / sigma)                   # inside the range
        if self.model.field_of_view < np.pi:                                # and the bearing
            bearing = np.abs(np.arctan2(local[:, 1], local[:, 0]))
            prob = prob * ndtr((self.model.field_of_view - bearing) * dist / sigma)
        order = np.argsort(-prob, kind="stable")
        chosen, rest = order[:M], order[M:]
        with np.errstate(divide="ignore"):
            log_conf = np.log(prob[chosen]).sum() + np.log1p(-prob[rest]).sum()
        if not log_conf >= np.log(self.view_confidence):
            return None, f"which {M} vehicles it sees is uncertain (probability {np.exp(log_conf):.2g})"
        return np.sort(chosen), ""


def sees_every_vehicle(setup: Setup) -> bool:
    """The papers' setup: one radar whose field is unbounded and all around (it sees every vehicle)."""
    radar = setup.sensors.get("radar")
    return (radar is not None and len(setup.infrastructure_ids) <= 1
            and bool(np.isinf(getattr(radar, "max_range", np.inf)))
            and getattr(radar, "field_of_view", np.pi) >= np.pi)


def topology_nis(p: FloatArray, var: FloatArray, T: float, radar_var: float) -> float:
    """NIS of a measured topology T against its prediction from the beliefs: positions
    p (n, 2) with isotropic variances var (n,), radar rows of per-axis variance radar_var
    (linearised, 1 dof; the mean and variance of T at exact positions: `topology_moments`)."""
    from cooploc.estimators.sme.pseudo_measurement import topology_moments

    n = p.shape[0]
    mean_T, var_T = topology_moments(p, radar_var)
    grad = 2.0 * n * (p - p.mean(axis=0))                                   # ∇_{p_i} T
    S = float(var_T + (grad**2).sum(-1) @ var)
    return float((T - mean_T) ** 2 / S)
