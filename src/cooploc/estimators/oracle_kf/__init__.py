"""`oracle-kf`: the centralized Kalman filter with known association — the accuracy bound.

One Kalman filter over the stacked state θ = [x_1; …; x_S; f_1; …; f_K] of every
vehicle and feature (Fröhle §III, eq. (9) with the association variables fixed to
their true values), fed every GNSS row (z = H x_s + w), every V2F row whose true origin
is read from `Truth.origin` (z = H f_k − H x_s + w, Fröhle eq. 1) and, where the
scenario has the odometry sensor, every odometry row z = H x_k − H x_{k−1} + w of a
vehicle (Gulati 2017 eq. 4; `sensors.Odometry`). For the linear-Gaussian scenarios
(Fröhle §V) this is the exact MMSE estimator given the association, so no estimator
that must also infer the association can beat it beyond Monte Carlo noise.

Odometry relates two states, so it is fused exactly by stochastic cloning (Roumeliotis &
Burdick 2002; `gaussian.kf_update_relative`, as `gnss-kf` and `oracle-pose` do): before
the prediction, c = H x_{k−1} of every vehicle in the state (present at k − 1 and k)
with an odometry row joins the joint state with all its correlations — with the
vehicle, the other vehicles and the features — is kept static by the prediction, and
the row z = H x_k − c + w is one more linear row of the update; then c is marginalised
out. A vehicle entering at k (no state at k − 1) or without a row gets no odometry
update. Where the scenario has no odometry sensor nothing changes, bit for bit.

Fröhle §V-B compares its loopy BP with "a centralized Kalman filter over the joint total
state"; Brambilla 2020 calls the same reference "ICP with known DA".

It reads only the association (`AssociationTruth`: origins and infrastructure poses),
never true states. Clutter rows (origin −1) are discarded — the oracle knows them.
Vehicles that leave are marginalised out, features unseen for `feature_timeout` steps
are dropped. `Estimate.info["nis"]`: the step's NIS with its m degrees of freedom
((0.0, 0) on a step without rows; `types.Estimate`).

Two forms compute the same filter (equal up to round-off; tests hold them within 1e-9):

- `components` (default): the joint covariance is block diagonal over the connected
  components of the coupling graph (entities are coupled once a V2F row has linked
  them, directly or through others), so each component keeps its own dense
  covariance; a V2F row between components merges them. The update is done in
  information form on the coordinates the rows observe: cost per component
  O(D_c² r_c) for D_c states and r_c observed coordinates, instead of O(D³) for all.
- `dense` (`dense=True`): the one joint covariance of every vehicle and feature and a
  Joseph-form update with all rows stacked — the reference the tests compare with.

The model written out: docs/oracle_kf.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from cooploc.budget import Sizes
from cooploc.estimators.oracle_kf.components import ComponentFilter
from cooploc.estimators.oracle_kf.dense import DenseJointFilter
from cooploc.estimators.oracle_kf.params import OracleKFParams
from cooploc.params import Params
from cooploc.registry import register_estimator
from cooploc.types import AssociationTruth, Estimate, Frame, Setup

__all__ = ["OracleKF", "OracleKFParams"]


@register_estimator
class OracleKF:
    """Joint Kalman filter over all vehicles and features with the true association.

    Uses: identified GNSS rows, V2F rows (their true origins) and odometry rows. Anonymous
    GNSS, radar and AoA it does not fuse: where a scenario has those it is no bound for
    the methods that read them.
    """

    name: ClassVar[str] = "oracle-kf"
    bound: ClassVar[str | None] = "oracle-kf"
    summary: ClassVar[str] = (
        "centralized joint Kalman filter with KNOWN association (reads Truth.origin) — "
        "the accuracy bound, not a method"
    )
    Params: ClassVar[type[Params]] = OracleKFParams
    needs_truth: ClassVar[bool] = True
    default_preset: ClassVar[str] = "froehle2018"
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "gnss": ("gnss-position",), "v2f": ("relative-position",), "odometry": ("odometry",)}

    @staticmethod
    def memory_bytes(sizes: Sizes, params: OracleKFParams) -> float:
        """Peak memory of the joint state (`cooploc.budget`) where everything couples into one
        component: the dense D × D covariance and the few D × D products of one update,
        D = state_dim × (S + K)."""
        dim = sizes.state_dim * (sizes.n_vehicles + sizes.n_features)
        return 4 * 8.0 * dim**2

    @staticmethod
    def flops_per_step(sizes: Sizes, params: OracleKFParams) -> float:
        """Operations of one step (`cooploc.budget`) where everything couples into one
        component: the update multiplies D × D matrices a few times, ~ 4 D³ (the
        component form does far less where the coupling stays sparse)."""
        dim = sizes.state_dim * (sizes.n_vehicles + sizes.n_features)
        return 4.0 * dim**3

    def __init__(self, setup: Setup, params: OracleKFParams, rng: np.random.Generator, *,
                 truth: AssociationTruth) -> None:
        self.setup, self.params, self.truth = setup, params, truth
        self._filter = (DenseJointFilter if params.dense else ComponentFilter)(setup, params, truth)

    def step(self, frame: Frame) -> Estimate:
        return self._filter.step(frame)
