"""Brambilla, Nicoli, Soatti & Deflorio 2020 (T-ITS), §V: the road and crossroad scenarios.

Model (paper §II and §V)
------------------------
- Vehicles, state [p_x, p_y, v_x, v_y], follow the inertial model of eq. (1),
  x_t = A x_{t−1} + B a_{t−1} + w_{t−1}, with zero-mean acceleration a (paper §V-A) and
  driving noise Q = B R(ψ) diag(σ²_a,∥, σ²_a,⊥) R(ψ)ᵀ Bᵀ turned to the driving
  direction ψ (`motion.CVAccelerationInput`). T_s = 1 s. The IMU reading is the
  zero acceleration, so no `imu` batch is emitted: its information is already the
  model's zero input.
- GNSS of position and velocity, eq. (3): z = x + n, R = blockdiag(σ_p² I_2, σ_v² I_2).
- V2F, eq. (4): z = x_k^(F) − x_i^(V) + n (relative position and velocity) for every
  feature within the sensing range R_s, R = blockdiag(σ_p² I_2, σ_v² I_2); rows are
  shuffled per vehicle (`subject` = −1, association unknown).
- V2V links between vehicles within the communication range R_c (`Frame.links`).
- Features follow eq. (2) with a velocity random walk along/across their sidewalk
  (`motion.CVVelocityNoise`, σ_v,∥ = v_f/100, σ_v,⊥ = σ_v,∥/2, §V-B); static features
  (v_f = 0) do not move.

Presets
-------
- ``brambilla-road`` (§V-A, Figs. 6–7): 2 vehicles at 25 km/h with 5 m headway,
  σ_a = 0.2 / 0.001 m/s², GNSS σ_p = 8 m, σ_v = 0.1 m/s; 2 static features on the
  sidewalk d_f apart (`feature_spacing`: the paper's 0.5, 3 and 6 m); V2F σ_p = 0.2 m,
  σ_v = 0.1 m/s.
- ``brambilla-crossroad`` (§V-B, Figs. 1, 8–11): 12 vehicles in 4 clusters of 3, one
  cluster per approach of a cross junction at (0, 0), lanes 500 m long, 50 km/h,
  σ_a = 0.35 / 0.001 m/s², GNSS 9 m / 0.25 m/s, R_c = 250 m, R_s = 75 m; N_f features
  uniform on the sidewalks within 150 m of the centre (`n_features`: 3, 10, 20, 60),
  static or walking along their sidewalk at v_f (`feature_speed`: 1, 2, 5 m/s);
  V2F 0.1 m / 0.1 m/s.

Choices the paper leaves open (parameters here)
------------------------------------------------
- Road geometry (§V-A): the lane is the x axis, the sidewalk the line y = 5 m
  (`sidewalk_offset`); the features sit at x = 0 and x = d_f; the leading vehicle
  starts at x = −`road_start` = −40 m, and the sensing range is R_s = 30 m, so V2F
  sensing starts after a few seconds as in Fig. 7; 12 steps; every vehicle talks
  to every other (R_c = 1 km).
- Crossroad geometry (§V-B): right-hand traffic, lane centres 1.75 m from the road
  axis, sidewalks 8 m from it; each cluster's leader starts 210 m from the centre with
  its followers 20 m apart behind it (`cluster_headway`), so the whole cluster starts
  inside the 250 m area; 32 steps take the leaders through the junction to 235 m
  beyond it. Features are placed uniformly along the four sidewalks within 150 m of
  the centre, outside the junction box; a moving feature walks one way or the other
  along its sidewalk with probability ½.
- Start spread: each vehicle starts at its nominal position plus N(0, 1 m²) along
  its lane and at its nominal speed plus N(0, (0.5 m/s)²); cross-track velocity 0.
  Estimators get no prior (`Setup.vehicle_prior` is empty): every filter starts from
  the vehicle's first GNSS fix with a broad covariance (`Setup.birth_cov`), so the
  GNSS-only error is the paper's, not that of a known start.
- Features are not known in advance (`Setup.feature_prior` is empty): as in the
  paper, a feature no vehicle senses has a uniform belief.
- Ids: vehicles 0..N_v−1 (cluster c holds 3c..3c+2); features 1000 + k.

Links and V2F visibility come from k-d trees (`geometry.links_within`, `close_pairs`),
so a frame costs what its links and rows cost; a run longer than
`streams.STREAM_FROM_STEPS` steps makes its frames on demand (`cooploc.streams`).
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from cooploc.budget import Sizes
from cooploc.geometry import close_pairs, links_within
from cooploc.motion import CVAccelerationInput, CVVelocityNoise, simulate
from cooploc.params import Params, param
from cooploc.registry import Preset, register_scenario
from cooploc.scenarios import limits
from cooploc.sensors import GnssPosition, RelativePosition
from cooploc.streams import Step, is_long, streamed
from cooploc.types import Frame, Recording, Setup, StateLayout, StateSet, Truth

__all__ = ["FEATURE_ID_OFFSET", "PRESETS", "BrambillaParams", "generate"]

FEATURE_ID_OFFSET = 1000
KMH = 1.0 / 3.6


@dataclass(frozen=True)
class BrambillaParams(Params):
    """Parameters of the Brambilla 2020 scenarios; defaults are the crossroad of §V-B.

    Attributes
    ----------
    geometry : "road" (§V-A) or "crossroad" (§V-B).
    n_vehicles : N_v (road: vehicles in one lane; crossroad: a multiple of 4 clusters).
    cluster_size : vehicles per cluster (crossroad).
    n_features : N_f.
    n_steps, dt : number of steps and T_s (s).
    speed : nominal vehicle speed (m/s).
    sigma_accel_along, sigma_accel_cross : σ_a,∥ and σ_a,⊥ of eq. (1) (m/s²).
    gnss_position_std, gnss_velocity_std : σ_p^(V) (m) and σ_v^(V) (m/s) of eq. (3).
    v2f_position_std, v2f_velocity_std : σ_p^(V2F) (m) and σ_v^(V2F) (m/s) of eq. (4).
    communication_range, sensing_range : R_c and R_s (m).
    feature_spacing : d_f (m), road only.
    feature_speed : v_f (m/s), crossroad only (0: static features).
    feature_radius : features lie within this distance of the junction centre (m).
    headway, cluster_headway : gap between consecutive vehicles on the road / in a cluster (m).
    road_start : distance of the road leader's start before the first feature (m).
    start_distance : distance of each crossroad cluster leader from the centre (m).
    lane_offset, sidewalk_offset : distance of lane centres / sidewalks from the road axis (m).
    start_position_std, start_speed_std : start spread along the lane (m, m/s).
    detection_probability, clutter_rate, clutter_extent : V2F misses and Poisson clutter
        (not in the paper: 1, 0), clutter uniform in a box of this half-width (m).
    """

    geometry: str = param("crossroad", choices=("road", "crossroad"))
    n_vehicles: int = param(12, ge=1)
    cluster_size: int = param(3, ge=1)
    n_features: int = param(20, ge=0)
    n_steps: int = param(32, ge=1)
    dt: float = param(1.0, gt=0, le=limits.STEP)
    speed: float = param(50.0 * KMH, gt=0, le=limits.SPEED)
    sigma_accel_along: float = param(0.35, ge=0, le=limits.ACCELERATION)
    sigma_accel_cross: float = param(0.001, ge=0, le=limits.ACCELERATION)
    gnss_position_std: float = param(9.0, ge=limits.STD_MIN, le=limits.LENGTH)
    gnss_velocity_std: float = param(0.25, ge=limits.STD_MIN, le=limits.SPEED)
    v2f_position_std: float = param(0.1, ge=limits.STD_MIN, le=limits.LENGTH)
    v2f_velocity_std: float = param(0.1, ge=limits.STD_MIN, le=limits.SPEED)
    communication_range: float = param(250.0, gt=0, le=limits.LENGTH)
    sensing_range: float = param(75.0, gt=0, le=limits.LENGTH)
    feature_spacing: float = param(3.0, ge=0, le=limits.LENGTH)
    feature_speed: float = param(0.0, ge=0, le=limits.SPEED)
    feature_radius: float = param(150.0, gt=0, le=limits.LENGTH)
    headway: float = param(5.0, gt=0, le=limits.LENGTH)
    cluster_headway: float = param(20.0, gt=0, le=limits.LENGTH)
    road_start: float = param(40.0, ge=0, le=limits.LENGTH)
    start_distance: float = param(210.0, ge=0, le=limits.LENGTH)
    lane_offset: float = param(1.75, ge=0, le=limits.LENGTH)
    sidewalk_offset: float = param(8.0, ge=0, le=limits.LENGTH)
    start_position_std: float = param(1.0, ge=limits.STD_MIN, le=limits.LENGTH)
    start_speed_std: float = param(0.5, ge=limits.STD_MIN, le=limits.SPEED)
    detection_probability: float = param(1.0, gt=0, le=1)
    clutter_rate: float = param(0.0, ge=0, le=limits.CLUTTER_RATE)
    clutter_extent: float = param(75.0, gt=0, le=limits.LENGTH)

    def validate(self) -> None:
        # crossroad features are drawn between the sidewalk and this radius
        self.require(self.feature_radius >= self.sidewalk_offset, "feature_radius",
                     f"be >= sidewalk_offset = {self.sidewalk_offset}")

    def sizes(self) -> Sizes:
        """Steps, vehicles and features of one run (for `cooploc.budget`)."""
        return Sizes(self.n_steps, self.n_vehicles, self.n_features, streamed=is_long(self.n_steps))


def _road_starts(p: BrambillaParams) -> tuple[np.ndarray, np.ndarray]:
    """Nominal start positions (n, 2) and driving directions (n,) on the single road."""
    x = -p.road_start - p.headway * np.arange(p.n_vehicles)
    return np.stack([x, np.zeros_like(x)], axis=1), np.zeros(p.n_vehicles)


def _crossroad_starts(p: BrambillaParams) -> tuple[np.ndarray, np.ndarray]:
    """Clusters on the 4 approaches, driving towards the centre in the right-hand lane."""
    v = np.arange(p.n_vehicles)
    approach = (v // p.cluster_size) % 4              # from the east, west, north, south
    heading = np.array([np.pi, 0.0, -np.pi / 2, np.pi / 2])[approach]
    # more than 4 clusters queue behind the first ones on the same approach
    rank = v % p.cluster_size + p.cluster_size * (v // (4 * p.cluster_size))
    behind = p.start_distance + p.cluster_headway * rank       # distance from the centre
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    right = np.stack([np.sin(heading), -np.cos(heading)], axis=1)  # right-hand lane
    return -behind[:, None] * direction + p.lane_offset * right, heading


def _features(p: BrambillaParams, rng: np.random.Generator) -> np.ndarray:
    """Feature start states (K, 4): on the sidewalks, walking along them at v_f."""
    K = p.n_features
    if p.geometry == "road":
        x = p.feature_spacing * np.arange(K)
        return np.stack([x, np.full(K, p.sidewalk_offset), np.zeros(K), np.zeros(K)], axis=1)
    side = rng.integers(0, 4, size=K)          # sidewalks y = ±s (along x) and x = ±s (along y)
    along = rng.uniform(p.sidewalk_offset, p.feature_radius, size=K) * rng.choice([-1.0, 1.0], size=K)
    offset = np.where(side % 2 == 0, 1.0, -1.0) * p.sidewalk_offset
    along_x = side < 2
    pos = np.where(along_x[:, None], np.stack([along, offset], 1), np.stack([offset, along], 1))
    direction = np.where(along_x, 0.0, np.pi / 2) + np.pi * (rng.random(K) < 0.5)
    vel = p.feature_speed * np.stack([np.cos(direction), np.sin(direction)], axis=1)
    return np.concatenate([pos, vel], axis=1)


def generate(params: BrambillaParams, rng: np.random.Generator) -> Recording:
    """Simulate one run of the road or crossroad scenario."""
    p = params
    N, K, T, dt = p.n_vehicles, p.n_features, p.n_steps, p.dt
    layout = StateLayout.position_velocity(2)
    vehicle_motion = CVAccelerationInput(p.sigma_accel_along, p.sigma_accel_cross)
    feature_motion = CVVelocityNoise(p.feature_speed / 100.0, p.feature_speed / 200.0)
    vehicle_ids = np.arange(N, dtype=np.int64)
    feature_ids = FEATURE_ID_OFFSET + np.arange(K, dtype=np.int64)
    rng_vehicles, rng_features, rng_gnss, rng_v2f = rng.spawn(4)

    start, heading = _road_starts(p) if p.geometry == "road" else _crossroad_starts(p)
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    nominal = np.concatenate([start, p.speed * direction], axis=1)
    # start spread along the lane only: position and speed (cross-track velocity stays 0)
    E = np.zeros((N, 4, 2))
    E[:, 0:2, 0] = direction
    E[:, 2:4, 1] = direction
    spread = rng_vehicles.normal(size=(N, 2)) * [p.start_position_std, p.start_speed_std]
    x0 = nominal + np.einsum("nij,nj->ni", E, spread)
    vehicles = simulate(vehicle_motion, x0, T, dt, rng_vehicles)                      # (T, N, 4)
    f0 = _features(p, rng_features)
    features = simulate(feature_motion, f0, T, dt, rng_features) if K else np.zeros((T, 0, 4))

    gnss_cov = np.diag([p.gnss_position_std**2] * 2 + [p.gnss_velocity_std**2] * 2)
    v2f_cov = np.diag([p.v2f_position_std**2] * 2 + [p.v2f_velocity_std**2] * 2)
    gnss = GnssPosition(default_cov=gnss_cov, state_indices=(0, 1, 2, 3))
    v2f = RelativePosition(default_cov=v2f_cov, state_indices=(0, 1, 2, 3), max_range=p.sensing_range)
    e = p.clutter_extent
    region = np.array([[-e, e], [-e, e], [-p.speed, p.speed], [-p.speed, p.speed]])

    def steps() -> Iterator[Step]:
        # from the generators' states now, so that every pass draws the same numbers
        rng_g, rng_f = copy.deepcopy(rng_gnss), copy.deepcopy(rng_v2f)
        for k in range(T):
            pos_v, pos_f = vehicles[k, :, :2], features[k, :, :2]
            visible = np.zeros((N, K), dtype=bool)
            visible[close_pairs(pos_v, pos_f, p.sensing_range)] = True
            gnss_batch = gnss.measure(vehicle_ids, vehicles[k], rng_g)
            v2f_batch, v2f_origin = v2f.measure(
                vehicle_ids, vehicles[k], feature_ids, features[k], rng_f, visible=visible,
                detection_probability=p.detection_probability, clutter_rate=p.clutter_rate,
                clutter_region=region,
            )
            links = links_within(vehicle_ids, pos_v, p.communication_range)
            yield (Frame(k, k * dt, vehicle_ids, {"gnss": gnss_batch, "v2f": v2f_batch}, links),
                   {"gnss": vehicle_ids, "v2f": v2f_origin})

    frames, origins = streamed(T, steps, lazy=is_long(T))

    setup = Setup(
        dt=dt,
        n_steps=T,
        vehicle_layout=layout,
        vehicle_motion=vehicle_motion,
        vehicle_prior=StateSet.empty(4),  # as the paper: each filter starts from its first fix
        sensors={"gnss": gnss, "v2f": v2f},
        feature_layout=layout,
        feature_motion=feature_motion,
        feature_prior=StateSet.empty(4),
        detection_probability=p.detection_probability,
        clutter_rate=p.clutter_rate,
        clutter_region=region if p.clutter_rate > 0 else None,
        description=(f"Brambilla 2020 §V {p.geometry}: {N} vehicles, {K} features, "
                     f"{T} steps of {dt} s"),
    )
    truth = Truth.always_present(vehicle_ids, vehicles, origins, feature_ids, features)
    return Recording(setup, frames, truth)


ROAD = BrambillaParams(
    geometry="road", n_vehicles=2, n_features=2, n_steps=12, speed=25.0 * KMH,
    sigma_accel_along=0.2, sigma_accel_cross=0.001, gnss_position_std=8.0, gnss_velocity_std=0.1,
    v2f_position_std=0.2, v2f_velocity_std=0.1, communication_range=1000.0, sensing_range=30.0,
    sidewalk_offset=5.0, clutter_extent=30.0,
)

PRESETS = register_scenario("brambilla2020", generate, [
    Preset(
        name="brambilla-road",
        params=ROAD,
        summary="Brambilla 2020 §V-A: 2 vehicles at 25 km/h, 2 static sidewalk features d_f apart",
        doc="Reproduces Fig. 7 of Brambilla et al. (T-ITS 2020) with feature_spacing 0.5, 3, 6 m.",
        bound="oracle-kf",
    ),
    Preset(
        name="brambilla-crossroad",
        params=BrambillaParams(),
        summary="Brambilla 2020 §V-B: 12 vehicles in 4 clusters at a junction, N_f sidewalk features",
        doc="Reproduces Figs. 8–11 of Brambilla et al. (T-ITS 2020): n_features, feature_speed.",
        bound="oracle-kf",
    ),
])
