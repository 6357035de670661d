r"""`oracle-pose`, `oracle-pose-smoother`: the known-association bound with the radar poses unknown.

What GNSS, odometry and a road-side radar of unknown pose can give at best once the
association is known. The model is the scenario's own (`Setup`): every vehicle moves
with `Setup.vehicle_motion`, x_k = F x_{k−1} + v, v ~ N(0, Q); a GNSS row is
z = H x + w (Zhang 2016 §3.2 "internal sensor", Gulati 2017 eqs. 6–7), an odometry
row z = H x_k − H x_{k−1} + w (Gulati eqs. 4–5), a radar row
z = R(θ_s)ᵀ(H x − t_s) + w with the radar's pose b_s = [t_s; θ_s] static and unknown
(Zhang §3.2, Gulati §II; `rows.radar_model`). The estimator reads the true origin of
every anonymous row (`AssociationTruth.origin`, DESIGN §4) — never the true states,
nor, unless `known_pose` is set, the radar poses — and estimates the vehicles and the
poses jointly:

- `oracle-pose` (`filter.PoseFilter`): an iterated EKF over all vehicles and poses.
  `step` returns the *filtered* estimate; it has no `smooth`, so it is scored on
  filtered estimates — the bound for filters (the `zhang2016-*` presets, where
  `kf-known-da`, `sme-*` and `gm-phd` are filters).
- `oracle-pose-smoother` (`smoother.PoseSmoother`): `smooth()` is the MAP estimate of
  every state of the run and of the poses by banded Levenberg–Marquardt with the poses
  as border unknowns (`cooploc.least_squares.solve_lm_bordered`), started from the
  `kf-known-da` filter of the GNSS and odometry rows (what its `step` returns, as the
  factor graphs' `step` returns their linear part) and the rigid fit of each radar's
  rows to it. `cooploc.experiment.estimate` scores it on the smoothed estimates, as it
  does the batch factor graphs — the bound for the `gulati-*` presets, whose headline
  methods are batch smoothers.

With the poses known and linear models both are exact: the Kalman filter (resp. the
RTS smoother) of the joint state. With unknown poses they are the Gauss–Newton
(Laplace) approximations, whose only approximations are the linearisation in θ and,
for the filter, relinearising a step's rows only once their pose is in the state.

Choices: a radar joins the filter once one frame has its rows of two vehicles (one
vehicle cannot fix a yaw in one frame; the smoother fits it from all steps); its pose
gets a diffuse Gaussian prior centred on the rigid fit of the rows
(`pose_prior_position_std`, `pose_prior_yaw_std`) — ~1e-5 of the information of one
radar row at the defaults, but it keeps every problem well-posed. `Estimate.info`:
"poses" (radars with an estimated pose), "nis" ((NIS, degrees of freedom) of the
step's rows, filter only), "smoothed", "iterations", "cost" (smoother).

The model, its use as a bound and its measured cost: docs/oracle_pose.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cooploc.errors import EstimatorError
from cooploc.estimators.base import checked_states
from cooploc.estimators.kf_known_da import KFKnownDA
from cooploc.estimators.oracle_pose.filter import PoseFilter
from cooploc.estimators.oracle_pose.rows import Chains, FrameRows, Models, Rows, StepRecord, radar_model
from cooploc.estimators.oracle_pose.smoother import PoseSmoother, initial_poses
from cooploc.geometry import wrap_angle
from cooploc.params import Params, param
from cooploc.registry import register_estimator
from cooploc.types import AssociationTruth, Estimate, FloatArray, Frame, Setup

__all__ = [
    "Chains",
    "FrameRows",
    "Models",
    "OraclePose",
    "OraclePoseParams",
    "OraclePoseSmoother",
    "PoseFilter",
    "PoseSmoother",
    "Rows",
    "StepRecord",
    "initial_poses",
    "radar_model",
]


@dataclass(frozen=True)
class OraclePoseParams(Params):
    """Settings of `oracle-pose` and `oracle-pose-smoother`.

    Attributes
    ----------
    known_pose : read the radar poses from `AssociationTruth.sensor_poses` and hold them
        fixed (an ablation: what not knowing them costs); default False, estimate them.
    pose_prior_position_std, pose_prior_yaw_std : m, rad — the diffuse prior of a pose
        at its first fit (module docstring).
    max_iterations : Gauss–Newton iterations per filter update, LM iterations of the smoother.
    tolerance : a filter update stops when no state component moves more than this.
    relative_tolerance, absolute_tolerance : the smoother's LM stops when the cost falls
        by less (`cooploc.least_squares.solve_lm`).
    """

    known_pose: bool = False
    pose_prior_position_std: float = param(100.0, gt=0, finite=True)
    pose_prior_yaw_std: float = param(float(np.pi), gt=0, finite=True)
    max_iterations: int = param(20, ge=1)
    tolerance: float = param(1e-9, gt=0)
    relative_tolerance: float = param(1e-12, gt=0)
    absolute_tolerance: float = param(1e-9, gt=0)


class _PoseBound:
    """What the two bounds share: their interface, the origins they read, a frame's rows."""

    Params: ClassVar[type[Params]] = OraclePoseParams
    needs_truth: ClassVar[bool] = True
    default_preset: ClassVar[str] = "gulati-2v"
    required_sensors: ClassVar[tuple[str, ...]] = ("radar",)
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "gnss": ("gnss-position", "anonymous-position"), "odometry": ("odometry",),
        "radar": ("infrastructure-radar",)}

    def __init__(self, setup: Setup, params: OraclePoseParams, truth: AssociationTruth) -> None:
        self.setup, self.params = setup, params
        self._origin = truth.origin
        self._known = _known_poses(setup, params, truth)
        self.pose_prior_cov = _pose_prior(params)

    def _rows(self, frame: Frame) -> FrameRows:
        return FrameRows.of(frame, self._origin[frame.k] if frame.k < len(self._origin) else {})


@register_estimator
class OraclePose(_PoseBound):
    """Iterated EKF of all vehicles and the radar poses with the true association (filtered).

    Uses: GNSS rows (identified or anonymous, by their true origin), odometry, and the
    radar rows by their true origin, with the radar's pose as an unknown.
    """

    name: ClassVar[str] = "oracle-pose"
    bound: ClassVar[str | None] = "oracle-pose"
    summary: ClassVar[str] = ("iterated EKF of the vehicles AND the radar's unknown pose from GPS, odometry "
                              "and radar rows with KNOWN association — the filtered bound, not a method")

    def __init__(self, setup: Setup, params: OraclePoseParams, rng: np.random.Generator, *,
                 truth: AssociationTruth) -> None:
        super().__init__(setup, params, truth)
        self.filter = PoseFilter(setup, self.name, self.pose_prior_cov, self._known, params.max_iterations,
                                 params.tolerance)

    def step(self, frame: Frame) -> Estimate:
        """Fuse the frame's rows; the filtered estimate of the vehicles present."""
        rows = self._rows(frame)
        mean, cov = self.filter.step(frame, rows)
        return Estimate(checked_states(self.name, "vehicle", rows.ids, mean, cov),
                        info={"poses": self.filter.n_poses, "nis": self.filter.nis})

    def poses(self) -> dict[int, tuple[FloatArray, FloatArray]]:
        """Radar id → (filtered pose [x, y, θ], its covariance (3, 3)); known poses are not listed."""
        return self.filter.pose_estimates()


@register_estimator
class OraclePoseSmoother(_PoseBound):
    """The MAP estimate of the whole run and of the radar poses with the true association.

    `step` returns the initial guess, `kf-known-da`'s filter of the GNSS and odometry rows
    (no radar, as the factor graphs' `step`); `smooth()` the bound. Uses: as `oracle-pose`.
    """

    name: ClassVar[str] = "oracle-pose-smoother"
    bound: ClassVar[str | None] = "oracle-pose-smoother"
    summary: ClassVar[str] = ("batch LM smoother of the vehicles AND the radar's unknown pose from GPS, "
                              "odometry and radar rows with KNOWN association — the smoothed bound")

    def __init__(self, setup: Setup, params: OraclePoseParams, rng: np.random.Generator, *,
                 truth: AssociationTruth) -> None:
        super().__init__(setup, params, truth)
        self._initial = KFKnownDA(setup, KFKnownDA.Params(), rng, truth=truth)
        self.chains = Chains(setup)
        self.models = Models.of(setup)
        self.initial_poses: dict[int, FloatArray] = {}
        self.smoothed_poses: dict[int, tuple[FloatArray, FloatArray]] = {}

    def step(self, frame: Frame) -> Estimate:
        """Record the frame's rows; the initial guess (GNSS + odometry filter) of this step."""
        rows = self._rows(frame)
        self.chains.add(frame, rows)
        out = self._initial.step(frame)
        self.chains.set_mean(out.vehicles.take(rows.ids).mean if len(rows.ids) else
                             np.zeros((0, self.models.dim)))
        return Estimate(out.vehicles, info={"filtered": True})

    def problem(self) -> PoseSmoother:
        """The batch problem of the steps so far (poses started from their rigid fit)."""
        history = self.chains.history
        self.initial_poses = {} if self._known is not None else initial_poses(history, self.models)
        return PoseSmoother(history, self.models, self.initial_poses, self.pose_prior_cov, self._known)

    def smooth(self) -> list[Estimate]:
        """Smoothed estimate of every step so far (one LM solve over all states and poses)."""
        history = self.chains.history
        if self.chains.n_vars == 0:
            return [Estimate(checked_states(self.name, "vehicle", h.rows.ids, h.mean,
                                            np.zeros((0, self.models.dim, self.models.dim))),
                             info={"smoothed": True}) for h in history]
        p = self.params
        problem = self.problem()
        try:
            result = problem.solve(max_iterations=p.max_iterations, relative_tolerance=p.relative_tolerance,
                                   absolute_tolerance=p.absolute_tolerance)
        except np.linalg.LinAlgError as exc:
            raise EstimatorError(self.name, f"the information matrix of the run is not positive definite "
                                 f"({exc})") from None
        assert result.cov is not None
        if result.border is not None and result.border_cov is not None:
            for s, sensor in enumerate(problem.pose_ids):
                b = result.border[3 * s:3 * s + 3].copy()
                b[2] = wrap_angle(b[2])
                self.smoothed_poses[sensor] = (b, result.border_cov[3 * s:3 * s + 3, 3 * s:3 * s + 3])
        info = {"smoothed": True, "iterations": result.iterations, "cost": result.cost,
                "poses": len(problem.pose_ids)}
        return [Estimate(checked_states(self.name, "vehicle", h.rows.ids, result.x[h.vars],
                                        result.cov[h.vars]), info=info) for h in history]


def _known_poses(setup: Setup, params: OraclePoseParams, truth: AssociationTruth
                 ) -> dict[int, FloatArray] | None:
    """Radar id → its true pose where `known_pose` is set (else None)."""
    if not params.known_pose:
        return None
    poses = np.asarray(truth.sensor_poses, dtype=float).reshape(-1, 3)
    return {int(s): poses[i] for i, s in enumerate(setup.infrastructure_ids) if i < len(poses)}


def _pose_prior(params: OraclePoseParams) -> FloatArray:
    return np.diag([params.pose_prior_position_std**2] * 2 + [params.pose_prior_yaw_std**2])
