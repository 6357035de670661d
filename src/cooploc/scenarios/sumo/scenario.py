"""The `sumo-*` recording: GNSS by zone, V2F and V2V on top of cached SUMO traffic, and the presets.

`generate` lays the sensors of Brambilla et al. 2020 §VI-A over one `Traffic` run
(`cooploc.scenarios.sumo.cache.traffic`):

- GNSS: position and velocity, z = x + w, W = diag(σ_p², σ_p², σ_v², σ_v²) of the zone
  (`roads.zone_of`) the vehicle is in at that step — zone A σ_p = 3 m, σ_v = 0.1 m/s;
  B 8 m, 0.17 m/s; C 15 m, 0.45 m/s. Each row of the GNSS batch carries its own
  covariance; `Setup.sensors["gnss"]` is the zone-B model, the nominal one.
- V2F: relative position and velocity z = f − x + w, W = diag(σ_p², σ_p², σ_v², σ_v²)
  with σ_p = σ_v = 0.1, of every feature (static ones from `roads.static_features`,
  and SUMO's pedestrians as mobile ones) within the sensing range R_s = 50 m
  (`sensors.RelativePosition` with a visibility mask; P_D and clutter optional; rows
  shuffled per vehicle). Features are not known in advance (no prior).
- V2V links: every pair of present vehicles within R_c = 250 m (§V).
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

Randomness: `rng` is split into four children (traffic seed, prior, GNSS, V2F), in
that order; `traffic_seed` reproduces the first.

Complexity: a frame costs O((n + K) log(n + K) + E + M) for n vehicles present, K
features, E links and M V2F rows (k-d trees, `geometry.links_within` and
`close_pairs`; an n × K boolean mask is the only dense array); the cost of a build is
measured by ``benchmarks/sumo_traffic.py``. A run longer than
`streams.STREAM_FROM_STEPS` steps makes its frames on demand (`cooploc.streams`), so
its memory does not grow with the horizon beyond the truth.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from typing import Any

import numpy as np

from cooploc.geometry import close_pairs, links_within
from cooploc.motion import ConstantVelocity
from cooploc.registry import Preset, register_scenario
from cooploc.scenarios.sumo.cache import traffic
from cooploc.scenarios.sumo.params import GRID, NETWORKS, STATIC_FEATURE_ID_OFFSET, SumoParams
from cooploc.scenarios.sumo.roads import zone_of
from cooploc.sensors import GnssPosition, RelativePosition
from cooploc.streams import Step, is_long, streamed
from cooploc.types import Batch, FloatArray, Frame, Recording, Setup, StateLayout, StateSet, Truth

__all__ = ["CITY", "PRESETS", "TINY_GRID", "generate", "traffic_seed"]


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
    return _draw_traffic_seed(params, rng.spawn(4)[0])


def generate(params: SumoParams, rng: np.random.Generator) -> Recording:
    """One run: SUMO traffic (cached per seed) plus GNSS, V2F and V2V drawn from `rng`."""
    rng_traffic, rng_prior, rng_gnss, rng_v2f = rng.spawn(4)
    run = traffic(params, _draw_traffic_seed(params, rng_traffic))
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

    # what the steps read, and nothing else of `run`: a streamed recording keeps these
    # (the states are swapped for the truth's copies below, so that one copy is kept)
    vehicle_ids, vehicle_present, centre = run.vehicle_ids, run.vehicle_present, run.centre
    states_of = {"vehicles": run.vehicle_states, "features": feature_states}

    def steps() -> Iterator[Step]:
        # from the generators' states now, so that every pass draws the same numbers
        rng_g, rng_f = copy.deepcopy(rng_gnss), copy.deepcopy(rng_v2f)
        vehicle_states, feature_states = states_of["vehicles"], states_of["features"]
        for k in range(T):
            present = vehicle_present[k]
            ids, states = vehicle_ids[present], vehicle_states[k, present]
            zone = zone_of(states, centre, params.zone_radii)
            parts = [zone_sensors[z].measure(ids[zone == z], states[zone == z], rng_g) for z in range(3)]
            gnss_z = np.concatenate([b.z for b in parts])
            gnss_cov = np.concatenate([b.cov for b in parts])
            gnss_ids = np.concatenate([b.subject for b in parts])
            order = np.argsort(gnss_ids, kind="stable")
            gnss = Batch(gnss_z[order].reshape(-1, 4), gnss_cov[order].reshape(-1, 4, 4), gnss_ids[order],
                         gnss_ids[order])
            f_on = feature_present[k]
            f_ids, f_states = feature_ids[f_on], feature_states[k, f_on]
            visible = np.zeros((ids.size, f_ids.size), dtype=bool)
            visible[close_pairs(states[:, :2], f_states[:, :2], r)] = True
            v2f_batch, v2f_origin = v2f.measure(
                ids, states, f_ids, f_states, rng_f, visible=visible,
                detection_probability=params.detection_probability, clutter_rate=params.clutter_rate,
                clutter_region=clutter_region)
            links = links_within(ids, states[:, :2], params.communication_range)
            yield (Frame(k, k * dt, ids, {"gnss": gnss, "v2f": v2f_batch}, links),
                   {"gnss": gnss_ids[order], "v2f": v2f_origin})

    frames, origins = streamed(T, steps, lazy=is_long(T))

    at_start = run.vehicle_ids[run.vehicle_present[0]]
    prior_cov = np.diag([params.prior_position_std**2] * 2 + [params.prior_velocity_std**2] * 2)
    start_states = run.vehicle_states[0, run.vehicle_present[0]]
    prior_mean = start_states + rng_prior.multivariate_normal(np.zeros(4), prior_cov,
                                                              size=at_start.size)
    birth_cov = np.diag([params.birth_position_std**2] * 2 + [params.birth_velocity_std**2] * 2)
    net = params.network if params.network == GRID else params.network_label
    setup = Setup(
        dt=dt,
        n_steps=T,
        vehicle_layout=layout,
        vehicle_motion=ConstantVelocity(params.vehicle_noise_density),
        vehicle_prior=StateSet(at_start, prior_mean.reshape(-1, 4),
                               np.repeat(prior_cov[None], at_start.size, 0)),
        # the zone-B model is the nominal one; every row carries its zone's covariance
        sensors={"gnss": zone_sensors[1], "v2f": v2f},
        feature_layout=layout,
        feature_motion=ConstantVelocity(params.feature_noise_density),
        feature_prior=StateSet.empty(4),
        birth_cov=birth_cov,
        detection_probability=params.detection_probability,
        clutter_rate=params.clutter_rate,
        clutter_region=clutter_region if params.clutter_rate > 0 else None,
        description=(f"SUMO {params.regulation.upper()} traffic on {net}: "
                     f"{run.vehicle_ids.size} vehicles, {K} static features, "
                     f"{run.pedestrian_ids.size} pedestrians, {T} steps of {dt} s"),
    )
    truth = Truth(
        vehicle_ids=run.vehicle_ids,
        vehicle_states=run.vehicle_states,
        vehicle_present=run.vehicle_present,
        feature_ids=feature_ids,
        feature_states=feature_states,
        feature_present=feature_present,
        origin=origins,
    )
    states_of.update(vehicles=truth.vehicle_states, features=truth.feature_states)  # equal values
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
                 "GNSS zones A/B/C, V2F R_s = 50 m"),
        doc=("Analogue of Brambilla et al. 2020 §VI (Figs. 16–17) on a SUMO network; see "
             "cooploc.scenarios.sumo for what differs from the paper's Turin arterial."),
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
