"""The estimator interface (DESIGN §4) and what every estimator shares.

An estimator is constructed once per run with the static `Setup`, its frozen `Params`
and its own random generator, then fed one `Frame` at a time:

    est = GnssKF(setup, GnssKFParams(), rng)
    for frame in recording.frames:
        estimate = est.step(frame)

Known-association references (`needs_truth = True`) also receive an
`AssociationTruth` — the measurement origins and infrastructure poses of the run, and
nothing else — so that no estimator can read true states.

`checked_states` turns an estimator's own beliefs into the `StateSet` it reports; where
its numerics broke (a non-finite mean, a covariance no longer positive definite) it
raises `EstimatorError` naming the estimator, the entity and what broke — not the
`InvalidInputError` with an array dump that `StateSet` gives a user's bad input.

`VehicleBeliefs` is the bookkeeping of per-vehicle Gaussian beliefs under traffic:
vehicles that leave are dropped, vehicles that enter start from their prior in
`Setup.vehicle_prior` or, failing that, from a broad belief centred on their first
GNSS fix (`birth_beliefs`).

`gnss_position_part` and `position_fixes` give the estimators that model GNSS as position
fixes the position-only marginal of rows that hold more (`sumo-*`'s z = [p, v] + w).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from cooploc.errors import ConfigError, EstimatorError, InvalidInputError
from cooploc.gaussian import Gaussians, kf_predict
from cooploc.params import Params
from cooploc.types import Batch, Estimate, FloatArray, Frame, IntArray, MotionModel, Setup, StateSet

__all__ = [
    "Estimator",
    "VehicleBeliefs",
    "birth_beliefs",
    "checked_states",
    "default_birth_cov",
    "gnss_position_part",
    "position_fixes",
    "predict_steps",
]


@runtime_checkable
class Estimator(Protocol):
    """A recursive estimator: `step(frame) -> Estimate` once per step."""

    name: ClassVar[str]
    summary: ClassVar[str]
    Params: ClassVar[type[Params]]
    needs_truth: ClassVar[bool]
    default_preset: ClassVar[str]
    #: measurement kinds (`Setup.sensors` keys) without which the method cannot run;
    #: `make_estimator` refuses a scenario that lacks one with a `ConfigError`
    required_sensors: ClassVar[tuple[str, ...]]
    #: measurement kind → the sensor models (`SensorModel.name`) of that kind the method
    #: can read; `make_estimator` refuses a scenario of which it can use nothing
    #: (`cooploc.registry.unused_kinds`)
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]]

    def step(self, frame: Frame) -> Estimate: ...


def checked_states(estimator: str, entities: str, ids: IntArray, mean: FloatArray,
                   cov: FloatArray) -> StateSet:
    """`StateSet(ids, mean, cov)` of an estimator's beliefs; `EstimatorError` where they broke.

    `entities` names them in the message ("vehicle", "feature"). A belief that is not
    finite or whose covariance is not symmetric positive definite is the estimator's
    numerical failure, not bad input: the error names the first such entity and its
    smallest and largest covariance eigenvalues, without the arrays.
    """
    try:
        return StateSet(ids, mean, cov)
    except InvalidInputError:
        pass
    mean, cov = np.asarray(mean, dtype=float), np.asarray(cov, dtype=float)
    finite = np.isfinite(mean).all(axis=1) & np.isfinite(cov).all(axis=(1, 2))
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise EstimatorError(estimator, f"the belief of {entities} {int(ids[i])} is not finite (it diverged)")
    eig = np.linalg.eigvalsh(0.5 * (cov + np.swapaxes(cov, -1, -2)))
    scale = np.maximum(np.abs(cov).max(axis=(1, 2)), np.finfo(float).tiny)
    asym = np.abs(cov - np.swapaxes(cov, -1, -2)).max(axis=(1, 2))
    bad = np.flatnonzero((eig[:, 0] <= np.finfo(float).eps * scale) | (asym > 1e-8 * scale))
    if bad.size == 0:  # not a numerical failure (ids, shapes): StateSet says what
        return StateSet(ids, mean, cov)
    i = int(bad[0])
    raise EstimatorError(estimator, f"the covariance of {entities} {int(ids[i])} is no longer symmetric "
                                    f"positive definite (eigenvalues {eig[i, 0]:.3g} … {eig[i, -1]:.3g}): "
                                    "too ill-conditioned for float64")


def gnss_position_part(setup: Setup, name: str) -> IntArray | None:
    """Which components of the setup's GNSS rows are the vehicle's position, in the order of
    `vehicle_layout.position` (the rows hold the state components `state_indices`).

    None where the rows are the position alone, in that order: callers then use the rows as
    they come, bit for bit. `ConfigError` naming estimator `name` where a row lacks a
    position component.
    """
    position = list(setup.vehicle_layout.position)
    cols = list(getattr(setup.sensors.get("gnss"), "state_indices", position))
    if cols == position:
        return None
    missing = [c for c in position if c not in cols]
    if missing:
        raise ConfigError(f"{name} needs GNSS rows that hold the position {tuple(position)}, got rows "
                          f"of the state components {tuple(cols)}")
    return np.array([cols.index(c) for c in position], dtype=np.int64)


def position_fixes(batch: Batch | None, part: IntArray | None) -> Batch | None:
    """`batch`'s rows as position fixes: z_p = p + w_p with the position block of each
    covariance — exact for Gaussian rows; the other components (e.g. a velocity) are left
    out. `part` from `gnss_position_part` (None: the rows are returned as they are)."""
    return batch if batch is None or part is None else batch.components(part)


def default_birth_cov(setup: Setup) -> FloatArray:
    """Covariance of a vehicle that enters without a prior: `Setup.birth_cov`, or broad.

    Broad means (100 m)² on position, (10 m/s)² on velocity and π² rad² on heading:
    wide enough that the first fix dominates, narrow enough for well-conditioned
    Joseph updates.
    """
    if setup.birth_cov is not None:
        return np.array(setup.birth_cov)
    layout = setup.vehicle_layout
    diag = np.full(layout.dim, 100.0)
    diag[list(layout.position)] = 1e4
    if layout.heading is not None:
        diag[layout.heading] = np.pi**2
    return np.diag(diag)


def predict_steps(belief: Gaussians, model: MotionModel, dt: float, n_steps: int) -> Gaussians:
    """Predict beliefs `n_steps` ahead without measurements (inputs unknown).

    This is what tracking without data would give: a prior stated for step 0 becomes
    the belief of an entity first seen at step k.
    """
    F = model.transition_matrix(dt)
    for _ in range(n_steps):
        belief = kf_predict(belief, F, model.noise_covariance(dt, belief.mean))
    return belief


def birth_beliefs(setup: Setup, ids: IntArray, frame: Frame) -> Gaussians:
    """Initial beliefs of vehicles `ids` first seen in `frame`.

    Vehicles listed in `setup.vehicle_prior` start from it, predicted from step 0 to
    `frame.k` with the motion model (the prior is the belief at the start). Others
    start from `default_birth_cov` centred on their first GNSS fix (position
    components; zero elsewhere). A broad prior centred on the fix it is then updated
    with counts that fix twice, but with weight R/(P_birth) ≈ 1e-3 of it — negligible,
    and it avoids a special first-step update.
    """
    dx = setup.vehicle_layout.dim
    mean = np.zeros((ids.size, dx))
    cov = np.repeat(default_birth_cov(setup)[None], ids.size, axis=0)
    prior = setup.vehicle_prior
    known = np.isin(ids, prior.ids)
    if known.any():
        p = prior.take(ids[known])
        # the prior holds at step 0; a vehicle entering at step k moved unseen since
        predicted = predict_steps(Gaussians(p.mean, p.cov), setup.vehicle_motion, setup.dt, frame.k)
        mean[known], cov[known] = predicted.mean, predicted.cov
    unknown = np.flatnonzero(~known)
    gnss = frame.batches.get("gnss")
    sensor = setup.sensors.get("gnss")
    if unknown.size and gnss is not None and sensor is not None and len(gnss):
        cols = list(getattr(sensor, "state_indices", setup.vehicle_layout.position))
        for i in unknown:  # entering vehicles are few per step; clarity over vectorising
            rows = np.flatnonzero(gnss.subject == ids[i])
            if rows.size:
                mean[i, cols] = gnss.z[rows[0]]
    return Gaussians(mean, cov)


class VehicleBeliefs:
    """Per-vehicle Gaussian beliefs keyed by id, following vehicles in and out.

    `sync(frame)` keeps the beliefs of the vehicles present in `frame`: continuing
    vehicles keep theirs, leaving ones are dropped, entering ones are born. It returns
    the mask of vehicles that were born this step (they are not predicted).
    """

    def __init__(self, setup: Setup) -> None:
        self.setup = setup
        dx = setup.vehicle_layout.dim
        self.ids: IntArray = np.zeros(0, dtype=np.int64)
        self.beliefs = Gaussians(np.zeros((0, dx)), np.zeros((0, dx, dx)))

    def sync(self, frame: Frame) -> np.ndarray:
        present = frame.vehicles
        if present.size == self.ids.size and np.array_equal(np.sort(present), self.ids):
            return np.zeros(self.ids.size, dtype=bool)  # same vehicles as last step
        keep = np.isin(self.ids, present)
        continuing = self.ids[keep]
        born_ids = present[~np.isin(present, continuing)]
        born = birth_beliefs(self.setup, born_ids, frame)
        ids = np.concatenate([continuing, born_ids])
        mean = np.concatenate([self.beliefs.mean[keep], born.mean])
        cov = np.concatenate([self.beliefs.cov[keep], born.cov])
        order = np.argsort(ids, kind="stable")
        self.ids = ids[order]
        self.beliefs = Gaussians(mean[order], cov[order])
        return np.isin(self.ids, born_ids)

