"""`aoa-grid`: AoA-only cooperative localization on a Manhattan street grid (issue 7).

Reproduces the scenario of §IV of "Cooperative Localization with Angular Measurements
and Posterior Linearization" (`papers/002_dfdb230c2e4252cd.txt`, model restated in
`papers/plbp_model_notes.md`), Table I and Figs. 4–6.

Model
-----
- Vehicles with state [p_x, p_y, α] (m, m, rad) on a square grid of streets
  (`grid_size` across, a street through the middle of every `block_size` strip, both
  ways), placed uniformly along the streets; each drives in one of the two directions
  in one of its `lanes` lanes on the right of the centre line, so its heading is along
  the street: 0, π/2, −π or −π/2. Default: one intersection of two 6-lane avenues
  (see below).
- Prior (eq. 1): μ_i ~ N(x_i, Σ_i), Σ_i = diag(σ_p², σ_p², σ_α²), given to estimators
  in `Setup.vehicle_prior`. Anchors have σ_p = 0.1 m, σ_α = 0.01 rad (notes, *chosen*).
- Links: every pair within R_c (`communication_radius`), `Frame.links`.
- AoA (`sensors.AngleOfArrival`, kind `"aoa"`): each end of a link measures the other's
  bearing relative to its own heading, with N(0, σ²_θ) noise, if it falls in the field
  of view ±Δ of its left or right array.
- Table I: R_c = 30 m, σ_p = 5 m, σ_α = 0.35 rad, σ²_θ = 0.10 rad²; 51 vehicles,
  6 anchors; Δ = π/3 (lost from the paper, *chosen*).

Snapshot and tracking
---------------------
`n_steps = 1` (default) is the paper's snapshot: one frame, the prior is all there is
besides the AoA. `n_steps > 1` is the tracking extension (preset `aoa-grid-tracking`):
vehicles drive at constant speed (uniform in [`speed_min`, `speed_max`]) along their
street for `n_steps` steps of `dt`; from step 1 on, every vehicle also gets a fresh
fix of [p_x, p_y, α] (kind `"gnss"`, `GnssPosition` over all three components) with
the prior's covariance, so that each step's prior is the previous posterior predicted
by the motion model (`motion.RandomWalk`, q_p = `motion_position_density`,
q_α = `motion_heading_density`) and updated with the fix. Speeds are those of congested
traffic (1–5 m/s) so that the intersection stays dense over the run, and
q_p = speed_max² ΔT makes one step's random-walk spread match the largest displacement.

Choices the paper leaves open
-----------------------------
- The map: the paper uses a piece of central Manhattan (51 vehicles on a zoom-18 map,
  Fig. 3) that is not available. Streets run through the middle of each
  `block_size` strip of a `grid_size` square, `lanes` lanes per direction. Its own
  statements imply a compact, dense scene: RMSE falls with R_c "up to the point where
  all vehicles are in each others' communication range" (≈ 30–50 m), and raising σ_p
  from 0 to 10 m costs "less than 2 m", i.e. the position RMSE at σ_p = 5 m is below
  2 m. The default is therefore one Manhattan intersection in congested traffic: a
  50 m × 50 m square with one 6-lane avenue each way (3 lanes per direction, 3.5 m
  lanes), 51 vehicles along its four 25 m arms (≈ 12 m of lane per vehicle), every
  vehicle with ≈ 40 links. Sparser grids are a parameter away (e.g. `grid_size=200`,
  `block_size=50`: 4 × 4 streets); accuracy falls quickly with density (see the
  reproduce report).
- Anchors are vehicles: ids 0 … `n_anchors` − 1 (their positions are random like the
  others'), estimated like every vehicle but with the tight prior. `anchor_ids(params)`
  names them; the reproduce report scores non-anchor vehicles only, while `cooploc run`
  pools all vehicles in `vehicle_rmse_all` and lists every id in `vehicle_rmse`.
- Δ = π/3 is the notes' choice (the paper's value was lost). Accuracy depends on it
  strongly: with Δ < π/2 the arrays miss the vehicles ahead and behind, most of a
  vehicle's neighbours on a street. `cooploc reproduce plbp` measures the share of
  non-anchor vehicles within 4 m and 0.15 rad against Δ (its `field_of_view.png`).
- Measurement noise is added to the true relative angle and the reading wrapped to
  [−π, π).
- Both array centres at the vehicle's reference point (paper footnote 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.budget import Sizes
from cooploc.geometry import links_within
from cooploc.motion import RandomWalk
from cooploc.params import Params, param
from cooploc.registry import Preset, register_scenario
from cooploc.scenarios import limits
from cooploc.sensors import AngleOfArrival, GnssPosition
from cooploc.types import Frame, Recording, Setup, StateLayout, StateSet, Truth

__all__ = ["PRESETS", "AoaGridParams", "anchor_ids", "generate", "place_vehicles"]

LAYOUT = StateLayout(3, (0, 1), None, 2)


@dataclass(frozen=True)
class AoaGridParams(Params):
    """Parameters of `aoa-grid`; defaults are Table I of the paper and the choices above.

    Attributes
    ----------
    n_vehicles : vehicles, anchors included.
    n_anchors : vehicles with the anchor prior: ids 0 … min(n_anchors, n_vehicles) − 1
        (so that a sweep over n_vehicles may go below n_anchors).
    grid_size : side of the square street grid in m.
    block_size : distance between parallel streets in m.
    lanes : lanes per direction of travel.
    lane_width : width of a lane in m (lane l's centre is (l + ½) lane widths from the
        street's centre line, on the right of the direction of travel).
    communication_radius : R_c in m.
    aoa_variance : σ²_θ in rad².
    field_of_view : Δ, half-width of each array's field of view in rad.
    prior_position_std, prior_heading_std : σ_p in m and σ_α in rad.
    anchor_position_std, anchor_heading_std : the same for anchors.
    n_steps : 1 = the paper's snapshot; more = tracking.
    dt : step length in s (tracking).
    speed_min, speed_max : speed range in m/s (tracking).
    motion_position_density, motion_heading_density : q_p (m²/s), q_α (rad²/s) of the
        random-walk prediction model given to estimators (tracking).
    """

    n_vehicles: int = param(51, ge=1)
    n_anchors: int = param(6, ge=0)
    grid_size: float = param(50.0, gt=0, le=limits.LENGTH)
    block_size: float = param(50.0, gt=0, le=limits.LENGTH)
    lanes: int = param(3, ge=1)
    lane_width: float = param(3.5, ge=0, le=limits.LENGTH)
    communication_radius: float = param(30.0, gt=0, le=limits.LENGTH)
    aoa_variance: float = param(0.10, ge=limits.VARIANCE_MIN, le=limits.ANGLE_VARIANCE)
    field_of_view: float = param(np.pi / 3, gt=0, le=np.pi / 2, must="lie in (0, π/2] rad")
    prior_position_std: float = param(5.0, ge=limits.STD_MIN, le=limits.LENGTH)
    prior_heading_std: float = param(0.35, ge=limits.STD_MIN, le=limits.ANGLE)
    anchor_position_std: float = param(0.1, ge=limits.STD_MIN, le=limits.LENGTH)
    anchor_heading_std: float = param(0.01, ge=limits.STD_MIN, le=limits.ANGLE)
    n_steps: int = param(1, ge=1)
    dt: float = param(0.1, gt=0, le=limits.STEP)
    speed_min: float = param(1.0, ge=0, le=limits.SPEED)
    speed_max: float = 5.0
    motion_position_density: float = param(2.5, ge=0, le=limits.NOISE_DENSITY)
    motion_heading_density: float = param(0.01, ge=0, le=limits.ANGLE_VARIANCE)

    def validate(self) -> None:
        self.require(self.block_size <= self.grid_size, "block_size", f"be <= grid_size = {self.grid_size}")
        # one street per block: more than 10⁴ a side is no road map and fills memory
        self.require(self.grid_size <= 1e4 * self.block_size, "block_size",
                     f"be >= grid_size / 10⁴ = {self.grid_size / 1e4:g} (at most 10⁴ streets a side)")
        self.require(bool(np.isfinite(self.speed_max)) and self.speed_max >= self.speed_min, "speed_max",
                     f"be >= speed_min = {self.speed_min}")

    def sizes(self) -> Sizes:
        """Steps, vehicles and features of one run (for `cooploc.budget`)."""
        return Sizes(self.n_steps, self.n_vehicles, state_dim=LAYOUT.dim)


def anchor_ids(params: AoaGridParams) -> np.ndarray:
    """Ids of the anchor vehicles."""
    return np.arange(min(params.n_anchors, params.n_vehicles), dtype=np.int64)


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
    n, T, dt = params.n_vehicles, params.n_steps, params.dt
    ids = np.arange(n, dtype=np.int64)
    anchors = ids < params.n_anchors
    rng_place, rng_prior, rng_aoa, rng_fix = rng.spawn(4)
    start = place_vehicles(params, rng_place)
    speed = rng_place.uniform(params.speed_min, params.speed_max, n)
    travel = np.arange(T)[:, None] * dt * speed[None, :]                     # (T, n) m driven
    states = np.repeat(start[None], T, axis=0)
    states[..., 0] += travel * np.cos(start[:, 2])
    states[..., 1] += travel * np.sin(start[:, 2])

    std = np.where(anchors[:, None], [params.anchor_position_std] * 2 + [params.anchor_heading_std],
                   [params.prior_position_std] * 2 + [params.prior_heading_std])   # (n, 3)
    cov = np.einsum("ni,ij->nij", std**2, np.eye(3))
    prior_mean = start + std * rng_prior.standard_normal((n, 3))            # eq. (1)
    prior_mean[:, 2] = (prior_mean[:, 2] + np.pi) % (2 * np.pi) - np.pi

    aoa = AngleOfArrival(default_cov=np.array([[params.aoa_variance]]),
                         field_of_view=params.field_of_view)
    fix = GnssPosition({int(i): cov[i] for i in ids[anchors]}, default_cov=cov[~anchors][0]
                       if (~anchors).any() else cov[0], state_indices=(0, 1, 2))
    frames, origins = [], []
    for k in range(T):
        # the k-d tree's order: the AoA noise is drawn link by link in this order
        links = links_within(ids, states[k, :, :2], params.communication_radius, tree_order=True)
        aoa_batch = aoa.measure(ids, states[k], links, rng_aoa)
        batches = {"aoa": aoa_batch}
        origin = {"aoa": aoa_batch.subject.copy()}
        if k > 0:  # tracking: a fresh fix of every vehicle (the prior at k = 0 plays that role)
            batches["gnss"] = fix.measure(ids, states[k], rng_fix)
            origin["gnss"] = ids
        frames.append(Frame(k, k * dt, ids, batches, links))
        origins.append(origin)

    sensors = {"aoa": aoa, **({"gnss": fix} if T > 1 else {})}
    setup = Setup(
        dt=dt,
        n_steps=T,
        vehicle_layout=LAYOUT,
        vehicle_motion=RandomWalk(params.motion_position_density, params.motion_heading_density),
        vehicle_prior=StateSet(ids, prior_mean, cov),
        sensors=sensors,
        description=(f"AoA grid: {n} vehicles ({int(anchors.sum())} anchors: ids below {int(anchors.sum())})"
                     f" on {params.grid_size:g} m, R_c = {params.communication_radius:g} m, "
                     f"{T} step{'s' if T > 1 else ''}"),
    )
    wrapped = states.copy()
    wrapped[..., 2] = (wrapped[..., 2] + np.pi) % (2 * np.pi) - np.pi
    truth = Truth.always_present(ids, wrapped, origins)
    return Recording(setup, frames, truth)


PRESETS = register_scenario("aoa-grid", generate, [
    Preset(
        name="aoa-grid",
        params=AoaGridParams(),
        summary="AoA-only snapshot: 51 vehicles (6 anchors) on a Manhattan grid, R_c = 30 m",
        doc="Reproduces Figs. 4–6 of 'Cooperative Localization with Angular Measurements and "
            "Posterior Linearization' (Table I parameters; grid and field of view chosen).",
    ),
    Preset(
        name="aoa-grid-tracking",
        params=AoaGridParams(n_steps=20),
        summary="aoa-grid over 20 steps of 0.1 s: each prior is the predicted previous posterior",
        doc="Beyond the paper: the aoa-grid scenario with moving vehicles and a fix per step.",
    ),
])
