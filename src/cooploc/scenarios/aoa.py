"""The AoA-only cooperative localization model shared by `aoa-grid` and `aoa-manhattan`.

"Cooperative Localization with Angular Measurements and Posterior Linearization"
(`papers/002_dfdb230c2e4252cd.txt`, model restated in `papers/plbp_model_notes.md`),
§II and Table I. A scene module places the vehicles on its streets
(`place(params, rng) -> (n, 3)` states); `simulate` does the rest:

- Vehicles with state [p_x, p_y, α] (m, m, rad); ids 0 … n − 1, of which 0 …
  `n_anchors` − 1 are anchors (`anchor_ids`).
- Prior (eq. 1): μ_i ~ N(x_i, Σ_i), Σ_i = diag(σ_p², σ_p², σ_α²), given to estimators
  in `Setup.vehicle_prior`. Anchors — vehicles or road-side units with a concentrated
  prior — have σ_p = 0.1 m, σ_α = 0.01 rad (notes, *chosen*).
- Links: every pair within R_c (`communication_radius`), `Frame.links`.
- AoA (`sensors.AngleOfArrival`, kind `"aoa"`): each end of a link measures the other's
  bearing relative to its own heading, with N(0, σ²_θ) noise, if it falls in the field
  of view ±Δ of its left or right array.
- Table I: R_c = 30 m, σ_p = 5 m, σ_α = 0.35 rad, σ²_θ = 0.10 rad²; 51 vehicles,
  6 anchors.

Snapshot and tracking
---------------------
`n_steps = 1` (default) is the paper's snapshot: one frame, the prior is all there is
besides the AoA. `n_steps > 1` is the tracking extension: vehicles drive at constant
speed (uniform in [`speed_min`, `speed_max`]) straight along their street for
`n_steps` steps of `dt`; from step 1 on, every vehicle also gets a fresh fix of
[p_x, p_y, α] (kind `"gnss"`, `GnssPosition` over all three components) with the
prior's covariance, so that each step's prior is the previous posterior predicted by
the motion model (`motion.RandomWalk`, q_p = `motion_position_density`,
q_α = `motion_heading_density`) and updated with the fix. Speeds are those of congested
traffic (1–5 m/s), and q_p = speed_max² ΔT makes one step's random-walk spread match
the largest displacement.

Choices the paper leaves open
-----------------------------
- Δ = π/2 by default (the notes, decided after measurement; the paper's value was
  lost): a linear array sees the half-plane in front of it (±90° about its broadside),
  so the two side arrays together see every direction. Narrower fields of view (arrays
  that are poor near endfire) are a parameter: with Δ < π/2 a vehicle is blind to the
  vehicles ahead of and behind it, most of its neighbours on a street.
  `cooploc reproduce plbp` sweeps Δ (its field-of-view section).
- Anchors are vehicles whose positions are drawn like the others'; they are estimated
  like every vehicle but with the tight prior. The reproduce report scores non-anchor
  vehicles only, while `cooploc run` pools all vehicles in `vehicle_rmse_all` and lists
  every id in `vehicle_rmse`.
- Measurement noise is added to the true relative angle and the reading wrapped to
  [−π, π).
- Both array centres at the vehicle's reference point (paper footnote 1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cooploc.budget import Sizes
from cooploc.geometry import links_within, wrap_angle
from cooploc.motion import RandomWalk
from cooploc.params import Params, param
from cooploc.scenarios import limits
from cooploc.sensors import AngleOfArrival, GnssPosition
from cooploc.types import Frame, Recording, Setup, StateLayout, StateSet, Truth

__all__ = ["LAYOUT", "AoaParams", "anchor_ids", "simulate"]

LAYOUT = StateLayout(3, (0, 1), None, 2)


@dataclass(frozen=True)
class AoaParams(Params):
    """What every AoA scene shares: Table I, anchors, the arrays and tracking.

    Attributes
    ----------
    n_vehicles : vehicles, anchors included.
    n_anchors : vehicles with the anchor prior: ids 0 … min(n_anchors, n_vehicles) − 1
        (so that a sweep over n_vehicles may go below n_anchors).
    communication_radius : R_c in m.
    aoa_variance : σ²_θ in rad².
    field_of_view : Δ, half-width of each array's field of view in rad (π/2: each array
        sees the half-plane on its side).
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
    communication_radius: float = param(30.0, gt=0, le=limits.LENGTH)
    aoa_variance: float = param(0.10, ge=limits.VARIANCE_MIN, le=limits.ANGLE_VARIANCE)
    field_of_view: float = param(np.pi / 2, gt=0, le=np.pi / 2, must="lie in (0, π/2] rad")
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
        self.require(bool(np.isfinite(self.speed_max)) and self.speed_max >= self.speed_min, "speed_max",
                     f"be >= speed_min = {self.speed_min}")

    def sizes(self) -> Sizes:
        """Steps, vehicles and features of one run (for `cooploc.budget`)."""
        return Sizes(self.n_steps, self.n_vehicles, state_dim=LAYOUT.dim)


def anchor_ids(params: AoaParams) -> np.ndarray:
    """Ids of the anchor vehicles."""
    return np.arange(min(params.n_anchors, params.n_vehicles), dtype=np.int64)


def simulate(params: AoaParams, place: Callable[[np.random.Generator], np.ndarray],
             rng: np.random.Generator, scene: str) -> Recording:
    """One run: vehicles placed by `place(rng)` ((n, 3) states on the streets), then the
    priors, links and AoA rows of a snapshot (n_steps = 1) or a tracking run.

    `scene` opens `Setup.description` (e.g. "AoA grid: 50 m square").
    """
    n, T, dt = params.n_vehicles, params.n_steps, params.dt
    ids = np.arange(n, dtype=np.int64)
    anchors = ids < params.n_anchors
    rng_place, rng_prior, rng_aoa, rng_fix = rng.spawn(4)
    start = place(rng_place)
    speed = rng_place.uniform(params.speed_min, params.speed_max, n)
    travel = np.arange(T)[:, None] * dt * speed[None, :]                     # (T, n) m driven
    states = np.repeat(start[None], T, axis=0)
    states[..., 0] += travel * np.cos(start[:, 2])
    states[..., 1] += travel * np.sin(start[:, 2])

    std = np.where(anchors[:, None], [params.anchor_position_std] * 2 + [params.anchor_heading_std],
                   [params.prior_position_std] * 2 + [params.prior_heading_std])   # (n, 3)
    cov = np.einsum("ni,ij->nij", std**2, np.eye(3))
    prior_mean = start + std * rng_prior.standard_normal((n, 3))            # eq. (1)
    prior_mean[:, 2] = wrap_angle(prior_mean[:, 2])

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
        description=(f"{scene}: {n} vehicles ({int(anchors.sum())} anchors: ids below "
                     f"{int(anchors.sum())}), R_c = {params.communication_radius:g} m, "
                     f"{T} step{'s' if T > 1 else ''}"),
    )
    wrapped = states.copy()
    wrapped[..., 2] = wrap_angle(wrapped[..., 2])
    truth = Truth.always_present(ids, wrapped, origins)
    return Recording(setup, frames, truth)
