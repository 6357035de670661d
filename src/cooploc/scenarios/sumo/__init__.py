"""`sumo-*`: urban traffic from Eclipse SUMO on real road networks (Brambilla et al. 2020 §VI).

Brambilla, Nicoli, Soatti & Deflorio (T-ITS 2020, ``papers/003``) validate ICP-DA on
an urban arterial in Turin simulated with a calibrated micro-simulator (AIMSUN) at
T_s = 0.75 s, comparing traffic-light-regulated (TLR) and vehicle-self-regulated (VSR)
junctions, with GNSS accuracy varying over three map zones and 64 static features
along the roads (§VI-A). This family builds the same kind of run with Eclipse SUMO,
headless and in-process, on road networks of real cities that the ``eclipse-sumo``
package ships (Braunschweig, Berlin-Adlershof), on the user's own network (``network``
= the path of a SUMO ``.net.xml`` or an OpenStreetMap ``.osm`` extract), or on a
generated grid (tests).

What differs from the paper, in short (each module says it in full):

- the network and the demand: SUMO's shipped city networks cut to a square study
  area around their traffic lights, random trips that mostly cross the area, random
  pedestrian walks, a warm-up before recording (the Turin arterial and its calibrated
  demand are not available);
- VSR: the same network with every signal rewritten as a priority junction;
- the static features: signal poles, junction corners and poles along the roads,
  spread to at most 64; SUMO's pedestrians are mobile features;
- the GNSS zones: rings C, B, A around the centre of the study area;
- vehicles enter and leave: those present at step 0 get the paper's fast-start prior,
  later ones are born from their first GNSS fix;
- the other papers' sensors on the same traffic (issue 19), each family switched by a
  key: road-side radars of unknown pose at the busiest junctions (Zhang 2016, Gulati
  2017), V2V angle of arrival with two side arrays (the PLBP paper), wheel odometry
  (Gulati eq. 4) and anonymous GNSS (Zhang 2016); SUMO's vehicle angle is the true
  heading (`Truth.vehicle_heading`).

The package, one job per module:

- `params` — `SumoParams` (defaults from §VI-A), the networks, id ranges;
- `simulation` — networks (netconvert/netgenerate), demand (randomTrips) and the
  libsumo/TraCI loop that yields `Traffic` (`simulate_traffic`);
- `cache` — `Traffic` on disk, keyed by everything that changes it (`traffic`),
  bounded in size with least-recently-used eviction (`cache_limit`, `evict`);
- `roads` — static features from the road geometry, GNSS zones (`zone_of`), junctions
  and the radars' sites (`junctions`, `radar_sites`);
- `scenario` — `generate` / `lay_sensors`: GNSS by zone, V2F, V2V links, radars,
  odometry, AoA, priors; the presets.

SUMO (eclipse-sumo, sumolib, libsumo or traci: the ``sumo`` extra) is imported only
when traffic is simulated; importing this package and listing its presets never
needs it. Timings and sizes: ``benchmarks/sumo_traffic.py``.
"""

from __future__ import annotations

from cooploc.scenarios.sumo.cache import (
    CACHE_FORMAT,
    CACHE_LIMIT_VARIABLE,
    DEFAULT_CACHE_LIMIT,
    cache_dir,
    cache_key,
    cache_limit,
    cache_path,
    evict,
    traffic,
)
from cooploc.scenarios.sumo.params import (
    GRID,
    NETWORK_SUFFIXES,
    NETWORKS,
    PEDESTRIAN_ID_OFFSET,
    RADAR_ID_OFFSET,
    REGULATIONS,
    STATIC_FEATURE_ID_OFFSET,
    TRAFFIC_KEYS,
    SumoParams,
)
from cooploc.scenarios.sumo.roads import ZONES, junctions, radar_sites, static_features, zone_of
from cooploc.scenarios.sumo.scenario import PRESETS, STREAMS, TINY_GRID, generate, lay_sensors, traffic_seed
from cooploc.scenarios.sumo.simulation import (
    SumoNotInstalledError,
    Traffic,
    network_file,
    network_path,
    simulate_traffic,
)

__all__ = [
    "CACHE_FORMAT",
    "CACHE_LIMIT_VARIABLE",
    "DEFAULT_CACHE_LIMIT",
    "GRID",
    "NETWORKS",
    "NETWORK_SUFFIXES",
    "PEDESTRIAN_ID_OFFSET",
    "PRESETS",
    "RADAR_ID_OFFSET",
    "REGULATIONS",
    "STATIC_FEATURE_ID_OFFSET",
    "STREAMS",
    "TINY_GRID",
    "TRAFFIC_KEYS",
    "ZONES",
    "SumoNotInstalledError",
    "SumoParams",
    "Traffic",
    "cache_dir",
    "cache_key",
    "cache_limit",
    "cache_path",
    "evict",
    "generate",
    "junctions",
    "lay_sensors",
    "network_file",
    "network_path",
    "radar_sites",
    "simulate_traffic",
    "static_features",
    "traffic",
    "traffic_seed",
    "zone_of",
]
