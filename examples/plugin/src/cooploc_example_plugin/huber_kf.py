"""`huber-kf`: a Kalman filter per vehicle whose GNSS update is robust to outlying fixes.

Model
-----
Each vehicle follows the scenario's motion model (`Setup.vehicle_motion`),
x_k = F x_{k−1} + w_k, w_k ~ N(0, s Q) with a tuning factor s (`process_noise_scale`),
and a GNSS fix is z = H x + e. With Gaussian e ~ N(0, R) the Kalman filter is optimal,
but its correction K ν grows in proportion to the innovation ν, so a single multipath
fix tens of metres off drags the estimate with it. Here each fix is weighted by Huber's
function (Huber 1964, "Robust estimation of a location parameter") of its normalised
innovation distance:

    ν = z − H m⁻,   S = H P⁻ Hᵀ + R,   d = √(νᵀ S⁻¹ ν)
    w = ψ(d) / d = min(1, c / d)            Huber's ψ(d) = min(d, c)

and the Kalman update (Joseph form, `cooploc.gaussian.kf_update`) is made with the
inflated noise R / w. A fix within c of the prediction counts in full (w = 1: exactly
the Kalman filter); one farther off is trusted less the farther it is, so that the
correction it causes stays bounded however far off the fix is, and the covariance grows
to say so. An optional hard gate (`reject_distance`) drops fixes beyond a second,
larger distance altogether.

This is the one-step, innovation-weighted form of the Huber-based Kalman filters: the
weight comes from the prediction, without iterating the weighted regression to its
M-estimate. Where the fixes are Gaussian it costs a little efficiency: for 2-D fixes
d² ~ χ²₂ under the model, so a fix is down-weighted with probability exp(−c²/2), 5 %
for the default c = 2.45.

Choices a reader may want to change (parameters of `HuberKFParams`): c, the gate, and s.
A vehicle with several fixes in one step takes them one after another. Rows without a
subject (anonymous GNSS) are ignored: this filter cannot associate them.

Complexity: O(n dx³) per step for n vehicles, in NumPy calls whose number does not grow
with n (all vehicles are filtered as one batch).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cooploc.estimators.base import VehicleBeliefs
from cooploc.gaussian import Gaussians, kf_predict, kf_update
from cooploc.params import Params, param
from cooploc.types import Batch, Estimate, FloatArray, Frame, Setup, StateSet

__all__ = ["HuberKF", "HuberKFParams", "huber_update"]


@dataclass(frozen=True)
class HuberKFParams(Params):
    """Parameters of `huber-kf`.

    Attributes
    ----------
    threshold : c, the normalised innovation distance beyond which a fix is
        down-weighted (default √χ²₂(0.95) ≈ 2.45: 5 % of model-conform 2-D fixes).
    reject_distance : distance beyond which a fix is dropped altogether, or None to
        keep every fix (it must exceed `threshold`).
    process_noise_scale : s, the factor on the scenario's process noise Q.
    """

    threshold: float = param(2.45, gt=0)
    reject_distance: float | None = param(None, gt=0)
    process_noise_scale: float = param(1.0, gt=0)

    def validate(self) -> None:
        # a gate inside the Huber threshold would turn the filter into a plain gated KF
        self.require(self.reject_distance is None or self.reject_distance > self.threshold,
                     "reject_distance", f"be greater than threshold = {self.threshold:g} (or none)")


def huber_update(prior: Gaussians, z: FloatArray, H: FloatArray, R: FloatArray, threshold: float,
                 reject_distance: float | None = None) -> tuple[Gaussians, FloatArray]:
    """Huber-weighted Kalman update of n beliefs, one fix each (see the module docstring).

    Parameters
    ----------
    prior : n predicted beliefs, mean (n, dx), cov (n, dx, dx).
    z : (n, dz) one fix per belief.
    H : (dz, dx) observation matrix.
    R : (n, dz, dz) nominal noise covariance of each fix.
    threshold : c, Huber's threshold on the normalised innovation distance.
    reject_distance : fixes farther than this are not used (None: all are).

    Returns
    -------
    The updated beliefs and the weight w (n,) given to each fix (0 where rejected).
    """
    nu = z - prior.mean @ H.T                                              # ν = z − H m⁻
    S = H @ prior.cov @ H.T + R                                            # S = H P⁻ Hᵀ + R
    d = np.sqrt(np.einsum("ni,ni->n", nu, np.linalg.solve(S, nu[..., None])[..., 0]))
    w = threshold / np.maximum(d, threshold)                               # min(1, c/d)
    if reject_distance is not None:
        w = np.where(d > reject_distance, 0.0, w)
    used = w > 0
    if not used.any():
        return prior, w
    updated = kf_update(prior.take(used), z[used], H, R[used] / w[used, None, None])  # R / w
    mean, cov = prior.mean.copy(), prior.cov.copy()
    mean[used], cov[used] = updated.mean, updated.cov
    return Gaussians(mean, cov), w


class HuberKF:
    """Kalman filter per vehicle with Huber-weighted GNSS fixes (batched over vehicles)."""

    name: ClassVar[str] = "huber-kf"
    summary: ClassVar[str] = "Kalman filter per vehicle with a Huber-robust GNSS update (example plug-in)"
    Params: ClassVar[type[Params]] = HuberKFParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "motorway-multipath"
    required_sensors: ClassVar[tuple[str, ...]] = ("gnss",)

    def __init__(self, setup: Setup, params: HuberKFParams, rng: np.random.Generator) -> None:
        self.setup = setup
        self.params = params
        self.vehicles = VehicleBeliefs(setup)  # beliefs by id; entering vehicles are born
        self._F = setup.vehicle_motion.transition_matrix(setup.dt)
        self._H = setup.sensors["gnss"].observation_matrix(setup.vehicle_layout.dim)

    def step(self, frame: Frame) -> Estimate:
        born = self.vehicles.sync(frame)
        beliefs = self.vehicles.beliefs
        if (~born).any():  # a vehicle born this step already holds its belief at frame.k
            beliefs = self._predict(beliefs, ~born)
        weights = np.zeros(0)
        gnss = frame.batches.get("gnss")
        if gnss is not None and len(gnss) and len(beliefs):
            beliefs, weights = self._update(beliefs, gnss)
        self.vehicles.beliefs = beliefs
        info = {"gnss_downweighted": int(np.count_nonzero(weights < 1.0))}
        return Estimate(StateSet(self.vehicles.ids, beliefs.mean, beliefs.cov), info=info)

    def _predict(self, beliefs: Gaussians, moving: np.ndarray) -> Gaussians:
        motion, dt = self.setup.vehicle_motion, self.setup.dt
        # some models turn their noise to each vehicle's direction of motion
        Q = motion.noise_covariance(dt, beliefs.mean[moving] if motion.state_dependent_noise else None)
        predicted = kf_predict(beliefs.take(moving), self._F, self.params.process_noise_scale * Q)
        mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
        mean[moving], cov[moving] = predicted.mean, predicted.cov
        return Gaussians(mean, cov)

    def _update(self, beliefs: Gaussians, gnss: Batch) -> tuple[Gaussians, FloatArray]:
        """Every fix about a present vehicle, in rounds of one fix per vehicle."""
        ids = self.vehicles.ids  # sorted
        pos = np.minimum(np.searchsorted(ids, gnss.subject), ids.size - 1)
        rows = np.flatnonzero(ids[pos] == gnss.subject)  # fixes of vehicles present
        target = pos[rows]
        weights = np.ones(rows.size)
        mean, cov = beliefs.mean.copy(), beliefs.cov.copy()
        pending = np.arange(rows.size)
        while pending.size:
            _, first = np.unique(target[pending], return_index=True)
            now = pending[first]
            t, r = target[now], rows[now]
            updated, weights[now] = huber_update(
                Gaussians(mean[t], cov[t]), gnss.z[r], self._H, gnss.cov[r],
                self.params.threshold, self.params.reject_distance)
            mean[t], cov[t] = updated.mean, updated.cov
            pending = np.delete(pending, first)
        return Gaussians(mean, cov), weights
