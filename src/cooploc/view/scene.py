"""The static scene of a run: roads, infrastructure and static features, per scenario family.

`scene(preset, params, recording)` returns a `Scene` of plain arrays that both
renderers (the Plotly page, the matplotlib animation) draw under the moving entities:

- roads: polylines (m) joined into one (P, 2) array with NaN rows between them;
  ``junctions`` the same for closed junction outlines;
- infrastructure: named points with a heading (radars, traffic lights);
- static features: features that stand still and are present at every step of the run
  (drawn once, not per frame).

Roads per family (what each scenario module defines; nothing is invented):

- ``sumo``: the lanes (centre lines) and junction outlines of the SUMO network the
  traffic ran on — rebuilt exactly as `cooploc.scenarios.sumo.simulation` builds it
  (netgenerate for the grid; netconvert's cut of the shipped city network to the study
  area) and read with sumolib; traffic lights from the network as infrastructure.
- ``brambilla2020``: the road (the x axis) and its sidewalk (y = `sidewalk_offset`),
  or the crossroad's two roads with lane centres at ± `lane_offset` and sidewalks at
  ± `sidewalk_offset`, over the extent the vehicles drive.
- ``aoa-grid``: the street centre lines through the middle of every `block_size`
  strip and their edges `lanes` × `lane_width` to each side.
- ``aoa-manhattan``: its avenues' and streets' centre lines and carriageway edges
  (`cooploc.scenarios.aoa_manhattan.road_lines`).
- the others (``froehle2018``, ``zhang2016``, ``gulati``) move in an open plane: no
  roads; the true paths of the whole run are drawn faintly instead.

Infrastructure sensors with a pose in `Truth.sensor_poses` (the radar of Zhang 2016
and Gulati 2017) are shown at their true pose.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cooploc.types import FloatArray, IntArray, Recording
from cooploc.view.frames import moving_features

__all__ = ["Scene", "scene"]

_NAN_ROW = np.full((1, 2), np.nan)


@dataclass(frozen=True)
class Scene:
    """What does not move in the view (metres, the scenario's frame).

    Attributes
    ----------
    roads : (P, 2) lane or road polylines separated by NaN rows.
    junctions : (Q, 2) closed junction outlines separated by NaN rows.
    paths : (R, 2) faint true paths (open-plane scenarios), NaN-separated.
    infrastructure : (I, 3) [x, y, yaw] of infrastructure sensors and signals.
    infrastructure_labels : (I,) what each one is ("radar 100", "traffic light").
    static_ids, static_positions : (S,), (S, 2) features that never move.
    description : one line under the title.
    """

    roads: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    junctions: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    paths: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    infrastructure: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    infrastructure_labels: tuple[str, ...] = ()
    static_ids: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    static_positions: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    description: str = ""


def polylines(lines: list[np.ndarray]) -> FloatArray:
    """Polylines (each (n_i, 2)) joined into one (P, 2) array, NaN rows between them."""
    parts = [p for line in lines for p in (np.asarray(line, dtype=float)[:, :2], _NAN_ROW)]
    return np.concatenate(parts) if parts else np.zeros((0, 2))


def _static_features(recording: Recording) -> tuple[IntArray, FloatArray]:
    truth = recording.truth
    fixed = ~moving_features(recording)
    return truth.feature_ids[fixed], truth.feature_states[0, fixed][:, :2]


def _sumo_roads(params: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(lanes, junction outlines, traffic lights (L, 2)) of the network the traffic ran on."""
    from cooploc.scenarios.sumo.simulation import _build_networks, _require_sumo

    _, sumolib = _require_sumo()
    with tempfile.TemporaryDirectory(prefix="cooploc-view-") as tmp:
        path, _ = _build_networks(params, Path(tmp), sumolib)
        net = sumolib.net.readNet(str(path))
    lanes = [np.array(lane.getShape(), dtype=float) for edge in net.getEdges()
             for lane in edge.getLanes()]
    outlines = []
    for node in net.getNodes():
        shape = np.array(node.getShape(), dtype=float).reshape(-1, 2) if node.getShape() else None
        if shape is not None and len(shape) >= 3:
            outlines.append(np.vstack([shape[:, :2], shape[:1, :2]]))
    lights = np.array([n.getCoord()[:2] for n in net.getNodes() if n.getType() == "traffic_light"],
                      dtype=float).reshape(-1, 2)
    if params.regulation == "vsr":
        lights = np.zeros((0, 2))
    return polylines(lanes), polylines(outlines), lights


def _extent(recording: Recording) -> tuple[float, float, float, float]:
    truth = recording.truth
    pos = truth.vehicle_states[..., :2][truth.vehicle_present]
    return float(pos[:, 0].min()), float(pos[:, 0].max()), float(pos[:, 1].min()), float(pos[:, 1].max())


def _brambilla_roads(params: Any, recording: Recording) -> FloatArray:
    x0, x1, y0, y1 = _extent(recording)
    if params.geometry == "road":
        return polylines([[[x0, 0.0], [x1, 0.0]],
                          [[x0, params.sidewalk_offset], [x1, params.sidewalk_offset]]])
    reach = max(abs(x0), abs(x1), abs(y0), abs(y1))
    lines = []
    for offset in (-params.sidewalk_offset, -params.lane_offset, params.lane_offset,
                   params.sidewalk_offset):
        lines += [[[-reach, offset], [reach, offset]], [[offset, -reach], [offset, reach]]]
    return polylines(lines)


def _grid_roads(params: Any) -> FloatArray:
    size = params.grid_size
    half = params.lanes * params.lane_width
    lines = []
    for c in (np.arange(int(size // params.block_size)) + 0.5) * params.block_size:
        for offset in (-half, 0.0, half):
            lines += [[[c + offset, 0.0], [c + offset, size]], [[0.0, c + offset], [size, c + offset]]]
    return polylines(lines)


def _paths(recording: Recording) -> FloatArray:
    truth = recording.truth
    lines = [truth.vehicle_states[truth.vehicle_present[:, i], i, :2]
             for i in range(truth.vehicle_ids.size)]
    lines += [truth.feature_states[truth.feature_present[:, j], j, :2]
              for j in range(truth.feature_ids.size)]
    return polylines([line for line in lines if len(line) > 1])


def scene(preset: Any, params: Any, recording: Recording) -> Scene:
    """The static scene of a run of `preset` (a registered `Preset`) with `params`."""
    static_ids, static_positions = _static_features(recording)
    setup, truth = recording.setup, recording.truth
    poses = np.asarray(truth.sensor_poses, dtype=float).reshape(-1, 3)
    labels = [f"radar {i}" for i in setup.infrastructure_ids[:len(poses)]]
    roads = junctions = paths = np.zeros((0, 2))
    if preset.family == "sumo":
        roads, junctions, lights = _sumo_roads(params)
        poses = np.vstack([poses, np.c_[lights, np.zeros(len(lights))]])
        labels += ["traffic light"] * len(lights)
    elif preset.family == "brambilla2020":
        roads = _brambilla_roads(params, recording)
    elif preset.family == "aoa-grid":
        roads = _grid_roads(params)
    elif preset.family == "aoa-manhattan":
        from cooploc.scenarios.aoa_manhattan import road_lines

        roads = polylines(road_lines(params))
    else:
        paths = _paths(recording)
    return Scene(roads, junctions, paths, poses, tuple(labels), static_ids, static_positions,
                 setup.description)
