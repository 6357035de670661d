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

Complexity: O(L) candidates for L lane-shape vertices and poles; the spreading is
O(K · L) for K chosen features; `zone_of` is O(n).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cooploc.scenarios.sumo.params import SumoParams
from cooploc.types import FloatArray, IntArray

__all__ = ["ZONES", "road_edges", "static_features", "zone_of"]

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
