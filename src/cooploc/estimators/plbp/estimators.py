"""`plbp` and `prior-lbp`: cooperative position and heading estimation from angle of arrival.

Paper: "Cooperative Localization with Angular Measurements and Posterior Linearization"
(`papers/002_dfdb230c2e4252cd.txt`; equations restated in `papers/plbp_model_notes.md`).

Model: vehicle state x_i = [p_x, p_y, α] (the AoA sensor's `state_indices`), Gaussian
prior N(μ_i, Σ_i) (eq. 1); AoA rows θ_{i←j} = wrap(atan2(p_j − p_i) − α_i) + w,
w ~ N(0, σ²_θ) (eqs. 2–5), grouped into one link factor per vehicle pair
(`plbp.links`). Every frame is one snapshot solved by Algorithm 1 (`plbp.solve`):
`plbp` relinearizes the links at the current posterior approximation (eq. 10),
`prior-lbp` linearizes them once at the priors.

Choices the paper leaves open:
- Tracking (beyond the paper's snapshot): the belief of the previous step is predicted
  with the scenario's motion model (`RandomWalk` for `aoa-grid`), then updated in
  information form with that step's `"gnss"` rows (a fresh position/heading fix,
  angular components moved onto the branch of the prediction); the result is the prior
  of this step's solve. Vehicles that enter start from `Setup.vehicle_prior` or their
  first fix (`estimators.base.birth_beliefs`). Gaussian BP treats the priors of a step
  as independent, but a carried posterior is correlated with its neighbours' through
  the AoA of earlier steps: a link's information lands in the beliefs of both its ends,
  and when they are linked again BP adds one end's carried belief to the other's, so a
  fully carried link is counted twice. The default `tracking="tempered"` carries the
  step's prior times half of what its links added (`tempered`, a fractional weight of
  the link factors), which counts it once; `"posterior"` carries the whole posterior
  (position NEES 1.4× `gnss-kf`'s on sumo-berlin-tlr, tempered 1.2×), and `"own-fixes"`
  each vehicle's filter of its own fixes, on which the AoA is solved as a snapshot every
  step (consistent as the GNSS filter, but it forgets the AoA of earlier steps).
  Measured in docs/plbp.md, "On a city".
- AoA rows naming a vehicle that is not present are ignored.
- Output headings are wrapped to [−π, π).
- Anchors (beyond the snapshot's priors): a scenario may give its anchors a fix of
  [p_x, p_y, α] at every step (kind `"anchor"`, `sumo-*`); it is fused like the
  `"gnss"` fix, after it.
- A layout without a heading but with a velocity ([p_x, p_y, v_x, v_y], the `sumo-*`
  family, whose AoA model reads the heading as component 4): the tracked beliefs stay
  over the layout, so the estimate has the layout's components like every other
  estimator's. At every step, after the fixes of the layout, the heading joins each
  belief as the direction of its velocity (`plbp.heading`: α = atan2(v_y, v_x) + s,
  by statistical linear regression, with its cross-covariance to v); the anchors' fixes
  and the solve run on [p, v, α]; then α is marginalised out again, so that the AoA
  information kept is what reached p and v. A receiver that may stand (its velocity
  belief does not exclude v = 0, `plbp.heading.standing`) and is no anchor has no known
  heading: the AoA rows it measures are left out (they carry no information), the rows
  others take of it stay. Counting them with the velocity's heading was what made the
  carried posterior over-confident on the cities (docs/plbp.md). The heading itself is
  reported in `info["heading"]` (n,) (wrapped) and scored against `Truth.vehicle_heading`.

`info["iterate_means"]` (J + 1, n, dx): the beliefs' means before the first and after
every linearization iteration (heading wrapped), in the order of `Estimate.vehicles`;
the estimator never sees truth, so per-iteration errors are computed by the caller
(`iteration_errors`). `info["n_links"]`: the number of link factors.

Complexity per step: that of `plbp_solve`, plus O(n dx³) for prediction and fixes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np

from cooploc.errors import ConfigError
from cooploc.estimators.base import VehicleBeliefs, checked_states
from cooploc.estimators.plbp.heading import standing, with_velocity_heading
from cooploc.estimators.plbp.links import link_factors
from cooploc.estimators.plbp.solve import plbp_solve
from cooploc.gaussian import Gaussians, from_information, kf_predict, symmetrize, to_information
from cooploc.geometry import wrap_angle
from cooploc.params import Params, param
from cooploc.registry import register_estimator
from cooploc.sensors import AngleOfArrival
from cooploc.types import Batch, Estimate, FloatArray, Frame, IntArray, Setup

__all__ = ["LINK_ENDS", "PLBP", "PLBPParams", "PriorLBP", "PriorLBPParams", "tempered"]


@dataclass(frozen=True)
class PLBPParams(Params):
    """Parameters of `plbp`.

    Attributes
    ----------
    linearization_iterations : J, relinearizations per snapshot (paper: converged by 4).
    bp_iterations : L, BP iterations per linearization.
    sigma_points : "unscented" or "cubature".
    central_weight : w₀ of the unscented points.
    heading_slip_std : σ_s (rad), spread of the heading about the velocity direction, where
        the heading comes from the velocity (a layout without a heading; `plbp.heading`).
    tracking : what a step carries on to the next one, where it is predicted and updated
        with that step's own fixes to become its prior. ``"tempered"`` (the default): the
        step's prior times half of the information its links added (`tempered`): a link's
        information lands in both its ends, so carrying all of it at each end counts it
        twice when they are linked again. ``"posterior"``: the step's posterior (until
        issue 19 the default). ``"own-fixes"``: each vehicle's own filter of its fixes
        (GNSS, and an anchor's fix); the AoA solve runs on it every step and its posterior
        is reported but not carried on, so the AoA of one step is never counted again.
        Measured: docs/plbp.md, "On a city".
    """

    linearization_iterations: int = param(5, ge=1)
    bp_iterations: int = param(3, ge=1)
    sigma_points: Literal["unscented", "cubature"] = "unscented"
    central_weight: float = param(1.0 / 3.0, ge=0, lt=1)
    heading_slip_std: float = param(0.01, gt=0, le=np.pi)
    tracking: str = param("tempered", choices=("tempered", "posterior", "own-fixes"))


@dataclass(frozen=True)
class PriorLBPParams(PLBPParams):
    """Parameters of `prior-lbp` (as `plbp`; the links are linearized once, at the priors)."""


@register_estimator
class PLBP:
    """Posterior-linearization Gaussian BP over AoA links, one solve per frame.

    Uses: AoA rows, identified GNSS fixes and the anchors' fixes.

    Knowingly inconsistent: Gaussian BP on the loopy AoA graph counts shared links more
    than once and each link is linearized, so the covariances are over-confident: its
    NEES on aoa-grid lies above the χ² band (tests/test_consistency.py bounds it by 2×
    the χ²₂ mean).
    """

    name: ClassVar[str] = "plbp"
    bound: ClassVar[str | None] = None
    summary: ClassVar[str] = "AoA cooperative position + heading, posterior-linearization Gaussian BP"
    Params: ClassVar[type[Params]] = PLBPParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "aoa-grid"
    required_sensors: ClassVar[tuple[str, ...]] = ("aoa",)
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "aoa": ("angle-of-arrival",), "gnss": ("gnss-position",), "anchor": ("gnss-position",)}
    posterior: ClassVar[bool] = True

    def __init__(self, setup: Setup, params: PLBPParams, rng: np.random.Generator) -> None:
        sensor = setup.sensors.get("aoa")
        if not isinstance(sensor, AngleOfArrival):
            raise ConfigError(f"{self.name} needs an 'aoa' sensor (AngleOfArrival) in the setup, "
                              f"got {sensor!r}")
        layout = setup.vehicle_layout
        self._velocity: tuple[int, ...] | None = None     # heading from the velocity (module docstring)
        if layout.heading is not None:
            self._heading = layout.heading
        elif (layout.velocity is not None and len(layout.velocity) == 2
              and sensor.state_indices == (*layout.position, layout.dim)):
            self._heading, self._velocity = layout.dim, layout.velocity
        else:
            raise ConfigError(
                f"{self.name} needs a vehicle layout with a heading, or a 2-D layout with a velocity and "
                f"an 'aoa' sensor reading the heading as component {layout.dim} (state_indices "
                f"{(*layout.position, layout.dim)}); got {layout} and state_indices {sensor.state_indices}")
        self.setup, self.params, self.sensor = setup, params, sensor
        self.vehicles = VehicleBeliefs(setup)
        motion = setup.vehicle_motion
        self._F = motion.transition_matrix(setup.dt)
        self._Q = None if motion.state_dependent_noise else motion.noise_covariance(setup.dt)
        self._started = False

    def step(self, frame: Frame) -> Estimate:
        p = self.params
        born = self.vehicles.sync(frame)
        beliefs = self._predict(self.vehicles.beliefs, ~born)
        self._started = True
        beliefs = self._fix(beliefs, frame.batches.get("gnss"), self.setup.sensors.get("gnss"))
        aoa = frame.batch("aoa", 1)
        if self._velocity is not None:
            aoa = self._moving_receivers(aoa, beliefs, frame.batches.get("anchor"))
            beliefs = with_velocity_heading(beliefs, self._velocity, p.heading_slip_std**2,
                                            method=p.sigma_points, central_weight=p.central_weight)
        beliefs = self._fix(beliefs, frame.batches.get("anchor"), self.setup.sensors.get("anchor"))
        dx = self.setup.vehicle_layout.dim
        own = Gaussians(beliefs.mean[:, :dx], beliefs.cov[:, :dx, :dx])   # the layout's marginal
        links = link_factors(aoa, self.vehicles.ids)
        posterior, iterates = plbp_solve(
            beliefs, links, self.sensor, linearization_iterations=p.linearization_iterations,
            bp_iterations=p.bp_iterations, posterior=self.posterior, method=p.sigma_points,
            central_weight=p.central_weight)
        mean = posterior.mean.copy()
        mean[:, self._heading] = wrap_angle(mean[:, self._heading])
        iterates[..., self._heading] = wrap_angle(iterates[..., self._heading])
        info: dict[str, Any] = {"iterate_means": iterates, "n_links": len(links)}
        cov = posterior.cov
        if self._velocity is not None:   # marginalise the heading out again
            info["heading"] = mean[:, self._heading]
            mean, cov = mean[:, :dx], cov[:, :dx, :dx]
        if p.tracking == "tempered":
            carried = tempered(beliefs, posterior, LINK_ENDS)
            carried.mean[:, self._heading] = wrap_angle(carried.mean[:, self._heading])
            self.vehicles.beliefs = Gaussians(carried.mean[:, :dx], carried.cov[:, :dx, :dx])
        else:
            self.vehicles.beliefs = Gaussians(mean, cov) if p.tracking == "posterior" else own
        return Estimate(checked_states(self.name, "vehicle", self.vehicles.ids, mean, cov), info=info)

    def _moving_receivers(self, aoa: Batch, beliefs: Gaussians, anchor: Batch | None) -> Batch:
        """The AoA rows whose receiver's heading is known: it moves, or it is an anchor.

        A bearing is relative to the receiver's heading. A vehicle whose velocity belief does
        not exclude v = 0 may stand (`plbp.heading.standing`), and a standing vehicle's
        heading is not the direction of a velocity: it is unknown, uniform over the circle,
        and a bearing minus a uniform angle is uniform whatever the positions. Such a row
        carries no information and is left out (the exact marginal over the heading); the
        rows others take of that vehicle stay. An anchor's heading comes with its fix.
        """
        still = standing(beliefs, self._velocity)
        if anchor is not None:
            still &= ~np.isin(self.vehicles.ids, anchor.subject)
        keep = ~np.isin(aoa.sensor, self.vehicles.ids[still])
        if keep.all():
            return aoa
        return Batch(aoa.z[keep], aoa.cov[keep], aoa.sensor[keep], aoa.subject[keep])

    def _predict(self, beliefs: Gaussians, moving: np.ndarray) -> Gaussians:
        """Prediction with the motion model of every vehicle that was already there."""
        if not self._started or not moving.any():
            return beliefs
        Q = self._Q if self._Q is not None else self.setup.vehicle_motion.noise_covariance(
            self.setup.dt, beliefs.mean[moving])
        predicted = kf_predict(beliefs.take(moving), self._F, Q)
        mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
        mean[moving], cov[moving] = predicted.mean, predicted.cov
        return Gaussians(mean, cov)

    def _fix(self, beliefs: Gaussians, gnss: Batch | None, sensor: Any) -> Gaussians:
        """Information-form update with this step's own fixes (tracking): Λ += Hᵀ R⁻¹ H, η += Hᵀ R⁻¹ z̃.

        `gnss`: rows of a `GnssPosition` `sensor` (kind "gnss" or "anchor"); rows of vehicles
        not present are ignored.
        """
        ids = self.vehicles.ids
        if gnss is None or len(gnss) == 0 or sensor is None or ids.size == 0:
            return beliefs
        pos = np.minimum(np.searchsorted(ids, gnss.subject), ids.size - 1)   # ids are sorted
        rows = np.flatnonzero(ids[pos] == gnss.subject)
        if rows.size == 0:
            return beliefs
        target = pos[rows]
        dx = beliefs.mean.shape[1]
        H = sensor.observation_matrix(dx)
        z = gnss.z[rows].copy()
        # heading components of the fix (none where the beliefs do not hold the heading)
        angular = np.flatnonzero(H[:, self._heading] != 0) if self._heading < dx else np.zeros(0, np.int64)
        prediction = beliefs.mean[target] @ H.T
        z[:, angular] = prediction[:, angular] + wrap_angle(z[:, angular] - prediction[:, angular])
        Rinv_H = np.linalg.solve(gnss.cov[rows], np.broadcast_to(H, (rows.size, *H.shape)))
        Rinv_z = np.linalg.solve(gnss.cov[rows], z[..., None])[..., 0]
        Lam, eta = to_information(beliefs)
        n = ids.size
        Lam = symmetrize(Lam + _scatter(target, H.T @ Rinv_H, n))
        eta = eta + _scatter(target, Rinv_z @ H, n)
        return from_information(Lam, eta)


@register_estimator
class PriorLBP(PLBP):
    """The baseline: the same Gaussian BP, linearized once w.r.t. the priors.

    Uses what `plbp` uses; knowingly inconsistent for the same reason.
    """

    name: ClassVar[str] = "prior-lbp"
    bound: ClassVar[str | None] = None
    summary: ClassVar[str] = "AoA cooperative position + heading, Gaussian BP linearized at the priors"
    Params: ClassVar[type[Params]] = PriorLBPParams
    posterior: ClassVar[bool] = False


# the beliefs a link factor's information lands in: its two ends
LINK_ENDS = 2


def tempered(prior: Gaussians, posterior: Gaussians, ends: int = LINK_ENDS) -> Gaussians:
    """The prior times the step's link information to the power 1/`ends` (information form).

    Λ = Λ₀ + (Λ⁺ − Λ₀) / ends,  η = η₀ + (η⁺ − η₀) / ends,

    with (Λ₀, η₀) the step's prior and (Λ⁺, η⁺) its posterior. The information of a link
    lands in the beliefs of both its ends; when a step's posteriors are carried on as the
    next priors and the two vehicles are linked again, Gaussian BP adds one end's carried
    belief to the other's through the new link, so a fully carried link is counted twice.
    Carrying 1/ends of it at each end counts it once (a fractional / power-EP weight of
    the link factor: Wiegerinck & Heskes 2003; Minka 2004). Vehicles in no link keep their
    prior. Headings are not wrapped here.
    """
    Lam0, eta0 = to_information(prior)
    Lam1, eta1 = to_information(posterior)
    return from_information(symmetrize(Lam0 + (Lam1 - Lam0) / ends), eta0 + (eta1 - eta0) / ends)


def _scatter(index: IntArray, values: FloatArray, n: int) -> FloatArray:
    """Σ of `values` (F, ...) into n slots by `index` (F,)."""
    out = np.zeros((n, *values.shape[1:]))
    np.add.at(out, index, values)
    return out
