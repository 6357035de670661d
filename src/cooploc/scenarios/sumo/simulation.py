"""Running SUMO headless: network, demand and the stepping loop that yields `Traffic`.

Brambilla et al. 2020 §VI-A simulate an urban arterial in Turin with a calibrated
micro-simulator (AIMSUN) at T_s = 0.75 s, in two regulations: traffic-light regulated
(TLR) and vehicle self-regulated (VSR, gap acceptance at unsignalised junctions), on
the same roads and demand. `simulate_traffic` builds the same kind of run with
Eclipse SUMO, in-process through `libsumo` (`traci`, SUMO as a subprocess, is the
fallback with identical results), and samples every vehicle and pedestrian at every
step. SUMO (sumo, sumolib, libsumo, traci) is imported on first use only, so that
listing the presets never needs it; without it, `SumoNotInstalledError` says how to
install the extra.

Choices the paper leaves open
-----------------------------
- Network: the Turin arterial is not available. Real networks are the ones the
  ``eclipse-sumo`` package ships under ``sumo/tools/game/`` (`NETWORKS`, located
  through the installed package at run time; nothing is downloaded or copied), or the
  user's own (`network` = a path, `network_file`): a SUMO ``.net.xml``, or an
  OpenStreetMap extract that SUMO's netconvert imports (`_from_osm`: its default OSM
  type map, geometry simplified, junction clusters joined, signals guessed from OSM's
  ``highway=traffic_signals`` nodes, sidewalks guessed for the pedestrians). Every
  real network is cut with netconvert to a square of half-width `area_half_width`
  around the median of its traffic lights (the dense core; the centre of its bounding
  box if it has none); the test network is a netgenerate grid (`GRID_OPTIONS`: with
  crossings and walking areas, so that pedestrians walk across junctions).
- Pedestrians: a network without walking areas (Braunschweig's export, an
  OpenStreetMap import) gets sidewalks, crossings and walking areas guessed by
  netconvert when it is cut (`PEDESTRIAN_OPTIONS`). Without them SUMO lets a person
  "jump" between any two pedestrian edges of a junction, and moves it there in one
  step: 6–34 m in 0.75 s on Braunschweig, a discontinuity that the features' CV model
  cannot explain (`oracle-kf`'s NIS per degree of freedom was 9.3 there, 88 % of it
  on the 7 steps of 80 with a jump). A network that has walking areas (Berlin) is
  cut as it is.
- Demand: the calibrated origin–destination demand is not available. randomTrips
  generates one vehicle trip every `vehicle_period` s with origins and destinations
  favouring the fringe by `fringe_factor` (most vehicles cross the area as through
  traffic) and, if `pedestrian_period` > 0, a pedestrian walk every
  `pedestrian_period` s, up to the end of the recording. A `warmup` is simulated
  before recording so that step 0 already has traffic.
- TLR keeps the shipped signals and adds those netconvert's ``--tls.guess`` places
  (the Braunschweig export ships a single signal). VSR rewrites every signalised
  junction as a priority junction (netconvert; minor roads yield by SUMO's gap
  acceptance); the few junctions netconvert 1.28 crashes on (one in Braunschweig)
  stay signalised but are switched off at run time (``sumo --tls.all-off``: priority
  rules without the junction's internal waiting positions). Both variants share the
  geometry, the demand (trip files generated on the TLR network) and the features.
- States: [p_x, p_y, v_x, v_y] (m, m/s), the position of the front bumper as SUMO
  reports it and the velocity as speed along the heading. Ids are the integer of the
  ``v<n>`` / ``p<n>`` trip id, so a trip has the same id in every run on the same
  demand.
- Heading: SUMO's own vehicle angle (degrees clockwise from north), recorded as
  α = wrap(π/2 − angle) (rad, counter-clockwise from the x axis, the convention of
  `cooploc.geometry`), so that v = speed · (cos α, sin α). It is kept beside the
  state because the velocity loses it whenever a vehicle stands (at a red light, in a
  queue), where its angle-of-arrival arrays still point somewhere.
- Junctions: every node of the study area that a road open to passenger cars touches,
  with SUMO's junction id, its position and the number of distinct nodes such roads
  join it to (`roads.junctions`); the road-side radars stand at some of them.
- Seeds: one traffic seed gives the two randomTrips seeds and SUMO's own seed (driver
  imperfection, departure lanes and speeds) through `numpy.random.SeedSequence`.

Complexity: O(T · N) simulator calls for T steps and N participants present. What a
run costs on real networks is measured by ``benchmarks/sumo_traffic.py``.
"""

from __future__ import annotations

import contextlib
import gzip
import io
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from cooploc.errors import CooplocError, InvalidInputError
from cooploc.geometry import wrap_angle
from cooploc.scenarios.sumo.params import GRID, NETWORKS, OSM_SUFFIXES, PEDESTRIAN_ID_OFFSET, SumoParams
from cooploc.scenarios.sumo.roads import junctions, road_edges, static_features
from cooploc.types import FloatArray, IntArray

__all__ = ["GRID_OPTIONS", "SumoNotInstalledError", "Traffic", "network_file", "network_path",
           "simulate_traffic"]


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
class Traffic:
    """One SUMO run, sampled at the scenario steps.

    Attributes
    ----------
    t : (T,) simulation time of each step (s), starting after the warm-up.
    vehicle_ids : (N,) ids of the vehicles seen while recording, sorted.
    vehicle_states : (T, N, 4) [p_x, p_y, v_x, v_y]; zero where absent.
    vehicle_present : (T, N).
    vehicle_heading : (T, N) heading α (rad, counter-clockwise from the x axis, wrapped
        to [−π, π)) from SUMO's vehicle angle; zero where absent.
    pedestrian_ids, pedestrian_states, pedestrian_present : the same for pedestrians
        (ids already offset by `PEDESTRIAN_ID_OFFSET`).
    static_features : (K, 2) positions of the static features.
    static_kind : (K,) 0 signal, 1 junction corner, 2 pole.
    centre : (2,) centre of the study area (zone rings).
    bounds : (2, 2) [[x_min, x_max], [y_min, y_max]] of the network.
    signals : (S, 2) positions of the signalised junctions (empty for VSR).
    junction_ids : (J,) SUMO ids of the junctions (nodes a road touches), sorted.
    junctions : (J, 2) their positions.
    junction_roads : (J,) how many distinct junctions roads join each one to.
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
    vehicle_heading: FloatArray
    junction_ids: np.ndarray
    junctions: FloatArray
    junction_roads: IntArray

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



def network_path(name: str) -> Path:
    """The shipped network file of `name` inside the installed eclipse-sumo package."""
    sumo, _ = _require_sumo()
    folder, file, _ = NETWORKS[name]
    path = Path(sumo.SUMO_HOME) / "tools" / "game" / folder / file
    if not path.is_file():
        raise SumoNotInstalledError(f"eclipse-sumo {sumo.__version__} does not ship {path}")
    return path

def network_file(network: str) -> Path:
    """The file of a shipped network (`network_path`) or of the user's own (its path)."""
    if network in NETWORKS:
        return network_path(network)
    path = Path(network).expanduser()
    if not path.is_file():
        raise InvalidInputError(f"network={network!r}: no such file")
    return path


def _run(args: list[str], what: str, cwd: Path, *, check: bool = True,
         error: type[CooplocError] = CooplocError) -> bool:
    """Run a SUMO tool in `cwd` (the tools may leave files in their working folder); a
    failure raises `error` (bad input where the user's own file caused it)."""
    done = subprocess.run(args, capture_output=True, text=True, check=False, cwd=cwd)
    if done.returncode != 0 and check:
        output = " ".join((done.stderr + done.stdout).split())  # one line
        raise error(f"{what} failed ({Path(args[0]).name}, exit code {done.returncode}): {output[-800:]}")
    return done.returncode == 0


#: netconvert options that give a network crossings and walking areas. Without walking
#: areas SUMO's pedestrian router lets a person "jump" between any two pedestrian edges
#: of a junction, and the simulation moves it there in one step (SUMO's documentation,
#: Simulation/Pedestrians): a jump of about the junction's width, up to 35 m in one
#: 0.75 s step on Braunschweig, which no motion model given to the estimators allows —
#: `oracle-kf`, which keeps the pedestrian's track, then drags the vehicles that see it.
#: The grid is generated with them (`GRID_OPTIONS`); a real network that has none
#: (Braunschweig's export, an OpenStreetMap import) gets them when it is cut (`cache_key`
#: hashes them).
PEDESTRIAN_OPTIONS = ("--sidewalks.guess", "true", "--crossings.guess", "true", "--walkingareas", "true")
#: netgenerate options of the grid (`cache_key` hashes them), with crossings and walking
#: areas (`PEDESTRIAN_OPTIONS`).
GRID_OPTIONS = ("--default.lanenumber", "1", *PEDESTRIAN_OPTIONS, "--default-junction-type", "traffic_light",
                "--seed", "0", "--no-warnings", "true")


def _binary(name: str) -> str:
    sumo, _ = _require_sumo()
    return str(Path(sumo.SUMO_HOME) / "bin" / name)


def _build_networks(params: SumoParams, folder: Path, sumolib: Any) -> tuple[Path, FloatArray]:
    """(network with traffic lights, centre of the study area)."""
    tlr = folder / "tlr.net.xml"
    if params.network == GRID:
        _run([_binary("netgenerate"), "--grid", "--grid.number", str(params.grid_size),
              "--grid.length", str(params.grid_length), *GRID_OPTIONS, "-o", str(tlr)], "netgenerate", folder)
        net = sumolib.net.readNet(str(tlr))
        (x0, y0), (x1, y1) = net.getBBoxXY()
        centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    else:
        source = network_file(params.network)
        if params.network.lower().endswith(OSM_SUFFIXES):
            source = _from_osm(params, source, folder)
        net = _read_network(params, source, sumolib)
        lights = [n.getCoord() for n in net.getNodes() if n.getType() == "traffic_light"]
        if lights:
            centre = np.median(np.array(lights, dtype=float), axis=0)
        else:
            (x0, y0), (x1, y1) = net.getBBoxXY()
            centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        h = params.area_half_width
        box = f"{centre[0] - h},{centre[1] - h},{centre[0] + h},{centre[1] + h}"
        what = "netconvert (study area, traffic lights)"
        # a network without walking areas gets them, with crossings (`PEDESTRIAN_OPTIONS`)
        walking = () if _has_walking_areas(source) else PEDESTRIAN_OPTIONS
        _run([_binary("netconvert"), "-s", str(source), "--keep-edges.in-boundary", box,
              "--keep-edges.components", "1", "--tls.guess", "true", *walking, "--no-warnings", "true",
              "-o", str(tlr)], f"network={params.network!r}: {what}" if params.own_network else what,
             folder, error=InvalidInputError if params.own_network else CooplocError)
    return tlr, centre


def _from_osm(params: SumoParams, source: Path, folder: Path) -> Path:
    """The SUMO network of an OpenStreetMap extract, converted by netconvert."""
    out = folder / "osm.net.xml"
    _run([_binary("netconvert"), "--osm-files", str(source), "--geometry.remove", "true",
          "--junctions.join", "true", "--tls.guess-signals", "true", "--tls.join", "true",
          "--sidewalks.guess", "true", "--no-warnings", "true", "-o", str(out)],
         f"network={params.network!r}: netconvert (OpenStreetMap import)", folder, error=InvalidInputError)
    return out


def _has_walking_areas(path: Path) -> bool:
    """Whether the SUMO network file (plain or gzip) has walking areas (sumolib's reader
    skips them with the other internal edges, so the file's text is searched)."""
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    with opener(path, "rt", encoding="utf-8", errors="replace") as text:
        return any('function="walkingarea"' in line for line in text)


def _read_network(params: SumoParams, path: Path, sumolib: Any) -> Any:
    """sumolib's network of the user's file, or `InvalidInputError` if it is not one."""
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            return sumolib.net.readNet(str(path))
    except Exception as exc:  # sumolib raises whatever its XML parser met
        text = " ".join(str(exc).split())[:300]
        raise InvalidInputError(f"network={params.network!r}: not a readable SUMO network "
                                f"({type(exc).__name__}: {text})") from exc


def _check_drivable(params: SumoParams, net: Any) -> None:
    if not road_edges(net):
        raise InvalidInputError(
            f"network={params.network!r}: no road open to passenger cars in the study area (a square "
            f"of half-width area_half_width = {params.area_half_width:g} m around the network's centre)")


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


def _record(api: Any, ids_of: Any, get: Any, offset: int
            ) -> dict[int, tuple[float, float, float, float, float]]:
    """One step of one kind of traffic participant: id → (x, y, v_x, v_y, SUMO angle in rad)."""
    out = {}
    for sumo_id in ids_of():
        x, y = get.getPosition(sumo_id)
        speed, angle = get.getSpeed(sumo_id), np.deg2rad(get.getAngle(sumo_id))
        # SUMO's angle is clockwise from north: v = speed · (sin α, cos α)
        out[offset + _trip_number(sumo_id)] = (x, y, speed * np.sin(angle), speed * np.cos(angle), angle)
    return out


def _dense(steps: list[dict[int, tuple[float, ...]]]) -> tuple[IntArray, FloatArray, np.ndarray]:
    """ids (N,), values (T, N, 5) [x, y, v_x, v_y, SUMO angle] (zero where absent), presence (T, N)."""
    ids = np.array(sorted({i for step in steps for i in step}), dtype=np.int64)
    states = np.zeros((len(steps), ids.size, 5))
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
        study_area = sumolib.net.readNet(str(tlr))
        _check_drivable(params, study_area)
        # demand and features from the TLR network: both variants share them
        routes = _demand(params, tlr, folder, seed)
        features, kind = static_features(study_area, params)
        junction_ids, junction_xy, junction_roads = junctions(study_area)
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
    # SUMO's angle, clockwise from north, as a heading counter-clockwise from the x axis
    heading = np.where(vpresent, wrap_angle(np.pi / 2 - vstates[..., 4]), 0.0)
    return Traffic(times, vids, vstates[..., :4].copy(), vpresent, pids, pstates[..., :4].copy(), ppresent,
                   features, kind, np.asarray(centre, dtype=float), np.array([[x0, x1], [y0, y1]]),
                   signals, heading, junction_ids, junction_xy, junction_roads)

