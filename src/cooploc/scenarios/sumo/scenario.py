"""The `sumo-*` recording: every paper's sensors on top of cached SUMO traffic, and the presets.

`generate` lays the sensors over one `Traffic` run (`cooploc.scenarios.sumo.cache.traffic`);
`lay_sensors` does the same over any `Traffic` (one made by hand, in tests). Brambilla
et al. 2020 §VI-A give the first three:

- GNSS (kind ``gnss``): position and velocity, z = x + w, W = diag(σ_p², σ_p², σ_v², σ_v²)
  of the zone (`roads.zone_of`) the vehicle is in at that step — zone A σ_p = 3 m,
  σ_v = 0.1 m/s; B 8 m, 0.17 m/s; C 15 m, 0.45 m/s. Each row of the GNSS batch carries
  its own covariance; `Setup.sensors["gnss"]` is the zone-B model, the nominal one.
  With `anonymous_gnss` the same rows reach the fusion centre without their vehicle's
  id and in random order (`sensor` = `subject` = −1; `AnonymousPosition`, the internal
  sensor of Zhang et al. 2016 §3.2, kind ``gnss`` as in `zhang2016`); off by default,
  since Brambilla's GNSS, and the estimators built on it, name the vehicle.
- V2F (kind ``v2f``): relative position and velocity z = f − x + w,
  W = diag(σ_p², σ_p², σ_v², σ_v²) with σ_p = σ_v = 0.1, of every feature (static ones
  from `roads.static_features`, and SUMO's pedestrians as mobile ones) within the
  sensing range R_s = 50 m (`sensors.RelativePosition` with a visibility mask; P_D and
  clutter optional; rows shuffled per vehicle). Features are not known in advance (no
  prior).
- V2V links: every pair of present vehicles within R_c = 250 m (§V).

The sensors of the other papers (issue 19), each switched off by its key:

- Road-side radars (``radar``, kind ``radar``), Zhang et al. 2016 §3.2 and Gulati et al.
  2017 §II: a radar at pose [t_x, t_y, θ] reports every vehicle within `radar_range` of
  t and `radar_field_of_view` of its boresight in its own frame,
  z = R(θ)ᵀ(p − t) + w, w ~ N(0, `radar_variance` I₂) (papers: 0.1 m²), as anonymous
  rows (`subject` = −1, `sensor` = the radar's id) in random order
  (`sensors.InfrastructureRadar`). As in `zhang2016` and `gulati`, the pose is unknown
  to the estimators: `Setup.infrastructure_ids` lists the radars (ids from
  `RADAR_ID_OFFSET`), `Setup` holds no pose prior, and the poses are kept only in
  `Truth.sensor_poses`. Radars stand at the `n_radars` busiest junctions
  (`roads.radar_sites`) or where `radar_junctions` / `radar_positions` say; the yaw θ is
  uniform in [−π, π) per run (the papers draw the whole pose at random; here the site
  is the junction). No missed detections or clutter (the papers have none).
- Wheel odometry (``odometry``, kind ``odometry``), Gulati eq. (4): each vehicle's
  displacement since the previous step in the global frame,
  z_k = p_k − p_{k−1} + w, w ~ N(0, `odometry_variance` I₂) (paper: 1 m²), for every
  vehicle present at k and k − 1 (`sensors.Odometry`); a vehicle's first step has none,
  and step 0 an empty batch.
- V2V angle of arrival (``aoa``, kind ``aoa``), ``papers/plbp_model_notes.md``: at
  receiver i of transmitter j, θ_{i←j} = wrap(atan2(p_j − p_i) − α_i) + w,
  w ~ N(0, σ²_θ), σ²_θ = `aoa_variance` = 0.10 rad² (Table I), measured by two side
  arrays each seeing ±Δ about its normal (Δ = `aoa_field_of_view` = π/2: together all
  around), on both ends of every V2V link no longer than `aoa_range` (30 m, the paper's
  R_c; links longer than R_c do not exist) — `sensors.AngleOfArrival`,
  `sensor` = receiver, `subject` = transmitter. α_i is SUMO's own vehicle angle
  (`Traffic.vehicle_heading`).

- AoA anchors (kind ``anchor``, with ``aoa``): a share `aoa_anchor_share` of the run's
  vehicles (the AoA paper's 6 of 51 by default), drawn once per run, know their position
  and heading: every step a fix z = [p_x, p_y, α] + w, w ~ N(0, diag(σ_p², σ_p², σ_α²)),
  σ_p = `anchor_position_std` = 0.1 m, σ_α = `anchor_heading_std` = 0.01 rad (the notes'
  anchor prior), `sensors.GnssPosition` over (0, 1, 4). Only the AoA estimators read it.

Heading. The vehicle state stays [p_x, p_y, v_x, v_y] (`StateLayout.position_velocity`),
so that the estimators that do not use a heading see exactly what they saw before the
AoA rows existed. The true heading is kept in `Truth.vehicle_heading` (T, N) for
scoring, and the AoA and anchor models in `Setup.sensors` have `state_indices`
(0, 1, 4): positions from the layout, the heading as a fifth component
[p_x, p_y, v_x, v_y, α] that an AoA estimator adds beside the layout (`plbp` takes it
from the direction of the velocity, `cooploc.estimators.plbp.heading`).

- Motion models given to the estimators: CV (Fröhle eqs. 28–29) with
  `vehicle_noise_density`; one CV with `feature_noise_density` (pedestrian-like) for
  all features, static and walking.

Choices the paper leaves open: vehicles present at step 0 start from the paper's
"fast start" prior N(x, diag(2², 2², 0.1², 0.1²)) centred on a draw around their true
state; vehicles that enter later have none (`Setup.vehicle_prior` lists only step-0
vehicles) and are born from their first GNSS fix with `Setup.birth_cov`
(`birth_position_std` = 100 m, `birth_velocity_std` = 10 m/s: broad, so that the
first fix dominates). The traffic seed is drawn from the run's generator unless
`traffic_seed` >= 0 fixes it, so that Monte Carlo runs share one traffic realisation
and differ only in sensor noise.

Which families are on by default: the radars and the AoA, so that the radar and AoA
methods find their sensors on a city (`cooploc compare`); no estimator that ran on the
`sumo-*` presets before reads either, so every one of them gives the same numbers, bit
for bit. Odometry is off by default: `gnss-kf`, `icp`, `icp-da-lc`, `icp-da-pf`,
`kf-known-da`, `rsu-bp` (through its own-vehicle `gnss-kf`) and `oracle-kf`, the
presets' bound, fuse odometry wherever a scenario has it, so with it on they would
change. The factor graphs need it: ``--set odometry=true``. Anonymous GNSS replaces
the identified rows that the GNSS baseline and the V2F methods need, so it is opt-in
too.

Randomness: `rng` is split into ten children, in this order: traffic seed, prior,
GNSS, V2F (the four of the Brambilla recording, unchanged), radar poses, radar noise,
odometry, AoA, anonymous-GNSS order, AoA anchors (which vehicles, then their fixes).
Every family draws from its own child, so switching one on or off leaves every other
row bit for bit as it was; `traffic_seed` reproduces the first child.

Complexity: a frame costs O((n + K) log(n + K) + E + M) for n vehicles present, K
features, E links and M V2F rows (k-d trees, `geometry.links_within` and
`close_pairs`; an n × K boolean mask is the only dense array), plus O(R n) for R radars
and O(n + E) for odometry and AoA; choosing the busiest junctions costs one k-d tree
over the run's vehicle-steps. The cost of a build is measured by
``benchmarks/sumo_traffic.py``. A run longer than `streams.STREAM_FROM_STEPS` steps
makes its frames on demand (`cooploc.streams`), so its memory does not grow with the
horizon beyond the truth.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from cooploc.geometry import close_pairs, links_within
from cooploc.motion import ConstantVelocity
from cooploc.registry import Preset, register_scenario
from cooploc.scenarios.sumo.cache import traffic
from cooploc.scenarios.sumo.params import (
    GRID,
    NETWORKS,
    RADAR_ID_OFFSET,
    STATIC_FEATURE_ID_OFFSET,
    SumoParams,
)
from cooploc.scenarios.sumo.roads import radar_sites, zone_of
from cooploc.scenarios.sumo.simulation import Traffic
from cooploc.sensors import (
    AngleOfArrival,
    AnonymousPosition,
    GnssPosition,
    InfrastructureRadar,
    Odometry,
    RelativePosition,
)
from cooploc.streams import Step, is_long, streamed
from cooploc.types import Batch, FloatArray, Frame, IntArray, Recording, Setup, StateLayout, StateSet, Truth

__all__ = ["CITY", "PRESETS", "STREAMS", "TINY_GRID", "generate", "lay_sensors", "traffic_seed"]

#: the random streams `generate` splits its generator into, in order (module docstring)
STREAMS = ("traffic", "prior", "gnss", "v2f", "radar_pose", "radar", "odometry", "aoa", "gnss_order",
           "anchor")
#: the vehicle state an AoA row is a function of: the layout's four components and the heading
_AOA_STATE = (0, 1, 4)


def _zone_covariances(params: SumoParams) -> FloatArray:
    """(3, 4, 4) GNSS covariance of zones A, B, C: diag(σ_p², σ_p², σ_v², σ_v²)."""
    p, v = np.asarray(params.gnss_position_std), np.asarray(params.gnss_velocity_std)
    return np.stack([np.diag([pi**2, pi**2, vi**2, vi**2]) for pi, vi in zip(p, v, strict=True)])


def _draw_traffic_seed(params: SumoParams, rng_traffic: np.random.Generator) -> int:
    if params.traffic_seed >= 0:
        return params.traffic_seed
    return int(rng_traffic.integers(2**31 - 1))


def traffic_seed(params: SumoParams, rng: np.random.Generator) -> int:
    """The traffic seed that `generate(params, rng)` uses, for a generator in the same state."""
    return _draw_traffic_seed(params, rng.spawn(len(STREAMS))[0])


def generate(params: SumoParams, rng: np.random.Generator) -> Recording:
    """One run: SUMO traffic (cached per seed) plus every family's measurements drawn from `rng`."""
    streams = rng.spawn(len(STREAMS))
    run = traffic(params, _draw_traffic_seed(params, streams[0]))
    return _lay(params, run, streams)


def lay_sensors(params: SumoParams, run: Traffic, rng: np.random.Generator) -> Recording:
    """The recording of `generate(params, rng)` with `run` as its traffic (no SUMO needed).

    With a generator in the state `generate` was given and the traffic of its seed,
    the two recordings are the same, bit for bit.
    """
    return _lay(params, run, rng.spawn(len(STREAMS)))


class _Radars:
    """The road-side radars of one run: ids (R,), poses (R, 3) and their sensor model."""

    def __init__(self, params: SumoParams, run: Traffic, rng_pose: np.random.Generator) -> None:
        sites = radar_sites(params, run.junction_ids, run.junctions, run.junction_roads,
                            run.vehicle_states[run.vehicle_present][:, :2])
        self.ids = RADAR_ID_OFFSET + np.arange(sites.shape[0], dtype=np.int64)
        yaw = rng_pose.uniform(-np.pi, np.pi, sites.shape[0])       # unknown to the estimators
        self.poses = np.column_stack([sites, yaw]).reshape(-1, 3)
        self.model = InfrastructureRadar(default_cov=params.radar_variance * np.eye(2),
                                         max_range=params.radar_range,
                                         field_of_view=params.radar_field_of_view)

    def measure(self, ids: IntArray, states: FloatArray, rng: np.random.Generator) -> tuple[Batch, IntArray]:
        """Every radar's rows of the vehicles `ids` (n,) at `states` (n, 4), grouped by radar."""
        return self.model.measure_many(self.ids, self.poses, ids, states, rng)


def _lay(params: SumoParams, run: Traffic, streams: Sequence[np.random.Generator]) -> Recording:
    """The recording of `run` with the generators of `STREAMS` (the traffic one unused here)."""
    (_, rng_prior, rng_gnss, rng_v2f, rng_pose, rng_radar, rng_odometry, rng_aoa, rng_order,
     rng_anchor) = streams
    T, dt = params.n_steps, params.dt
    layout = StateLayout.position_velocity(2)
    state = (0, 1, 2, 3)

    K = run.static_features.shape[0]
    static_ids = STATIC_FEATURE_ID_OFFSET + np.arange(K, dtype=np.int64)
    feature_ids = np.concatenate([static_ids, run.pedestrian_ids])
    static_states = np.concatenate([run.static_features, np.zeros((K, 2))], axis=1)
    feature_states = np.concatenate(
        [np.broadcast_to(static_states, (T, K, 4)), run.pedestrian_states], axis=1)
    feature_present = np.concatenate([np.ones((T, K), dtype=bool), run.pedestrian_present], axis=1)

    zone_cov = _zone_covariances(params)
    zone_sensors = [GnssPosition(default_cov=c, state_indices=state) for c in zone_cov]
    v2f_cov = np.diag([params.v2f_position_std**2] * 2 + [params.v2f_velocity_std**2] * 2)
    r = params.sensing_range
    v2f = RelativePosition(default_cov=v2f_cov, state_indices=state, max_range=r)
    clutter_region = np.array([[-r, r], [-r, r], [-20.0, 20.0], [-20.0, 20.0]])
    # the zone-B model is the nominal one; every row carries its zone's covariance
    sensors: dict[str, Any] = {
        "gnss": (AnonymousPosition(default_cov=zone_cov[1], state_indices=state) if params.anonymous_gnss
                 else zone_sensors[1]),
        "v2f": v2f}
    radars = _Radars(params, run, rng_pose) if params.radar else None
    if radars is not None:
        sensors["radar"] = radars.model
    odometry = Odometry(default_cov=params.odometry_variance * np.eye(2)) if params.odometry else None
    if odometry is not None:
        sensors["odometry"] = odometry
    aoa = (AngleOfArrival(default_cov=np.array([[params.aoa_variance]]), state_indices=_AOA_STATE,
                          field_of_view=params.aoa_field_of_view) if params.aoa else None)
    if aoa is not None:
        sensors["aoa"] = aoa
    aoa_range = min(params.aoa_range, params.communication_range)
    # AoA anchors: a share of the run's vehicles, drawn once per run; each present anchor
    # gets a fix of [p_x, p_y, α] at every step (the PLBP paper's anchor prior, kept)
    rng_pick, rng_anchor_fix = rng_anchor.spawn(2)
    is_anchor = rng_pick.random(run.vehicle_ids.size) < params.aoa_anchor_share
    anchor = None
    if aoa is not None and params.aoa_anchor_share > 0:
        anchor = GnssPosition(default_cov=np.diag([params.anchor_position_std**2] * 2
                                                  + [params.anchor_heading_std**2]), state_indices=_AOA_STATE)
        sensors["anchor"] = anchor

    # what the steps read, and nothing else of `run`: a streamed recording keeps these
    # (the states are swapped for the truth's copies below, so that one copy is kept)
    vehicle_ids, vehicle_present, centre = run.vehicle_ids, run.vehicle_present, run.centre
    states_of = {"vehicles": run.vehicle_states, "features": feature_states, "heading": run.vehicle_heading}

    def steps() -> Iterator[Step]:
        # from the generators' states now, so that every pass draws the same numbers
        rng_g, rng_f = copy.deepcopy(rng_gnss), copy.deepcopy(rng_v2f)
        rng_r, rng_o, rng_a, rng_s, rng_n = (copy.deepcopy(g) for g in (rng_radar, rng_odometry, rng_aoa,
                                                                         rng_order, rng_anchor_fix))
        vehicle_states, feature_states = states_of["vehicles"], states_of["features"]
        heading = states_of["heading"]
        for k in range(T):
            present = vehicle_present[k]
            ids, states = vehicle_ids[present], vehicle_states[k, present]
            zone = zone_of(states, centre, params.zone_radii)
            parts = [zone_sensors[z].measure(ids[zone == z], states[zone == z], rng_g) for z in range(3)]
            gnss_z = np.concatenate([b.z for b in parts])
            gnss_cov = np.concatenate([b.cov for b in parts])
            gnss_ids = np.concatenate([b.subject for b in parts])
            order = np.argsort(gnss_ids, kind="stable")
            gnss_origin, gnss_sensor = gnss_ids[order], gnss_ids[order]
            if params.anonymous_gnss:  # the same rows, without their vehicle and in random order
                order = order[rng_s.permutation(order.size)]
                gnss_origin, gnss_sensor = gnss_ids[order], np.full(order.size, -1, dtype=np.int64)
            gnss = Batch(gnss_z[order].reshape(-1, 4), gnss_cov[order].reshape(-1, 4, 4), gnss_sensor,
                         gnss_sensor)
            f_on = feature_present[k]
            f_ids, f_states = feature_ids[f_on], feature_states[k, f_on]
            visible = np.zeros((ids.size, f_ids.size), dtype=bool)
            visible[close_pairs(states[:, :2], f_states[:, :2], r)] = True
            v2f_batch, v2f_origin = v2f.measure(
                ids, states, f_ids, f_states, rng_f, visible=visible,
                detection_probability=params.detection_probability, clutter_rate=params.clutter_rate,
                clutter_region=clutter_region)
            links = links_within(ids, states[:, :2], params.communication_range)
            batches = {"gnss": gnss, "v2f": v2f_batch}
            origin = {"gnss": gnss_origin, "v2f": v2f_origin}
            if radars is not None:
                batches["radar"], origin["radar"] = radars.measure(ids, states, rng_r)
            if odometry is not None:  # Gulati eq. (4), for the vehicles also present at k − 1
                both = present & vehicle_present[k - 1] if k else np.zeros_like(present)
                batches["odometry"] = odometry.measure(vehicle_ids[both], vehicle_states[k, both],
                                                       vehicle_states[k - 1, both], rng_o)
                origin["odometry"] = vehicle_ids[both]
            if aoa is not None:
                with_heading = np.concatenate([states, heading[k, present][:, None]], axis=1)
                # the links no longer than the AoA range (a k-d tree of its own is faster than
                # testing every link of R_c): the same pairs, in the same order
                near = links_within(ids, states[:, :2], aoa_range)
                aoa_batch = aoa.measure(ids, with_heading, near, rng_a)
                batches["aoa"], origin["aoa"] = aoa_batch, aoa_batch.subject.copy()
                if anchor is not None:
                    on = is_anchor[present]
                    batches["anchor"] = anchor.measure(ids[on], with_heading[on], rng_n)
                    origin["anchor"] = ids[on]
            yield Frame(k, k * dt, ids, batches, links), origin

    frames, origins = streamed(T, steps, lazy=is_long(T))

    at_start = run.vehicle_ids[run.vehicle_present[0]]
    prior_cov = np.diag([params.prior_position_std**2] * 2 + [params.prior_velocity_std**2] * 2)
    start_states = run.vehicle_states[0, run.vehicle_present[0]]
    prior_mean = start_states + rng_prior.multivariate_normal(np.zeros(4), prior_cov,
                                                              size=at_start.size)
    birth_cov = np.diag([params.birth_position_std**2] * 2 + [params.birth_velocity_std**2] * 2)
    net = params.network if params.network == GRID else params.network_label
    n_radars = 0 if radars is None else radars.ids.size
    setup = Setup(
        dt=dt,
        n_steps=T,
        vehicle_layout=layout,
        vehicle_motion=ConstantVelocity(params.vehicle_noise_density),
        vehicle_prior=StateSet(at_start, prior_mean.reshape(-1, 4),
                               np.repeat(prior_cov[None], at_start.size, 0)),
        sensors=sensors,
        feature_layout=layout,
        feature_motion=ConstantVelocity(params.feature_noise_density),
        feature_prior=StateSet.empty(4),
        birth_cov=birth_cov,
        detection_probability=params.detection_probability,
        clutter_rate=params.clutter_rate,
        clutter_region=clutter_region if params.clutter_rate > 0 else None,
        infrastructure_ids=() if radars is None else tuple(radars.ids.tolist()),
        description=(f"SUMO {params.regulation.upper()} traffic on {net}: "
                     f"{run.vehicle_ids.size} vehicles, {K} static features, "
                     f"{run.pedestrian_ids.size} pedestrians, {n_radars} radars, "
                     f"{int(is_anchor.sum()) if anchor is not None else 0} AoA anchors, {T} steps of {dt} s"),
    )
    truth = Truth(
        vehicle_ids=run.vehicle_ids,
        vehicle_states=run.vehicle_states,
        vehicle_present=run.vehicle_present,
        feature_ids=feature_ids,
        feature_states=feature_states,
        feature_present=feature_present,
        origin=origins,
        sensor_poses=np.zeros((0, 3)) if radars is None else radars.poses,
        vehicle_heading=run.vehicle_heading,
    )
    states_of.update(vehicles=truth.vehicle_states, features=truth.feature_states,  # equal values
                     heading=truth.vehicle_heading)
    return Recording(setup, frames, truth)


# ----------------------------------------------------------------------------
# presets
# ----------------------------------------------------------------------------


def _preset(network: str, regulation: str, *, size: str = "", **overrides: Any) -> Preset:
    label = "generated grid" if network == GRID else NETWORKS[network][2]
    lights = ("traffic-light regulated (TLR)" if regulation == "tlr"
              else "vehicle self-regulated (VSR, unsignalised priority junctions)")
    return Preset(
        name=f"sumo-{network}{size and '-' + size}-{regulation}",
        params=SumoParams(network=network, regulation=regulation, **overrides),
        summary=(f"SUMO urban traffic, {label}{size and ' (' + size + '-size cut)'}, {lights}; "
                 "GNSS zones A/B/C, V2F R_s = 50 m, radars at 4 junctions, V2V AoA"),
        doc=("Analogue of Brambilla et al. 2020 §VI (Figs. 16–17) on a SUMO network; see "
             "cooploc.scenarios.sumo for what differs from the paper's Turin arterial. The "
             "radars of Zhang 2016 / Gulati 2017 and the AoA of the PLBP paper are laid on the "
             "same traffic (odometry and anonymous GNSS: --set odometry=true, anonymous_gnss=true)."),
        bound="oracle-kf",
    )


#: the city-size cut: Berlin-Adlershof in a 4 km square, a vehicle trip every 0.2 s and a
#: pedestrian every 2 s — over a thousand vehicles in the network at once
CITY: dict[str, Any] = {"area_half_width": 2000.0, "vehicle_period": 0.2, "pedestrian_period": 2.0}


#: a network and run small enough for the test suite: 2 × 2 grid of 80 m blocks, 20 s
#: recorded after 30 s of warm-up; vehicles and pedestrians enter and leave within it
TINY_GRID: dict[str, Any] = {"network": GRID, "grid_size": 2, "grid_length": 80.0, "duration": 20.0,
                             "warmup": 30.0, "vehicle_period": 3.0, "pedestrian_period": 5.0,
                             "max_static_features": 6, "zone_radii": (45.0, 52.0)}

PRESETS = register_scenario("sumo", generate, [
    _preset("braunschweig", "tlr"),
    _preset("braunschweig", "vsr"),
    _preset("berlin", "tlr"),
    _preset("berlin", "vsr"),
    _preset("berlin", "tlr", size="city", **CITY),
    # tests and quick checks: a 3 × 3 grid of 100 m blocks, 60 s
    _preset(GRID, "tlr", duration=60.0, warmup=60.0, zone_radii=(40.0, 90.0)),
    _preset(GRID, "vsr", duration=60.0, warmup=60.0, zone_radii=(40.0, 90.0)),
])
