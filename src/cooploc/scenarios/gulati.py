"""Gulati et al. (IV 2017), §II and §IV-A: N vehicles, GPS, odometry and a road-side radar.

Model (paper §II and §IV-A)
---------------------------
- N vehicles (2, 3 or 4) on a plane, 250 steps of T = 1 s.
- GPS of every vehicle: z = p + w, w ~ N(0, diag(9, 9)) m² (eq. 6).
- Odometry of every vehicle: the displacement since the previous step in the global
  frame, z_k = p_k − p_{k−1} + w, w ~ N(0, diag(1, 1)) m² (eqs. 4, 9–10).
- One infrastructure radar with an unknown pose (position t, yaw θ): it reports every
  vehicle in its own frame, z = R(θ)ᵀ(p − t) + w, w ~ N(0, diag(0.1, 0.1)) m², as
  anonymous rows in random order (§II: no identification mechanism).
- No clutter and no missed detections (§II, §IV-A).

Choices the paper leaves open (parameters of `GulatiParams`)
------------------------------------------------------------
- Trajectories: the paper says only "random trajectory". Each vehicle follows the
  constant-velocity model with white acceleration noise of density
  `noise_density` = 1 m²/s³ (`motion.ConstantVelocity`; eq. 20 is this model, written
  for T = 1 in its discrete-acceleration form). Vehicles start at independent
  positions p_0 ~ N(0, `start_position_std`² I) with `start_position_std` = 50 m and
  velocities v_0 ~ N(0, `start_velocity_std`² I) with `start_velocity_std` = 5 m/s, so
  that they are tens of metres apart and their trajectories bend randomly.
- Radar pose: position uniform in [−`radar_extent`, `radar_extent`]² (100 m) and yaw
  uniform in [−π, π), drawn anew every run and kept only in `Truth.sensor_poses`.
- Estimators get the start distribution as the vehicle prior (`Setup.vehicle_prior`).
- The state is [p_x, p_y, v_x, v_y] (the Kalman filter of eq. 20 needs the velocity);
  the factor graphs estimate positions.
- Missed detections and clutter (the paper's future work): `detection_probability`
  thins radar rows; `clutter_rate` adds Poisson(λ) rows per step, uniform over a
  square of half-width `clutter_extent` around the radar, in its frame.

Ids: vehicles 0..N−1, radar 100. Batch kinds: ``gnss``, ``odometry`` (from step 1),
``radar``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.budget import Sizes
from cooploc.motion import ConstantVelocity, simulate
from cooploc.params import Params, param
from cooploc.registry import Preset, register_scenario
from cooploc.scenarios import limits
from cooploc.sensors import GnssPosition, InfrastructureRadar, Odometry
from cooploc.types import Batch, Frame, Recording, Setup, StateLayout, StateSet, Truth

__all__ = ["PRESETS", "RADAR_ID", "GulatiParams", "generate"]

RADAR_ID = 100


@dataclass(frozen=True)
class GulatiParams(Params):
    """Parameters of the Gulati scenario; defaults are the paper's §IV-A (2 vehicles).

    Attributes
    ----------
    n_vehicles : N.
    n_steps : number of steps (paper: 250).
    dt : T in s (paper: 1).
    gnss_variance, odometry_variance, radar_variance : per-axis variances in m²
        (paper: 9, 1, 0.1).
    noise_density : r of the CV model of the trajectories, m²/s³ (not in the paper).
    start_position_std, start_velocity_std : spread of the start (m, m/s).
    radar_extent : half-width in m of the square the radar position is drawn from.
    detection_probability : P_D of each radar row (paper: 1).
    clutter_rate : mean clutter rows per radar scan (paper: 0).
    clutter_extent : half-width in m of the clutter square (radar frame).
    """

    n_vehicles: int = param(2, ge=1)
    n_steps: int = param(250, ge=1)
    dt: float = param(1.0, gt=0, le=limits.STEP)
    gnss_variance: float = param(9.0, ge=limits.VARIANCE_MIN, le=limits.LENGTH_VARIANCE)
    odometry_variance: float = param(1.0, ge=limits.VARIANCE_MIN, le=limits.LENGTH_VARIANCE)
    radar_variance: float = param(0.1, ge=limits.VARIANCE_MIN, le=limits.LENGTH_VARIANCE)
    noise_density: float = param(1.0, ge=0, le=limits.NOISE_DENSITY)
    start_position_std: float = param(50.0, ge=limits.STD_MIN, le=limits.LENGTH)
    start_velocity_std: float = param(5.0, ge=limits.STD_MIN, le=limits.SPEED)
    radar_extent: float = param(100.0, gt=0, le=limits.LENGTH)
    detection_probability: float = param(1.0, gt=0, le=1)
    clutter_rate: float = param(0.0, ge=0, le=limits.CLUTTER_RATE)
    clutter_extent: float = param(200.0, gt=0, le=limits.LENGTH)

    def sizes(self) -> Sizes:
        """Steps, vehicles and features of one run (for `cooploc.budget`)."""
        return Sizes(self.n_steps, self.n_vehicles)


def generate(params: GulatiParams, rng: np.random.Generator) -> Recording:
    """Simulate one run of the scenario."""
    N, T, dt = params.n_vehicles, params.n_steps, params.dt
    motion = ConstantVelocity(params.noise_density)
    ids = np.arange(N, dtype=np.int64)
    # independent streams: trajectories, radar pose, and each sensor's noise
    rng_motion, rng_pose, rng_gnss, rng_odometry, rng_radar = rng.spawn(5)
    start_cov = np.diag([params.start_position_std**2] * 2 + [params.start_velocity_std**2] * 2)
    x0 = rng_motion.multivariate_normal(np.zeros(4), start_cov, size=N)
    states = simulate(motion, x0, T, dt, rng_motion)                            # (T, N, 4)
    pose = np.r_[rng_pose.uniform(-params.radar_extent, params.radar_extent, 2),
                 rng_pose.uniform(-np.pi, np.pi)]

    gnss = GnssPosition(default_cov=params.gnss_variance * np.eye(2))
    odometry = Odometry(default_cov=params.odometry_variance * np.eye(2))
    radar = InfrastructureRadar(default_cov=params.radar_variance * np.eye(2))
    extent = params.clutter_extent
    region = np.array([[-extent, extent], [-extent, extent]])

    frames, origins = [], []
    for k in range(T):
        batches = {"gnss": gnss.measure(ids, states[k], rng_gnss)}
        origin = {"gnss": ids}
        if k > 0:
            batches["odometry"] = odometry.measure(ids, states[k], states[k - 1], rng_odometry)
        else:
            batches["odometry"] = Batch.empty(2)
        origin["odometry"] = ids if k > 0 else np.zeros(0, np.int64)
        batches["radar"], origin["radar"] = radar.measure(
            RADAR_ID, pose, ids, states[k], rng_radar,
            detection_probability=params.detection_probability, clutter_rate=params.clutter_rate,
            clutter_region=region)
        frames.append(Frame(k, k * dt, ids, batches))
        origins.append(origin)

    setup = Setup(
        dt=dt,
        n_steps=T,
        vehicle_layout=StateLayout.position_velocity(2),
        vehicle_motion=motion,
        vehicle_prior=StateSet(ids, np.zeros((N, 4)), np.repeat(start_cov[None], N, 0)),
        sensors={"gnss": gnss, "odometry": odometry, "radar": radar},
        detection_probability=params.detection_probability,
        clutter_rate=params.clutter_rate,
        clutter_region=region if params.clutter_rate > 0 else None,
        infrastructure_ids=(RADAR_ID,),
        description=f"Gulati 2017 §IV-A: {N} vehicles, GPS + odometry + anonymous radar, "
                    f"{T} steps of {dt} s",
    )
    truth = Truth.always_present(ids, states, origins, sensor_poses=pose[None])
    return Recording(setup, frames, truth)


PRESETS = register_scenario("gulati", generate, [
    Preset(
        name=f"gulati-{n}v",
        params=GulatiParams(n_vehicles=n),
        summary=f"Gulati 2017 §IV-A: {n} vehicles, GPS 9 m², odometry 1 m², radar 0.1 m² "
                "(unknown pose), 250 steps",
        doc=f"Reproduces the {n}-vehicle row of Tables I–II"
            + (" and Figs. 3–4" if n == 2 else " and Figs. 5–6" if n == 4 else "")
            + " of Gulati et al. (IV 2017).",
        # the compared graphs are batch smoothers: the bound is the smoothed one
        bound="oracle-pose-smoother",
    )
    for n in (2, 3, 4)
])
