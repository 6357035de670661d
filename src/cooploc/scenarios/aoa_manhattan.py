"""`aoa-manhattan`: AoA-only cooperative localization on a few Manhattan blocks (issue 15).

The scene of §IV of "Cooperative Localization with Angular Measurements and Posterior
Linearization" (`papers/002_dfdb230c2e4252cd.txt`) as `papers/plbp_model_notes.md`
describes it: 51 vehicles, 6 of them anchors, on the streets of a Manhattan grid a
few hundred metres across, headings along the streets, Table I parameters. The model —
priors, anchors, links, the two side arrays (Δ = π/2), tracking — is
`cooploc.scenarios.aoa`; this module places the vehicles. `aoa-grid` is the dense
single intersection that the paper's own statements imply.

Placement
---------
`n_avenues` avenues run north–south (x = i · `avenue_spacing`, i = 0 … n_avenues − 1)
and `n_streets` streets east–west (y = j · `street_spacing`), each from one outer road
of the grid to the other, so the map is (n_avenues − 1) · avenue_spacing by
(n_streets − 1) · street_spacing. Roads are one-way, directions alternating as in
Manhattan: avenue i northbound (α = π/2) for even i, southbound (−π/2) for odd i;
street j eastbound (0) for even j, westbound (−π) for odd j. An avenue has
`avenue_lanes`, a street `street_lanes` lanes of `lane_width`, centred on its centre
line. Each vehicle takes a lane with probability proportional to its length (every lane
of the map equally dense) and a point uniform along it; its heading is its road's
direction.

Choices the notes leave open
----------------------------
- Blocks of 270 m × 80 m (avenue to avenue, street to street, centre to centre: the
  common Manhattan block), 2 × 3 of them: 3 avenues and 4 streets, a 540 m × 240 m map
  with 12 intersections and ≈ 2.9 km of road.
- One-way roads with 4 lanes on an avenue and 2 on a street, 3.5 m lanes.
- Vehicles are placed independently (no spacing between them, no queues at
  intersections): the density is the same everywhere, 51 vehicles over 7.2 km of lane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.params import param
from cooploc.registry import Preset, register_scenario
from cooploc.scenarios import limits
from cooploc.scenarios.aoa import AoaParams, anchor_ids, simulate
from cooploc.types import Recording

__all__ = ["PRESETS", "AoaManhattanParams", "anchor_ids", "generate", "place_vehicles", "road_lines"]


@dataclass(frozen=True)
class AoaManhattanParams(AoaParams):
    """Parameters of `aoa-manhattan`: Table I and the arrays (`AoaParams`) and the map.

    Attributes
    ----------
    n_avenues, n_streets : north–south avenues and east–west streets (≥ 2 each: at least
        one block).
    avenue_spacing, street_spacing : distance between the centre lines of neighbouring
        avenues (the long side of a block) and streets (the short side), in m.
    avenue_lanes, street_lanes : lanes of a (one-way) avenue and street.
    lane_width : width of a lane in m.
    """

    n_avenues: int = param(3, ge=2)
    n_streets: int = param(4, ge=2)
    avenue_spacing: float = param(270.0, gt=0, le=limits.LENGTH)
    street_spacing: float = param(80.0, gt=0, le=limits.LENGTH)
    avenue_lanes: int = param(4, ge=1)
    street_lanes: int = param(2, ge=1)
    lane_width: float = param(3.5, ge=0, le=limits.LENGTH)

    def validate(self) -> None:
        super().validate()
        # a road per block side: more than 10⁴ a side is no road map and fills memory
        for key in ("n_avenues", "n_streets"):
            self.require(getattr(self, key) <= 10_000, key, "be <= 10⁴")

    @property
    def extent(self) -> tuple[float, float]:
        """Width (east–west) and height (north–south) of the map in m."""
        return ((self.n_avenues - 1) * self.avenue_spacing, (self.n_streets - 1) * self.street_spacing)


def _roads(params: AoaManhattanParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per road: vertical?, centre-line coordinate (m), direction of travel (rad), lanes."""
    avenues, streets = np.arange(params.n_avenues), np.arange(params.n_streets)
    vertical = np.r_[np.ones(avenues.size, bool), np.zeros(streets.size, bool)]
    centre = np.r_[avenues * params.avenue_spacing, streets * params.street_spacing]
    heading = np.r_[np.where(avenues % 2 == 0, np.pi / 2, -np.pi / 2),
                    np.where(streets % 2 == 0, 0.0, -np.pi)]
    lanes = np.r_[np.full(avenues.size, params.avenue_lanes), np.full(streets.size, params.street_lanes)]
    return vertical, centre, heading, lanes


def place_vehicles(params: AoaManhattanParams, rng: np.random.Generator) -> np.ndarray:
    """States (n, 3): a lane drawn in proportion to its length, a point uniform along it,
    the heading of its one-way road."""
    width, height = params.extent
    vertical, centre, heading, lanes = _roads(params)
    length = np.where(vertical, height, width)
    weight = lanes * length
    road = rng.choice(vertical.size, size=params.n_vehicles, p=weight / weight.sum())
    lane = rng.integers(0, lanes[road])
    offset = (lane - (lanes[road] - 1) / 2) * params.lane_width        # lanes centred on the centre line
    along = length[road] * rng.random(params.n_vehicles)
    across = centre[road] + offset
    x = np.where(vertical[road], across, along)
    y = np.where(vertical[road], along, across)
    return np.stack([x, y, heading[road]], axis=1)


def road_lines(params: AoaManhattanParams) -> list[np.ndarray]:
    """(2, 2) segments of every road's centre line and its two carriageway edges (m)."""
    width, height = params.extent
    vertical, centre, _, lanes = _roads(params)
    segments = []
    for v, c, k in zip(vertical, centre, lanes, strict=True):
        for offset in (-k * params.lane_width / 2, 0.0, k * params.lane_width / 2):
            a = c + offset
            segments.append(np.array([[a, 0.0], [a, height]]) if v else np.array([[0.0, a], [width, a]]))
    return segments


def generate(params: AoaManhattanParams, rng: np.random.Generator) -> Recording:
    """Simulate one run: a snapshot (n_steps = 1) or a tracking run."""
    width, height = params.extent
    return simulate(params, lambda r: place_vehicles(params, r), rng,
                    f"AoA Manhattan, {width:g} m × {height:g} m")


PRESETS = register_scenario("aoa-manhattan", generate, [
    Preset(
        name="aoa-manhattan",
        params=AoaManhattanParams(),
        summary="AoA-only snapshot: 51 vehicles (6 anchors) on 2 × 3 Manhattan blocks of 270 × 80 m, "
                "R_c = 30 m",
        doc="The scene of §IV of 'Cooperative Localization with Angular Measurements and Posterior "
            "Linearization' as the model notes describe it (Table I parameters; the blocks, "
            "lanes and field of view Δ = π/2 chosen).",
    ),
])
