"""`sumo-*`: urban traffic from Eclipse SUMO on real road networks (Brambilla et al. 2020 §VI).

Brambilla, Nicoli, Soatti & Deflorio (T-ITS 2020, ``papers/003``) validate ICP-DA on
an urban arterial in Turin simulated with a calibrated micro-simulator (AIMSUN) at
T_s = 0.75 s, comparing traffic-light-regulated (TLR) and vehicle-self-regulated (VSR)
junctions, with GNSS accuracy varying over three map zones. This family builds the
same kind of run with Eclipse SUMO, headless and in-process (`libsumo`; `traci` is
the fallback), on road networks of real cities that the `eclipse-sumo` package ships
under ``sumo/tools/game/`` (located through the installed package at run time;
nothing is downloaded or copied into cooploc), or on a generated grid (tests).

Model
-----
- Vehicles: state [p_x, p_y, v_x, v_y] (m, m/s) read from SUMO every step (position of
  the front bumper as SUMO reports it; velocity = speed along the heading). Vehicles
  enter and leave the network; their ids are the integer of SUMO's ``v<n>`` trip id,
  so the same trip has the same id in every run on the same traffic. Estimators get
  the CV model (Fröhle eqs. 28–29) with `vehicle_noise_density`.
- GNSS (paper §VI): position and velocity, z = x + w with
  W = diag(σ_p², σ_p², σ_v², σ_v²) of the zone the vehicle is in at that step —
  zone A σ_p = 3 m, σ_v = 0.1 m/s; B 8 m, 0.17 m/s; C 15 m, 0.45 m/s. Zones are rings
  around the centre of the study area (the dense built-up core, where the network's
  traffic lights cluster): C within `zone_radii[0]`, B within `zone_radii[1]`, A beyond.
  Each row of the GNSS batch carries its own covariance.
- Features (paper §VI: 64 static features at traffic lights, road signs, bus stops):
  static features from the network geometry — one at the stop line of every road
  entering a signalised junction (signal pole, right kerb), the corners of junction
  shapes, and poles along every road every `pole_spacing` m on the right kerb — spread
  by farthest-point sampling to at most `max_static_features` at least
  `min_feature_spacing` apart (signals first). SUMO pedestrians walking on the
  sidewalks are mobile features. Features are not known in advance (no prior).
- V2F (paper §VI): relative position and velocity z = f − x + w,
  W = diag(σ_p², σ_p², σ_v², σ_v²) with σ_p = σ_v = 0.1, of every feature within the
  sensing range R_s = 50 m (`sensors.RelativePosition` with a visibility mask; P_D and
  clutter optional); rows shuffled per vehicle.
- V2V links: every pair of present vehicles within R_c = 250 m (paper §V).

Choices the paper leaves open (parameters of `SumoParams`)
----------------------------------------------------------
- Network and demand: the paper's Turin arterial and its calibrated demand are not
  available. Presets use SUMO's Braunschweig and Berlin (Adlershof) networks, cut to a
  square study area of half-width `area_half_width` around the median of their
  traffic lights, with random trips (``randomTrips.py``: one vehicle every
  `vehicle_period` s, origins and destinations favouring the fringe by
  `fringe_factor`, so most vehicles cross the area as through traffic) and random
  pedestrian walks (one every `pedestrian_period` s). A `warmup` is simulated before
  recording so that step 0 already has traffic.
- TLR vs VSR: TLR keeps the shipped signals and adds those that netconvert's
  ``--tls.guess`` heuristic places (the Braunschweig export ships a single signal);
  VSR rewrites every signalised junction of that network as a priority junction
  (netconvert), minor roads yielding by SUMO's gap acceptance; the few junctions
  netconvert 1.28 crashes on (one in Braunschweig) stay signalised but are switched
  off at run time (``sumo --tls.all-off``: priority rules without the junction's
  internal waiting positions). Same geometry, same demand (trip files generated on
  the TLR network), same features.
- Priors: vehicles present at step 0 start from the paper's "fast start" prior
  N(x, diag(2², 2², 0.1², 0.1²)) centred on a draw around their true state; vehicles
  that enter later have none (`Setup.vehicle_prior` lists only step-0 vehicles) and
  are born from their first GNSS fix with `Setup.birth_cov`
  (`birth_position_std` = 100 m, `birth_velocity_std` = 10 m/s: broad, so that the
  first fix dominates).
- One feature motion model for all features (static and walking): CV with
  `feature_noise_density` (pedestrian-like).
- Randomness: SUMO's seed (driver imperfection, departure lanes and speeds) and the
  demand's seed are drawn from the run's generator, unless `traffic_seed` >= 0 fixes
  them so that Monte Carlo runs share one traffic realisation and differ only in
  sensor noise.

Caching
-------
The SUMO part (network build, demand, simulation, feature geometry) is deterministic
for its parameters and seed, and it is cached on disk as one ``.npz`` per key (a
SHA-256 of the network file, the SUMO version, the seed and every parameter that
changes the traffic — never the sensor parameters, so sensor sweeps reuse it). The
folder is ``$COOPLOC_CACHE_DIR/sumo`` if that variable is set, else
``$XDG_CACHE_HOME/cooploc/sumo`` (``~/.cache/cooploc/sumo``). Writes are atomic, so
parallel workers may share it; deleting the folder is always safe.

Complexity: simulation O(T · N) libsumo calls; a frame costs O(n K + n²) for n
vehicles present and K features.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from cooploc.errors import CooplocError
from cooploc.motion import ConstantVelocity
from cooploc.params import Params, param
from cooploc.registry import Preset, register_scenario
from cooploc.sensors import GnssPosition, RelativePosition
from cooploc.types import (
    Batch,
    FloatArray,
    Frame,
    IntArray,
    Recording,
    Setup,
    StateLayout,
    StateSet,
    Truth,
)

__all__ = [
    "NETWORKS",
    "PEDESTRIAN_ID_OFFSET",
    "PRESETS",
    "STATIC_FEATURE_ID_OFFSET",
    "TINY_GRID",
    "SumoNotInstalledError",
    "SumoParams",
    "Traffic",
    "cache_dir",
    "cache_key",
    "cache_path",
    "generate",
    "network_path",
    "simulate_traffic",
    "traffic",
    "traffic_seed",
    "zone_of",
]

#: real-city networks shipped by eclipse-sumo under sumo/tools/game/: name → (folder, file, city)
NETWORKS: dict[str, tuple[str, str, str]] = {
    "braunschweig": ("bs3d", "bs.net.xml", "Braunschweig (Germany), city centre"),
    "berlin": ("DRT", "osm.net.xml", "Berlin-Adlershof (Germany)"),
}
GRID = "grid"
REGULATIONS = ("tlr", "vsr")
ZONES = ("A", "B", "C")
STATIC_FEATURE_ID_OFFSET = 1_000_000
PEDESTRIAN_ID_OFFSET = 2_000_000
CACHE_FORMAT = 3  # bump when the cached arrays change meaning
_THREE_ZONES = "be three positive numbers (zones A, B, C)"
_KERB_OFFSET = 1.5  # m beyond the right edge of the rightmost lane: signal heads, poles


class SumoNotInstalledError(CooplocError, ImportError):
    """The `sumo` extra (eclipse-sumo, sumolib, libsumo or traci) is not installed."""


def _require_sumo() -> tuple[Any, Any]:
    """(sumo package, sumolib), or a clear error saying how to install them."""
    try:
        import sumo
        import sumolib
    except ImportError as exc:
        raise SumoNotInstalledError(
            "the sumo-* scenarios need Eclipse SUMO: install the optional extra with "
            "`pip install 'cooploc[sumo]'` (eclipse-sumo, sumolib, libsumo) — "
            f"import failed: {exc}"
        ) from exc
    return sumo, sumolib


def _simulator() -> Any:
    """libsumo (in-process) if available, else traci (SUMO as a subprocess)."""
    _require_sumo()
    try:
        # libsumo prints a warning about pyarrow's ABI on import; we do not use its
        # Parquet output, so the note is noise for our users
        with contextlib.redirect_stdout(io.StringIO()):
            import libsumo
        return libsumo
    except ImportError:
        pass
    try:
        import traci
        return traci
    except ImportError as exc:
        raise SumoNotInstalledError(
            "the sumo-* scenarios need libsumo or traci: `pip install 'cooploc[sumo]'`"
        ) from exc


@dataclass(frozen=True)
class SumoParams(Params):
    """Parameters of a SUMO traffic run; defaults follow Brambilla 2020 §VI where it says.

    Attributes
    ----------
    network : ``"grid"`` (netgenerate, for tests) or a name of `NETWORKS`.
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
    """

    network: str = param(GRID, choices=(GRID, *NETWORKS))
    regulation: str = param("tlr", choices=REGULATIONS)
    grid_size: int = param(3, ge=2)
    grid_length: float = param(100.0, gt=0)
    area_half_width: float = param(500.0, gt=0)
    duration: float = param(300.0, gt=0)
    warmup: float = param(120.0, ge=0)
    dt: float = param(0.75, gt=0)
    vehicle_period: float = param(2.0, gt=0)
    pedestrian_period: float = param(10.0, ge=0)
    fringe_factor: float = param(10.0, gt=0)
    traffic_seed: int = param(-1, ge=-1)
    pole_spacing: float = param(60.0, gt=0)
    min_feature_spacing: float = param(20.0, gt=0)
    max_static_features: int = param(64, ge=0)
    zone_radii: tuple[float, float] = param((150.0, 300.0), length=2, gt=0,
                                            must="be (r_C, r_B) with 0 < r_C <= r_B")
    gnss_position_std: tuple[float, float, float] = param((3.0, 8.0, 15.0), length=3, gt=0,
                                                          must=_THREE_ZONES)
    gnss_velocity_std: tuple[float, float, float] = param((0.1, 0.17, 0.45), length=3, gt=0,
                                                          must=_THREE_ZONES)
    v2f_position_std: float = param(0.1, gt=0)
    v2f_velocity_std: float = param(0.1, gt=0)
    sensing_range: float = param(50.0, gt=0)
    communication_range: float = param(250.0, gt=0)
    detection_probability: float = param(1.0, gt=0, le=1)
    clutter_rate: float = param(0.0, ge=0)
    vehicle_noise_density: float = param(2.0, gt=0)
    feature_noise_density: float = param(0.05, gt=0)
    prior_position_std: float = param(2.0, gt=0)
    prior_velocity_std: float = param(0.1, gt=0)
    birth_position_std: float = param(100.0, gt=0)
    birth_velocity_std: float = param(10.0, gt=0)

    def validate(self) -> None:
        self.require(self.duration >= self.dt, "duration", f"be >= dt = {self.dt}")
        self.require(self.zone_radii[0] <= self.zone_radii[1], "zone_radii",
                     "be (r_C, r_B) with 0 < r_C <= r_B")

    @property
    def n_steps(self) -> int:
        return round(self.duration / self.dt)


#: the parameters that change the SUMO run or the feature geometry (the cache key)
TRAFFIC_KEYS = ("network", "regulation", "grid_size", "grid_length", "area_half_width", "duration",
                "warmup", "dt", "vehicle_period", "pedestrian_period", "fringe_factor",
                "pole_spacing", "min_feature_spacing", "max_static_features")


# ----------------------------------------------------------------------------
# traffic: what SUMO simulates (cached)
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Traffic:
    """One SUMO run, sampled at the scenario steps.

    Attributes
    ----------
    t : (T,) simulation time of each step (s), starting after the warm-up.
    vehicle_ids : (N,) ids of the vehicles seen while recording, sorted.
    vehicle_states : (T, N, 4) [p_x, p_y, v_x, v_y]; zero where absent.
    vehicle_present : (T, N).
    pedestrian_ids, pedestrian_states, pedestrian_present : the same for pedestrians
        (ids already offset by `PEDESTRIAN_ID_OFFSET`).
    static_features : (K, 2) positions of the static features.
    static_kind : (K,) 0 signal, 1 junction corner, 2 pole.
    centre : (2,) centre of the study area (zone rings).
    bounds : (2, 2) [[x_min, x_max], [y_min, y_max]] of the network.
    signals : (S, 2) positions of the signalised junctions (empty for VSR).
    """

    t: FloatArray
    vehicle_ids: IntArray
    vehicle_states: FloatArray
    vehicle_present: np.ndarray
    pedestrian_ids: IntArray
    pedestrian_states: FloatArray
    pedestrian_present: np.ndarray
    static_features: FloatArray
    static_kind: IntArray
    centre: FloatArray
    bounds: FloatArray
    signals: FloatArray

    def save(self, path: Path) -> None:
        """Atomic write (temporary file + rename), safe with parallel workers."""
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as tmp:
            np.savez_compressed(tmp, **{f.name: getattr(self, f.name) for f in fields(self)})
        os.replace(tmp.name, path)

    @classmethod
    def load(cls, path: Path) -> Traffic:
        with np.load(path) as data:
            return cls(**{f.name: data[f.name] for f in fields(cls)})


def cache_dir() -> Path:
    """Folder of the traffic cache: $COOPLOC_CACHE_DIR/sumo, else the user cache dir."""
    root = os.environ.get("COOPLOC_CACHE_DIR")
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        root = os.path.join(base, "cooploc")
    return Path(root) / "sumo"


def network_path(name: str) -> Path:
    """The shipped network file of `name` inside the installed eclipse-sumo package."""
    sumo, _ = _require_sumo()
    folder, file, _ = NETWORKS[name]
    path = Path(sumo.SUMO_HOME) / "tools" / "game" / folder / file
    if not path.is_file():
        raise SumoNotInstalledError(f"eclipse-sumo {sumo.__version__} does not ship {path}")
    return path


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def cache_key(params: SumoParams, seed: int) -> str:
    """SHA-256 over the network file, the SUMO version, the seed and `TRAFFIC_KEYS`."""
    sumo, _ = _require_sumo()
    source = _file_digest(network_path(params.network)) if params.network != GRID else "netgenerate"
    payload = {"format": CACHE_FORMAT, "sumo": sumo.__version__, "network_file": source,
               "seed": int(seed), **{k: getattr(params, k) for k in TRAFFIC_KEYS}}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


def cache_path(params: SumoParams, seed: int) -> Path:
    """The cache file of the traffic of `params` and `seed`."""
    return cache_dir() / f"{params.network}-{params.regulation}-{cache_key(params, seed)}.npz"


def traffic(params: SumoParams, seed: int, *, use_cache: bool = True) -> Traffic:
    """The traffic of `params` and `seed`: from the cache, or simulated and cached."""
    path = cache_path(params, seed)
    if use_cache and path.is_file():
        try:
            return Traffic.load(path)
        except (OSError, ValueError, KeyError):  # a damaged file: simulate again
            pass
    result = simulate_traffic(params, seed)
    if use_cache:
        result.save(path)
    return result


def _run(args: list[str], what: str, cwd: Path, *, check: bool = True) -> bool:
    """Run a SUMO tool in `cwd` (the tools may leave files in their working folder)."""
    done = subprocess.run(args, capture_output=True, text=True, check=False, cwd=cwd)
    if done.returncode != 0 and check:
        raise CooplocError(f"{what} failed ({args[0]}, exit code {done.returncode}): "
                           f"{(done.stderr + done.stdout).strip()[-800:]}")
    return done.returncode == 0


def _binary(name: str) -> str:
    sumo, _ = _require_sumo()
    return str(Path(sumo.SUMO_HOME) / "bin" / name)


def _build_networks(params: SumoParams, folder: Path, sumolib: Any) -> tuple[Path, FloatArray]:
    """(network with traffic lights, centre of the study area)."""
    tlr = folder / "tlr.net.xml"
    if params.network == GRID:
        _run([_binary("netgenerate"), "--grid", "--grid.number", str(params.grid_size),
              "--grid.length", str(params.grid_length), "--default.lanenumber", "1",
              "--sidewalks.guess", "true", "--default-junction-type", "traffic_light",
              "--seed", "0", "--no-warnings", "true", "-o", str(tlr)], "netgenerate", folder)
        net = sumolib.net.readNet(str(tlr))
        (x0, y0), (x1, y1) = net.getBBoxXY()
        centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    else:
        source = network_path(params.network)
        net = sumolib.net.readNet(str(source))
        lights = [n.getCoord() for n in net.getNodes() if n.getType() == "traffic_light"]
        if lights:
            centre = np.median(np.array(lights, dtype=float), axis=0)
        else:
            (x0, y0), (x1, y1) = net.getBBoxXY()
            centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        h = params.area_half_width
        box = f"{centre[0] - h},{centre[1] - h},{centre[0] + h},{centre[1] + h}"
        _run([_binary("netconvert"), "-s", str(source), "--keep-edges.in-boundary", box,
              "--keep-edges.components", "1", "--tls.guess", "true", "--no-warnings", "true",
              "-o", str(tlr)], "netconvert (study area, traffic lights)", folder)
    return tlr, centre


def _unsignalised(tlr: Path, folder: Path, sumolib: Any) -> Path:
    """The network with every signalised junction rewritten as a priority junction (VSR).

    netconvert 1.28 crashes on a few joined junctions (one in Braunschweig); those are
    left signalised here and switched off at run time (``--tls.all-off``).
    """
    nodes = [n.getID() for n in sumolib.net.readNet(str(tlr)).getNodes()
             if n.getType() == "traffic_light"]
    vsr, patch = folder / "vsr.net.xml", folder / "unsignalised.nod.xml"

    def rewrite(ids: list[str], check: bool) -> bool:
        patch.write_text("<nodes>\n" + "".join(f'    <node id="{i}" type="priority"/>\n'
                                               for i in ids) + "</nodes>\n")
        return _run([_binary("netconvert"), "-s", str(tlr), "--node-files", str(patch),
                     "--no-warnings", "true", "-o", str(vsr)], "netconvert (unsignalised junctions)",
                    folder, check=check)

    if not rewrite(nodes, check=False):
        rewrite([i for i in nodes if rewrite([i], check=False)], check=True)
    return vsr


def _demand(params: SumoParams, net: Path, folder: Path, seed: int) -> list[Path]:
    """Random vehicle trips and pedestrian walks generated on the TLR network."""
    sumo, _ = _require_sumo()
    tool = str(Path(sumo.SUMO_HOME) / "tools" / "randomTrips.py")
    end = f"{params.warmup + params.duration:.3f}"
    seeds = np.random.SeedSequence(seed).generate_state(2)
    trips = folder / "vehicles.rou.xml"
    _run([sys.executable, tool, "-n", str(net), "-o", str(folder / "vehicles.trips.xml"),
          "-r", str(trips), "--seed", str(int(seeds[0])), "--period", str(params.vehicle_period),
          "--fringe-factor", str(params.fringe_factor), "--end", end, "--prefix", "v",
          "--validate"], "randomTrips (vehicles)", folder)
    files = [trips]
    if params.pedestrian_period > 0:
        walks = folder / "pedestrians.rou.xml"
        _run([sys.executable, tool, "-n", str(net), "-o", str(walks), "--pedestrians",
              "--seed", str(int(seeds[1])), "--period", str(params.pedestrian_period),
              "--end", end, "--prefix", "p"], "randomTrips (pedestrians)", folder)
        files.append(walks)
    return files


def _trip_number(sumo_id: str) -> int:
    """`v12` → 12 (ids made by randomTrips with our prefix)."""
    return int(sumo_id[1:].split(".")[0].split("#")[0])


def _record(api: Any, ids_of: Any, get: Any, offset: int) -> dict[int, tuple[float, float, float, float]]:
    """One step of one kind of traffic participant: id → (x, y, v_x, v_y)."""
    out = {}
    for sumo_id in ids_of():
        x, y = get.getPosition(sumo_id)
        speed, angle = get.getSpeed(sumo_id), np.deg2rad(get.getAngle(sumo_id))
        # SUMO's angle is clockwise from north: v = speed · (sin α, cos α)
        out[offset + _trip_number(sumo_id)] = (x, y, speed * np.sin(angle), speed * np.cos(angle))
    return out


def _dense(steps: list[dict[int, tuple[float, ...]]]) -> tuple[IntArray, FloatArray, np.ndarray]:
    ids = np.array(sorted({i for step in steps for i in step}), dtype=np.int64)
    states = np.zeros((len(steps), ids.size, 4))
    present = np.zeros((len(steps), ids.size), dtype=bool)
    for k, step in enumerate(steps):
        if step:
            cols = np.searchsorted(ids, np.fromiter(step, dtype=np.int64, count=len(step)))
            states[k, cols] = np.array(list(step.values()))
            present[k, cols] = True
    return ids, states, present


def simulate_traffic(params: SumoParams, seed: int) -> Traffic:
    """Build the network and demand, run SUMO headless, sample every `dt` (no cache)."""
    _, sumolib = _require_sumo()
    api = _simulator()
    with tempfile.TemporaryDirectory(prefix="cooploc-sumo-") as tmp:
        folder = Path(tmp)
        tlr, centre = _build_networks(params, folder, sumolib)
        # demand and features from the TLR network: both variants share them
        routes = _demand(params, tlr, folder, seed)
        features, kind = static_features(sumolib.net.readNet(str(tlr)), params)
        net_file = tlr if params.regulation == "tlr" else _unsignalised(tlr, folder, sumolib)
        net = sumolib.net.readNet(str(net_file))
        signals = np.array([n.getCoord() for n in net.getNodes() if n.getType() == "traffic_light"],
                           dtype=float).reshape(-1, 2)
        if params.regulation == "vsr":
            signals = np.zeros((0, 2))  # none left active (see `_unsignalised`)
        (x0, y0), (x1, y1) = net.getBBoxXY()
        T = params.n_steps
        end = params.warmup + params.duration
        # libsumo ignores args[0]; traci starts that binary
        args = [_binary("sumo"), "-n", str(net_file), "-r", ",".join(map(str, routes)),
                "--step-length", str(params.dt), "--begin", "0", "--end", f"{end + params.dt:.3f}",
                "--seed", str(int(np.random.SeedSequence(seed).generate_state(3)[2] % 2**31)),
                "--no-step-log", "true", "--no-warnings", "true", "--xml-validation", "never",
                "--ignore-route-errors", "true", "--duration-log.disable", "true",
                # VSR: a signal netconvert could not rewrite is switched off — its
                # junction falls back to priority rules (major 'O', minor yield 'o')
                "--tls.all-off", "true" if params.regulation == "vsr" else "false"]
        vehicles, pedestrians, times = [], [], np.zeros(T)
        with contextlib.redirect_stdout(io.StringIO()):
            api.start(args)
        try:
            start_step = round(params.warmup / params.dt)
            for _ in range(start_step):
                api.simulationStep()
            for k in range(T):
                times[k] = api.simulation.getTime()
                vehicles.append(_record(api, api.vehicle.getIDList, api.vehicle, 0))
                pedestrians.append(_record(api, api.person.getIDList, api.person,
                                           PEDESTRIAN_ID_OFFSET))
                api.simulationStep()
        finally:
            api.close()
    vids, vstates, vpresent = _dense(vehicles)
    pids, pstates, ppresent = _dense(pedestrians)
    return Traffic(times, vids, vstates, vpresent, pids, pstates, ppresent, features, kind,
                   np.asarray(centre, dtype=float), np.array([[x0, x1], [y0, y1]]), signals)


# ----------------------------------------------------------------------------
# static features from the network geometry
# ----------------------------------------------------------------------------


def _kerb_point(shape: FloatArray, offset: float, lateral: float) -> FloatArray:
    """Point at arc length `offset` along a polyline, moved `lateral` m to its right."""
    seg = np.diff(shape, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(length)])
    i = int(np.clip(np.searchsorted(cum, offset, side="right") - 1, 0, seg.shape[0] - 1))
    direction = seg[i] / max(length[i], 1e-9)
    point = shape[i] + direction * (offset - cum[i])
    return point + lateral * np.array([direction[1], -direction[0]])  # right of travel


def _road_edges(net: Any) -> list[Any]:
    return [e for e in net.getEdges() if e.getFunction() == "" and e.allows("passenger")]


def static_features(net: Any, params: SumoParams) -> tuple[FloatArray, IntArray]:
    """(K, 2) static feature positions and (K,) kinds (0 signal, 1 corner, 2 pole).

    Candidates: a signal pole at the stop line of every road entering a signalised
    junction (right kerb), every vertex of the shape of junctions with three or more
    roads, and poles every `pole_spacing` m along every road on the right kerb. They
    are spread by farthest-point sampling (signals first) to at most
    `max_static_features`, never closer than `min_feature_spacing`.
    """
    candidates: list[tuple[int, FloatArray]] = []
    for edge in _road_edges(net):
        lane = edge.getLanes()[0]  # index 0 is the rightmost lane in SUMO
        shape = np.array(lane.getShape(), dtype=float)
        if shape.shape[0] < 2:
            continue
        lateral = lane.getWidth() / 2 + _KERB_OFFSET
        length = float(np.hypot(*np.diff(shape, axis=0).T).sum())
        if edge.getToNode().getType() == "traffic_light":
            candidates.append((0, _kerb_point(shape, length, lateral)))
        for offset in np.arange(params.pole_spacing / 2, length, params.pole_spacing):
            candidates.append((2, _kerb_point(shape, float(offset), lateral)))
    for node in net.getNodes():
        legs = len(node.getIncoming()) + len(node.getOutgoing())
        if node.getType() in ("dead_end", "internal") or legs < 5:  # ≥ 3 two-way roads
            continue
        candidates.extend((1, np.asarray(p[:2], dtype=float)) for p in node.getShape())
    if not candidates or params.max_static_features == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
    kinds = np.array([c[0] for c in candidates], dtype=np.int64)
    points = np.array([c[1] for c in candidates])
    order = np.lexsort((points[:, 1], points[:, 0], kinds))  # deterministic: kind, then x, y
    kinds, points = kinds[order], points[order]
    chosen = _spread(points, kinds, params.max_static_features, params.min_feature_spacing)
    return points[chosen], kinds[chosen]


def _spread(points: FloatArray, kinds: IntArray, limit: int, spacing: float) -> IntArray:
    """Farthest-point sampling, signals first: indices of at most `limit` points ≥ `spacing` apart."""
    chosen = [0]
    nearest = np.hypot(*(points - points[0]).T)
    while len(chosen) < limit:
        # prefer the lowest kind that still has a point far enough, then the farthest one
        far = nearest >= spacing
        if not far.any():
            break
        best_kind = kinds[far].min()
        score = np.where(far & (kinds == best_kind), nearest, -1.0)
        i = int(np.argmax(score))
        chosen.append(i)
        nearest = np.minimum(nearest, np.hypot(*(points - points[i]).T))
    return np.array(chosen, dtype=np.int64)


# ----------------------------------------------------------------------------
# the recording: sensors on top of the traffic
# ----------------------------------------------------------------------------


def zone_of(positions: FloatArray, centre: FloatArray, zone_radii: tuple[float, float]) -> IntArray:
    """GNSS zone (0 = A, 1 = B, 2 = C) of each position (n, 2): rings around `centre`."""
    distance = np.hypot(*(np.asarray(positions)[:, :2] - centre).T)
    return np.where(distance <= zone_radii[0], 2, np.where(distance <= zone_radii[1], 1, 0))


def _zone_covariances(params: SumoParams) -> FloatArray:
    """(3, 4, 4) GNSS covariance of zones A, B, C: diag(σ_p², σ_p², σ_v², σ_v²)."""
    p, v = np.asarray(params.gnss_position_std), np.asarray(params.gnss_velocity_std)
    return np.stack([np.diag([pi**2, pi**2, vi**2, vi**2]) for pi, vi in zip(p, v, strict=True)])


def _links(ids: IntArray, positions: FloatArray, radius: float) -> IntArray:
    """(E, 2) pairs i < j of vehicles within `radius` m."""
    d = np.hypot(*(positions[:, None, :] - positions[None, :, :]).transpose(2, 0, 1))
    i, j = np.nonzero(np.triu(d <= radius, k=1))
    return np.stack([ids[i], ids[j]], axis=1)


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
    v2f = RelativePosition(default_cov=v2f_cov, state_indices=state)
    r = params.sensing_range
    clutter_region = np.array([[-r, r], [-r, r], [-20.0, 20.0], [-20.0, 20.0]])

    frames, origins = [], []
    for k in range(T):
        present = run.vehicle_present[k]
        ids, states = run.vehicle_ids[present], run.vehicle_states[k, present]
        zone = zone_of(states, run.centre, params.zone_radii)
        parts = [zone_sensors[z].measure(ids[zone == z], states[zone == z], rng_gnss) for z in range(3)]
        gnss_z = np.concatenate([b.z for b in parts])
        gnss_cov = np.concatenate([b.cov for b in parts])
        gnss_ids = np.concatenate([b.subject for b in parts])
        order = np.argsort(gnss_ids, kind="stable")
        gnss = Batch(gnss_z[order].reshape(-1, 4), gnss_cov[order].reshape(-1, 4, 4), gnss_ids[order],
                     gnss_ids[order])
        f_on = feature_present[k]
        f_ids, f_states = feature_ids[f_on], feature_states[k, f_on]
        distance = np.hypot(*(states[:, None, :2] - f_states[None, :, :2]).transpose(2, 0, 1))
        v2f_batch, v2f_origin = v2f.measure(
            ids, states, f_ids, f_states, rng_v2f, visible=distance <= r,
            detection_probability=params.detection_probability, clutter_rate=params.clutter_rate,
            clutter_region=clutter_region)
        links = _links(ids, states[:, :2], params.communication_range)
        frames.append(Frame(k, k * dt, ids, {"gnss": gnss, "v2f": v2f_batch}, links))
        origins.append({"gnss": gnss_ids[order], "v2f": v2f_origin})

    at_start = run.vehicle_ids[run.vehicle_present[0]]
    prior_cov = np.diag([params.prior_position_std**2] * 2 + [params.prior_velocity_std**2] * 2)
    start_states = run.vehicle_states[0, run.vehicle_present[0]]
    prior_mean = start_states + rng_prior.multivariate_normal(np.zeros(4), prior_cov,
                                                              size=at_start.size)
    birth_cov = np.diag([params.birth_position_std**2] * 2 + [params.birth_velocity_std**2] * 2)
    net = params.network if params.network == GRID else NETWORKS[params.network][2]
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
    return Recording(setup, frames, truth)


# ----------------------------------------------------------------------------
# presets
# ----------------------------------------------------------------------------


def _preset(network: str, regulation: str, **overrides: Any) -> Preset:
    label = "generated grid" if network == GRID else NETWORKS[network][2]
    lights = ("traffic-light regulated (TLR)" if regulation == "tlr"
              else "vehicle self-regulated (VSR, unsignalised priority junctions)")
    return Preset(
        name=f"sumo-{network}-{regulation}",
        params=SumoParams(network=network, regulation=regulation, **overrides),
        summary=f"SUMO urban traffic, {label}, {lights}; GNSS zones A/B/C, V2F R_s = 50 m",
        doc=("Analogue of Brambilla et al. 2020 §VI (Figs. 16–17) on a SUMO network; see "
             "cooploc.scenarios.sumo for what differs from the paper's Turin arterial."),
    )


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
    # tests and quick checks: a 3 × 3 grid of 100 m blocks, 60 s
    _preset(GRID, "tlr", duration=60.0, warmup=60.0, zone_radii=(40.0, 90.0)),
    _preset(GRID, "vsr", duration=60.0, warmup=60.0, zone_radii=(40.0, 90.0)),
])
