"""Parameters of the `sumo-*` family and its fixed conventions (networks, id ranges).

`SumoParams` holds every setting of a run: what SUMO simulates (network, regulation,
demand, timing — the `TRAFFIC_KEYS`, which also key the traffic cache), where the
static features go, and the sensors laid on top. Defaults are Brambilla et al. 2020
§VI-A where the paper states them (T_s = 0.75 s, GNSS zones A/B/C with σ_p = 3, 8,
15 m and σ_v = 0.1, 0.17, 0.45 m/s, fast-start prior 2 m / 0.1 m/s, 64 static
features, σ^(V2F) = 0.1 m and 0.1 m/s, R_s = 50 m) and §V (R_c = 250 m); the rest
are our choices, listed in `cooploc.scenarios.sumo`.

The sensors of the other papers (issue 19), each family switched by one key:

- ``radar``: road-side radars of unknown pose at junctions, Zhang et al. 2016 §3.2 and
  Gulati et al. 2017 §II — W = `radar_variance` I₂ with the papers' 0.1 m²; `n_radars`
  at the busiest junctions unless `radar_junctions` (SUMO junction ids) or
  `radar_positions` (x, y pairs) name them; `radar_range` and `radar_field_of_view`
  (a half-angle; π: all around, the papers' radar, which sees every vehicle) are our
  choices;
- ``odometry``: each vehicle's displacement since the previous step, global frame,
  Gulati eq. (4), W = `odometry_variance` I₂ with the paper's 1 m² (off by default:
  the estimators of the Brambilla recording fuse it where they find it, see
  `cooploc.scenarios.sumo.scenario`);
- ``aoa``: V2V angle of arrival with two side arrays (``papers/plbp_model_notes.md``):
  σ²_θ = `aoa_variance` = 0.10 rad², Δ = `aoa_field_of_view` = π/2, measured on the
  V2V links no longer than `aoa_range` = R_c of the AoA paper's Table I, 30 m;
- ``anonymous_gnss``: the GNSS rows without the identity of their vehicle, as
  Zhang 2016 §3.2 has them (off by default: Brambilla's GNSS names its vehicle).

Ids of one recording never collide: vehicles keep their randomTrips trip number
(below `STATIC_FEATURE_ID_OFFSET`), static features count up from
`STATIC_FEATURE_ID_OFFSET`, pedestrians are their trip number plus
`PEDESTRIAN_ID_OFFSET`, radars count up from `RADAR_ID_OFFSET`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.budget import Sizes
from cooploc.params import Params, param
from cooploc.scenarios import limits
from cooploc.streams import is_long

__all__ = [
    "GRID",
    "NETWORKS",
    "NETWORK_SUFFIXES",
    "OSM_SUFFIXES",
    "PEDESTRIAN_ID_OFFSET",
    "RADAR_ID_OFFSET",
    "REGULATIONS",
    "STATIC_FEATURE_ID_OFFSET",
    "TRAFFIC_KEYS",
    "SumoParams",
]

#: real-city networks shipped by eclipse-sumo under sumo/tools/game/: name → (folder, file, city)
NETWORKS: dict[str, tuple[str, str, str]] = {
    "braunschweig": ("bs3d", "bs.net.xml", "Braunschweig (Germany), city centre"),
    "berlin": ("DRT", "osm.net.xml", "Berlin-Adlershof (Germany)"),
}
GRID = "grid"
#: a `network` that is none of the names above is the path of the user's own network:
#: a SUMO network, or an OpenStreetMap extract that netconvert converts
OSM_SUFFIXES = (".osm", ".osm.xml", ".osm.gz", ".osm.xml.gz")
NETWORK_SUFFIXES = (".net.xml", ".net.xml.gz", *OSM_SUFFIXES)
REGULATIONS = ("tlr", "vsr")
STATIC_FEATURE_ID_OFFSET = 1_000_000
PEDESTRIAN_ID_OFFSET = 2_000_000
RADAR_ID_OFFSET = 3_000_000
@dataclass(frozen=True)
class SumoParams(Params):
    """Parameters of a SUMO traffic run; defaults follow Brambilla 2020 §VI where it says.

    Attributes
    ----------
    network : ``"grid"`` (netgenerate, for tests), a name of `NETWORKS`, or the path of
        the user's own network: a SUMO ``.net.xml`` or an OpenStreetMap ``.osm`` extract
        (`NETWORK_SUFFIXES`), cut to the study area like the shipped ones.
    regulation : ``"tlr"`` (traffic lights) or ``"vsr"`` (unregulated priority junctions).
    grid_size, grid_length : junctions per side and block length (m) of the grid network.
    area_half_width : half-width (m) of the square study area a real network is cut to.
    duration : recorded time (s); n_steps = round(duration / dt).
    warmup : simulated time (s) before recording starts.
    dt : SUMO step = scenario step (s) (paper: T_s = 0.75 s).
    vehicle_period, pedestrian_period : mean time (s) between two trips (0: no pedestrians).
    fringe_factor : how much trips favour the network fringe (randomTrips).
    traffic_seed : -1 draws the traffic seed from the run's generator; >= 0 fixes it.
    pole_spacing : distance (m) between poles along a road.
    min_feature_spacing : smallest distance (m) between two static features.
    max_static_features : at most this many static features (paper: 64).
    zone_radii : (C, B) radii (m) of the GNSS zones around the centre; A beyond.
    gnss_position_std, gnss_velocity_std : σ_p (m), σ_v (m/s) in zones (A, B, C).
    v2f_position_std, v2f_velocity_std : σ_p, σ_v of V2F relative measurements.
    sensing_range : R_s (m). communication_range : R_c (m).
    detection_probability, clutter_rate : P_D and Poisson clutter per vehicle and step.
    vehicle_noise_density, feature_noise_density : r (m²/s³) of the CV models given
        to the estimators.
    prior_position_std, prior_velocity_std : fast-start prior of step-0 vehicles.
    birth_position_std, birth_velocity_std : `Setup.birth_cov` of entering vehicles.
    radar : lay road-side radars of unknown pose (kind ``radar``).
    n_radars : how many, at the busiest junctions (most vehicle-steps within
        `radar_range`, at least `radar_range` apart), unless named below.
    radar_junctions : SUMO ids of the junctions to put the radars at instead.
    radar_positions : (x0, y0, x1, y1, …) network coordinates (m) of the radars instead.
    radar_range : R (m) within which a radar reports vehicles.
    radar_field_of_view : half-angle (rad) about the radar's boresight it sees (π: all around).
    radar_variance : per-axis noise variance (m²) of a radar row (papers: 0.1).
    odometry : give each vehicle its displacement since the previous step (kind ``odometry``).
    odometry_variance : per-axis noise variance (m²) of an odometry row (Gulati: 1).
    aoa : measure V2V angles of arrival with two side arrays (kind ``aoa``).
    aoa_variance : σ²_θ (rad²). aoa_field_of_view : Δ (rad), half-width of each array's view.
    aoa_range : longest V2V link (m) with AoA rows (no longer than `communication_range`
        is used: the angle rides on the link's message).
    aoa_anchor_share : share of the vehicles that are AoA anchors (kind ``anchor``; 0: none).
    anchor_position_std, anchor_heading_std : σ_p (m), σ_α (rad) of an anchor's fix.
    anonymous_gnss : the GNSS rows reach the fusion centre without their vehicle's id.
    """

    network: str = param(GRID)
    regulation: str = param("tlr", choices=REGULATIONS)
    grid_size: int = param(3, ge=2)
    grid_length: float = param(100.0, gt=0, le=limits.LENGTH)
    area_half_width: float = param(500.0, gt=0, le=limits.LENGTH)
    duration: float = param(300.0, gt=0, le=limits.DAY)
    warmup: float = param(120.0, ge=0, le=limits.DAY)
    dt: float = param(0.75, gt=0, le=limits.STEP)
    vehicle_period: float = param(2.0, gt=0, le=limits.DAY)
    pedestrian_period: float = param(10.0, ge=0, le=limits.DAY)
    fringe_factor: float = param(10.0, gt=0, le=1e6)  # randomTrips weight: 10⁶ is all fringe already
    traffic_seed: int = param(-1, ge=-1, le=2**31 - 1)  # SUMO's --seed is a C int
    pole_spacing: float = param(60.0, gt=0, le=limits.LENGTH)
    min_feature_spacing: float = param(20.0, gt=0, le=limits.LENGTH)
    max_static_features: int = param(64, ge=0)
    zone_radii: tuple[float, float] = param((150.0, 300.0), length=2, gt=0,
                                            must="be (r_C, r_B) with 0 < r_C <= r_B")
    gnss_position_std: tuple[float, float, float] = param(
        (3.0, 8.0, 15.0), length=3, ge=limits.STD_MIN, le=limits.LENGTH,
        must=f"be three numbers in [{limits.STD_MIN:g}, {limits.LENGTH:g}] m (zones A, B, C)")
    gnss_velocity_std: tuple[float, float, float] = param(
        (0.1, 0.17, 0.45), length=3, ge=limits.STD_MIN, le=limits.SPEED,
        must=f"be three numbers in [{limits.STD_MIN:g}, {limits.SPEED:g}] m/s (zones A, B, C)")
    v2f_position_std: float = param(0.1, ge=limits.STD_MIN, le=limits.LENGTH)
    v2f_velocity_std: float = param(0.1, ge=limits.STD_MIN, le=limits.SPEED)
    sensing_range: float = param(50.0, gt=0, le=limits.LENGTH)
    communication_range: float = param(250.0, gt=0, le=limits.LENGTH)
    detection_probability: float = param(1.0, gt=0, le=1)
    clutter_rate: float = param(0.0, ge=0, le=limits.CLUTTER_RATE)
    vehicle_noise_density: float = param(2.0, gt=0, le=limits.NOISE_DENSITY)
    feature_noise_density: float = param(0.05, gt=0, le=limits.NOISE_DENSITY)
    prior_position_std: float = param(2.0, ge=limits.STD_MIN, le=limits.LENGTH)
    prior_velocity_std: float = param(0.1, ge=limits.STD_MIN, le=limits.SPEED)
    birth_position_std: float = param(100.0, ge=limits.STD_MIN, le=limits.LENGTH)
    birth_velocity_std: float = param(10.0, ge=limits.STD_MIN, le=limits.SPEED)
    radar: bool = True
    n_radars: int = param(4, ge=1, le=1000)  # radars are a few junctions, not a network's every node
    radar_junctions: tuple[str, ...] = ()
    radar_positions: tuple[float, ...] = param((), ge=-limits.LENGTH, le=limits.LENGTH)
    radar_range: float = param(50.0, gt=0, le=limits.LENGTH)
    radar_field_of_view: float = param(float(np.pi), gt=0, le=float(np.pi), must="lie in (0, π] rad")
    radar_variance: float = param(0.1, ge=limits.VARIANCE_MIN, le=limits.LENGTH_VARIANCE)
    odometry: bool = False
    odometry_variance: float = param(1.0, ge=limits.VARIANCE_MIN, le=limits.LENGTH_VARIANCE)
    aoa: bool = True
    aoa_variance: float = param(0.10, ge=limits.VARIANCE_MIN, le=limits.ANGLE_VARIANCE)
    aoa_field_of_view: float = param(float(np.pi / 2), gt=0, le=float(np.pi / 2), must="lie in (0, π/2] rad")
    aoa_range: float = param(30.0, gt=0, le=limits.LENGTH)
    aoa_anchor_share: float = param(6 / 51, ge=0, le=1)
    anchor_position_std: float = param(0.1, ge=limits.STD_MIN, le=limits.LENGTH)
    anchor_heading_std: float = param(0.01, ge=limits.STD_MIN, le=limits.ANGLE)
    anonymous_gnss: bool = False

    def validate(self) -> None:
        self.require(self.network in (GRID, *NETWORKS) or self.network.lower().endswith(NETWORK_SUFFIXES),
                     "network", f"be {GRID!r}, {' or '.join(map(repr, NETWORKS))}, or the path of a "
                     "SUMO .net.xml or OpenStreetMap .osm file")
        self.require(self.duration >= self.dt, "duration", f"be >= dt = {self.dt}")
        self.require(self.zone_radii[0] <= self.zone_radii[1], "zone_radii",
                     "be (r_C, r_B) with 0 < r_C <= r_B")
        self.require(len(self.radar_positions) % 2 == 0, "radar_positions",
                     "be x, y pairs (an even number of coordinates, m)")
        self.require(not (self.radar_junctions and self.radar_positions), "radar_positions",
                     f"be empty when radar_junctions names the junctions ({', '.join(self.radar_junctions)})")
        self.require(len(set(self.radar_junctions)) == len(self.radar_junctions), "radar_junctions",
                     "name each junction once")

    def sizes(self) -> Sizes:
        """A floor for `cooploc.budget`: how many vehicles share a step depends on the traffic,
        so only one is counted, beside every static feature."""
        return Sizes(self.n_steps, 1, self.max_static_features, streamed=is_long(self.n_steps))

    @property
    def n_steps(self) -> int:
        return round(self.duration / self.dt)

    @property
    def own_network(self) -> bool:
        """Whether `network` is the path of the user's own network file."""
        return self.network not in (GRID, *NETWORKS)

    @property
    def network_label(self) -> str:
        """What the network is called in descriptions: the city, the grid, or the file."""
        if self.network == GRID:
            return "generated grid"
        return self.network if self.own_network else NETWORKS[self.network][2]


#: the parameters that change the SUMO run or the feature geometry (the cache key)
TRAFFIC_KEYS = ("network", "regulation", "grid_size", "grid_length", "area_half_width", "duration",
                "warmup", "dt", "vehicle_period", "pedestrian_period", "fringe_factor",
                "pole_spacing", "min_feature_spacing", "max_static_features")
