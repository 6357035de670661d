"""`motorway`: vehicles on a straight multi-lane motorway with GNSS fixes, some of them multipath.

Importing this module registers the family and its presets with cooploc
(`cooploc.register_scenario`); the package's entry point in the group
``cooploc.scenarios`` is what makes cooploc import it.

Model
-----
- Road: straight along the x axis, lane ℓ = 0, 1, … centred at y = ℓ · `lane_width`.
  Vehicle i (ids 0..n−1) starts in lane i mod `n_lanes`, `gap` metres behind the
  vehicle ahead in its lane, at p_x ~ N(slot, `start_std`²), p_y ~ N(lane centre,
  0.5²) m, v_x ~ N(`speed`, `speed_std`²), v_y ~ N(0, 0.2²) m/s. Estimators are given
  exactly this distribution as the prior.
- Motion: constant velocity whose velocity takes random-walk steps turned to the
  direction of motion (`cooploc.motion.CVVelocityNoise`): `speed_noise` m/s per step
  along the road, `lateral_noise` across it, so that vehicles speed up and slow down
  but keep roughly to their lanes (nothing holds them there: over a long run they drift
  as the noise says).
- GNSS: one fix per vehicle and step, z = H x + e, e ~ N(0, σ² I_2)
  (`cooploc.sensors.GnssPosition`). With probability `outlier_probability` a fix is a
  multipath outlier: an extra error drawn from N(0, `outlier_std`² I_2) is added, while
  the fix still reports its nominal covariance σ² I_2 — the receiver does not know.

Choices: the trajectories, the GNSS noise and the outliers come from independent
child generators, and every outlier offset is drawn whether it is used or not, so that
changing `outlier_probability` changes which fixes are off and nothing else.

Complexity: O(T n) to generate T steps of n vehicles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.motion import CVVelocityNoise, simulate
from cooploc.params import Params, param
from cooploc.registry import Preset, register_scenario
from cooploc.sensors import GnssPosition
from cooploc.types import Batch, Frame, Recording, Setup, StateLayout, StateSet, Truth

__all__ = ["PRESETS", "MotorwayParams", "generate"]

#: how far a vehicle starts from its lane's centre line (m) and how fast it drifts
#: across the road at the start (m/s), as standard deviations
LATERAL_POSITION_STD = 0.5
LATERAL_SPEED_STD = 0.2


@dataclass(frozen=True)
class MotorwayParams(Params):
    """Parameters of the motorway scenario.

    Attributes
    ----------
    n_vehicles : number of vehicles.
    n_lanes : lanes of the road.
    n_steps : number of steps.
    dt : step length in s (also the GNSS fix interval).
    lane_width : distance between lane centres in m.
    gap : distance in m between consecutive vehicles of a lane at the start.
    start_std : spread in m of a vehicle's start along the road.
    speed, speed_std : mean and spread of the vehicles' starting speed in m/s.
    speed_noise, lateral_noise : standard deviation of the velocity step per dt along and
        across the direction of motion in m/s.
    gnss_variance : σ², the variance in m² of each axis of a fix.
    outlier_probability : probability that a fix is a multipath outlier.
    outlier_std : standard deviation in m of each axis of an outlier's extra error.
    """

    n_vehicles: int = param(6, ge=1)
    n_lanes: int = param(3, ge=1, le=6)
    n_steps: int = param(300, ge=1)
    dt: float = param(0.2, gt=0)
    lane_width: float = param(3.5, gt=0)
    gap: float = param(40.0, gt=0)
    start_std: float = param(5.0, gt=0)
    speed: float = param(30.0, ge=0, le=70)
    speed_std: float = param(2.0, gt=0)
    speed_noise: float = param(0.1, gt=0)
    lateral_noise: float = param(0.005, ge=0)
    gnss_variance: float = param(4.0, gt=0)
    outlier_probability: float = param(0.0, ge=0, lt=1)
    outlier_std: float = param(20.0, gt=0)


def generate(params: MotorwayParams, rng: np.random.Generator) -> Recording:
    """Simulate one run of the motorway (deterministic given `rng`)."""
    n, T, dt = params.n_vehicles, params.n_steps, params.dt
    ids = np.arange(n, dtype=np.int64)
    rng_start, rng_motion, rng_gnss, rng_outliers = rng.spawn(4)

    # 1. the start: lane slots, and the spread the estimators are told about (prior)
    lane, rank = ids % params.n_lanes, ids // params.n_lanes
    slot = np.column_stack([-params.gap * rank, params.lane_width * lane,
                            np.full(n, params.speed), np.zeros(n)])
    start_cov = np.diag([params.start_std**2, LATERAL_POSITION_STD**2,
                         params.speed_std**2, LATERAL_SPEED_STD**2])
    x0 = slot + rng_start.multivariate_normal(np.zeros(4), start_cov, size=n)

    # 2. the trajectories: (T, n, 4)
    motion = CVVelocityNoise(params.speed_noise, params.lateral_noise)
    states = simulate(motion, x0, T, dt, rng_motion)

    # 3. the fixes, then the multipath outliers on top of them
    gnss = GnssPosition(default_cov=params.gnss_variance * np.eye(2))
    outlying = rng_outliers.random((T, n)) < params.outlier_probability
    offsets = rng_outliers.normal(0.0, params.outlier_std, size=(T, n, 2))
    frames, origins = [], []
    for k in range(T):
        fix = gnss.measure(ids, states[k], rng_gnss)
        z = fix.z + np.where(outlying[k, :, None], offsets[k], 0.0)
        frames.append(Frame(k, k * dt, ids, {"gnss": Batch(z, fix.cov, fix.sensor, fix.subject)}))
        origins.append({"gnss": ids})

    setup = Setup(
        dt=dt,
        n_steps=T,
        vehicle_layout=StateLayout.position_velocity(2),
        vehicle_motion=motion,
        vehicle_prior=StateSet(ids, slot, np.repeat(start_cov[None], n, axis=0)),
        sensors={"gnss": gnss},
        description=f"motorway: {n} vehicles on {params.n_lanes} lanes, {T} steps of {dt} s, "
                    f"{params.outlier_probability:.0%} multipath fixes",
    )
    return Recording(setup, frames, Truth.always_present(ids, states, origins))


PRESETS = register_scenario("motorway", generate, [
    Preset(
        name="motorway",
        params=MotorwayParams(),
        summary="example plug-in: 6 vehicles on a 3-lane motorway at 30 m/s, GNSS 4 m², no outliers",
        doc="Clean GNSS: the Kalman filter is optimal here; a robust filter shows what it costs.",
    ),
    Preset(
        name="motorway-multipath",
        params=MotorwayParams(outlier_probability=0.1),
        summary="example plug-in: the motorway with 10 % multipath GNSS fixes (20 m outliers)",
        doc="One fix in ten is a multipath outlier: where a robust GNSS update pays.",
    ),
])
