"""`aoa-grid`: AoA-only cooperative localization at a dense Manhattan intersection (issue 7).

Reproduces the scenario of §IV of "Cooperative Localization with Angular Measurements
and Posterior Linearization" (`papers/002_dfdb230c2e4252cd.txt`, model restated in
`papers/plbp_model_notes.md`), Table I and Figs. 4–6. The model — priors, anchors,
links, the two side arrays, tracking — is `cooploc.scenarios.aoa`; this module places
the vehicles. `aoa-manhattan` (`cooploc.scenarios.aoa_manhattan`) is the sparser scene
of several Manhattan blocks.

Placement
---------
Vehicles on a square grid of streets (`grid_size` across, a street through the middle
of every `block_size` strip, both ways), placed uniformly along the streets; each
drives in one of the two directions in one of its `lanes` lanes on the right of the
centre line, so its heading is along the street: 0, π/2, −π or −π/2.

Choices the paper leaves open
-----------------------------
- The map: the paper uses a piece of central Manhattan (51 vehicles on a zoom-18 map,
  Fig. 3) that is not available. Its own statements imply a compact, dense scene: RMSE
  falls with R_c "up to the point where all vehicles are in each others' communication
  range" (≈ 30–50 m), and raising σ_p from 0 to 10 m costs "less than 2 m", i.e. the
  position RMSE at σ_p = 5 m is below 2 m. The default is therefore one Manhattan
  intersection in congested traffic: a 50 m × 50 m square with one 6-lane avenue each
  way (3 lanes per direction, 3.5 m lanes), 51 vehicles along its four 25 m arms
  (≈ 12 m of lane per vehicle), every vehicle with ≈ 40 links. Sparser grids are a
  parameter away (e.g. `grid_size=200`, `block_size=50`: 4 × 4 streets), and
  `aoa-manhattan` is the scene of several blocks; accuracy falls quickly with density
  (see the reproduce report).
- Δ = π/2 (`cooploc.scenarios.aoa`): the two side arrays see all around.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.params import param
from cooploc.registry import Preset, register_scenario
from cooploc.scenarios import limits
from cooploc.scenarios.aoa import LAYOUT, AoaParams, anchor_ids, simulate
from cooploc.types import Recording

__all__ = ["LAYOUT", "PRESETS", "AoaGridParams", "anchor_ids", "generate", "place_vehicles"]


@dataclass(frozen=True)
class AoaGridParams(AoaParams):
    """Parameters of `aoa-grid`: Table I and the arrays (`AoaParams`) and the grid.

    Attributes
    ----------
    grid_size : side of the square street grid in m.
    block_size : distance between parallel streets in m.
    lanes : lanes per direction of travel.
    lane_width : width of a lane in m (lane l's centre is (l + ½) lane widths from the
        street's centre line, on the right of the direction of travel).
    """

    grid_size: float = param(50.0, gt=0, le=limits.LENGTH)
    block_size: float = param(50.0, gt=0, le=limits.LENGTH)
    lanes: int = param(3, ge=1)
    lane_width: float = param(3.5, ge=0, le=limits.LENGTH)

    def validate(self) -> None:
        super().validate()
        self.require(self.block_size <= self.grid_size, "block_size", f"be <= grid_size = {self.grid_size}")
        # one street per block: more than 10⁴ a side is no road map and fills memory
        self.require(self.grid_size <= 1e4 * self.block_size, "block_size",
                     f"be >= grid_size / 10⁴ = {self.grid_size / 1e4:g} (at most 10⁴ streets a side)")


def place_vehicles(params: AoaGridParams, rng: np.random.Generator) -> np.ndarray:
    """States (n, 3) uniform along the streets, heading along the street, right-hand lane."""
    n = params.n_vehicles
    # centre lines through the middle of each block-size strip of the square
    lines = (np.arange(int(params.grid_size // params.block_size)) + 0.5) * params.block_size
    vertical = rng.random(n) < 0.5                                         # N–S (x = const) or E–W
    line = lines[rng.integers(0, lines.size, n)]
    along = params.grid_size * rng.random(n)
    forward = rng.random(n) < 0.5
    heading = np.where(vertical, np.where(forward, np.pi / 2, -np.pi / 2),
                       np.where(forward, 0.0, -np.pi))
    x = np.where(vertical, line, along)
    y = np.where(vertical, along, line)
    # a lane on the right of the direction of travel: (sin α, −cos α)
    offset = params.lane_width * (rng.integers(0, params.lanes, n) + 0.5)
    x = x + offset * np.sin(heading)
    y = y - offset * np.cos(heading)
    return np.stack([x, y, heading], axis=1)


def generate(params: AoaGridParams, rng: np.random.Generator) -> Recording:
    """Simulate one run: a snapshot (n_steps = 1) or a tracking run."""
    return simulate(params, lambda r: place_vehicles(params, r), rng,
                    f"AoA grid, {params.grid_size:g} m square")


PRESETS = register_scenario("aoa-grid", generate, [
    Preset(
        name="aoa-grid",
        params=AoaGridParams(),
        summary="AoA-only snapshot: 51 vehicles (6 anchors) at a dense Manhattan intersection, R_c = 30 m",
        doc="Reproduces Figs. 4–6 of 'Cooperative Localization with Angular Measurements and "
            "Posterior Linearization' (Table I parameters; the dense intersection and the "
            "field of view Δ = π/2 chosen).",
    ),
    Preset(
        name="aoa-grid-tracking",
        params=AoaGridParams(n_steps=20),
        summary="aoa-grid over 20 steps of 0.1 s: each prior is the predicted previous posterior",
        doc="Beyond the paper: the aoa-grid scenario (Δ = π/2) with moving vehicles and a fix "
            "per step.",
    ),
])
