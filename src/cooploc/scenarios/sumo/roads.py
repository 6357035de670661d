"""Road geometry of a SUMO network: where the static features stand, which GNSS zone a point is in.

Brambilla et al. 2020 §VI-A place N_f = 64 static features "in correspondence of bus
stops, traffic lights, road signs and car parks" of the Turin arterial (Fig. 12) and
divide the area into three GNSS zones: A (open sky) outside, B intermediate, C the
built-up core. Neither the feature positions nor the zone borders are published, so
both come from the network here:

- Features (`static_features`): candidates are a signal pole at the stop line of every
  road entering a signalised junction, every vertex of the shape of junctions with
  three or more two-way roads (corners), and poles every `pole_spacing` m along every
  road. Signal poles and road poles stand on the right kerb, `_KERB_OFFSET` beyond the
  edge of the rightmost lane. The candidates are spread by farthest-point sampling
  (`_spread`), signals first, to at most `max_static_features` points never closer
  than `min_feature_spacing`; ties are broken by sorting on (kind, x, y), so the
  choice is deterministic for a network file.
- Zones (`zone_of`): rings around the centre of the study area (the median of the
  network's traffic lights, where the dense built-up core is): C within
  `zone_radii[0]`, B within `zone_radii[1]`, A beyond.
- Junctions (`junctions`) and where the road-side radars stand (`radar_sites`). Zhang
  et al. 2016 and Gulati et al. 2017 have one radar that sees every vehicle of a small
  scene; in a city, radars stand at junctions, where traffic meets. Candidates are the
  junctions where three or more roads meet (every junction a road touches, if the
  network has none such, e.g. a 2 × 2 grid). The busiest are chosen greedily: the most
  vehicle-steps within `radar_range` over the whole recorded traffic (a property of
  the traffic, the same for every sensor draw), ties broken by junction id, skipping a
  junction closer than `radar_range` to one already chosen so that two radars do not
  watch the same crossing. `radar_junctions` or `radar_positions` name the sites
  instead.

Complexity: O(L) candidates for L lane-shape vertices and poles; the spreading is
O(K · L) for K chosen features; `zone_of` is O(n); `radar_sites` O(P log P) for the P
vehicle-steps of the recording (one k-d tree).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cooploc.errors import ConfigError
from cooploc.scenarios.sumo.params import SumoParams
from cooploc.types import FloatArray, IntArray

__all__ = ["ZONES", "junctions", "radar_sites", "road_edges", "static_features", "zone_of"]

ZONES = ("A", "B", "C")
_KERB_OFFSET = 1.5  # m beyond the right edge of the rightmost lane: signal heads, poles


def _kerb_point(shape: FloatArray, offset: float, lateral: float) -> FloatArray:
    """Point at arc length `offset` along a polyline, moved `lateral` m to its right."""
    seg = np.diff(shape, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(length)])
    i = int(np.clip(np.searchsorted(cum, offset, side="right") - 1, 0, seg.shape[0] - 1))
    direction = seg[i] / max(length[i], 1e-9)
    point = shape[i] + direction * (offset - cum[i])
    return point + lateral * np.array([direction[1], -direction[0]])  # right of travel


def road_edges(net: Any) -> list[Any]:
    """The edges of a sumolib network that are roads open to passenger cars."""
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
    for edge in road_edges(net):
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


def zone_of(positions: FloatArray, centre: FloatArray, zone_radii: tuple[float, float]) -> IntArray:
    """GNSS zone (0 = A, 1 = B, 2 = C) of each position (n, 2): rings around `centre`."""
    distance = np.hypot(*(np.asarray(positions)[:, :2] - centre).T)
    return np.where(distance <= zone_radii[0], 2, np.where(distance <= zone_radii[1], 1, 0))


def junctions(net: Any) -> tuple[np.ndarray, FloatArray, IntArray]:
    """SUMO ids (J,) (sorted), positions (J, 2) and road counts (J,) of the junctions.

    A junction is a node that a road open to passenger cars (`road_edges`) touches; its
    road count is the number of distinct other junctions such roads join it to.
    """
    neighbours: dict[str, set[str]] = {}
    position: dict[str, tuple[float, float]] = {}
    for edge in road_edges(net):
        ends = (edge.getFromNode(), edge.getToNode())
        if ends[0].getID() == ends[1].getID():  # a loop joins the junction to no other
            continue
        for node, other in (ends, ends[::-1]):
            neighbours.setdefault(node.getID(), set()).add(other.getID())
            position[node.getID()] = tuple(node.getCoord()[:2])
    ids = sorted(neighbours)
    return (np.array(ids, dtype=str), np.array([position[i] for i in ids], dtype=float).reshape(-1, 2),
            np.array([len(neighbours[i]) for i in ids], dtype=np.int64))


def radar_sites(params: SumoParams, junction_ids: np.ndarray, junction_xy: FloatArray,
                junction_roads: IntArray, vehicle_xy: FloatArray) -> FloatArray:
    """(R, 2) positions of the road-side radars (module docstring: the busiest junctions).

    Parameters
    ----------
    junction_ids, junction_xy, junction_roads : the network's junctions (`junctions`).
    vehicle_xy : (P, 2) every recorded vehicle position (all steps), for "busiest".
    """
    if params.radar_positions:
        return np.asarray(params.radar_positions, dtype=float).reshape(-1, 2)
    if params.radar_junctions:
        unknown = [j for j in params.radar_junctions if j not in set(junction_ids.tolist())]
        if unknown:
            shown = ", ".join(junction_ids[:8].tolist()) + (", …" if junction_ids.size > 8 else "")
            raise ConfigError(f"{params.owner()}: radar_junctions must name junctions of the network "
                              f"({junction_ids.size} junctions: {shown}), got {unknown[0]!r}")
        return junction_xy[np.searchsorted(junction_ids, params.radar_junctions)]
    from scipy.spatial import cKDTree

    candidates = np.flatnonzero(junction_roads >= 3)
    if candidates.size == 0:
        candidates = np.arange(junction_ids.size)
    r = params.radar_range
    busy = (cKDTree(vehicle_xy).query_ball_point(junction_xy[candidates], r, return_length=True)
            if vehicle_xy.size else np.zeros(candidates.size, dtype=np.int64))
    chosen: list[int] = []
    for i in candidates[np.lexsort((candidates, -np.asarray(busy)))]:  # busiest first, then by id
        if len(chosen) == params.n_radars:
            break
        if not chosen or np.hypot(*(junction_xy[chosen] - junction_xy[i]).T).min() >= r:
            chosen.append(int(i))
    return junction_xy[np.array(chosen, dtype=np.int64)].reshape(-1, 2)
