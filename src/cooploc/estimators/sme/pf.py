r"""`sme-pf`: the SME particle filter over the joint state of all vehicles (Zhang et al. 2016).

Paper: Zhang, Hinz, Gulati, Clarke & Knoll, GeoInformatica 2016, §3.3 and §4.1
(``papers/001_80a6c560b7fdaa20.txt``): the paper's method, "the particle filter is
utilized to execute the SME filter with the sum of powers format".

Model
-----
Particles (n_particles, N, dx) of the joint state x = [x¹; …; xᴺ] (eq. 1), one weight
per joint particle, each with the prior kernel of the motion model,
p(x_k | x_{k−1}) = N(A x_{k−1}, blockdiag Q) (eq. 16), weighted in log domain by the
Gaussian pseudo-likelihood of eq. (19) evaluated *per particle*,
p(y | x) = N(y; h(x) + b(x), R(x)) with its own bias and covariance
(`PseudoMeasurement.log_likelihood`, numba; noise moments in ``docs/sme.md``).

How the particles are drawn (`proposal`; the paper leaves it open)
------------------------------------------------------------------
- ``"linearized"`` (default): an auxiliary particle filter (Pitt & Shephard 1999) with
  the linearized optimal proposal of the extended/unscented particle filter (Doucet,
  Godsill & Andrieu 2000; van der Merwe et al. 2000), module `proposal`: eq. (19) is
  linearized once per step by statistical linear regression over the predicted cloud;
  parents are drawn by w_j λ_j (λ_j their linearized predictive likelihood), each
  particle from its parent's Kalman posterior, and weighted by p(y | x) / N(y; H x + c, Λ)
  — only the linearization error weighs. When the effective sample size falls below
  `resample_threshold`, the cloud is resampled and moved by `n_moves` independence
  Metropolis–Hastings sweeps with the same proposal. Where the linearization is not
  positive definite, that step falls back to a bootstrap update
  (``info["proposal_fallback"]``).
- ``"bootstrap"``: the paper's kind of particle filter, drawing from the motion model.
  A plain bootstrap update collapses in this 4N-dimensional state, so the likelihood
  enters in powers δ (progressive correction, Oudjane & Musso 2000) chosen by bisection
  so that each stage keeps `target_ess` of the particles (Jasra et al. 2011),
  w ∝ w p(y | x)^δ; after each resampling inside the update `n_moves` random-walk
  Metropolis–Hastings sweeps (Gilks & Berzuini 2001) move the particles with target
  p(x_k | x_{k−1}) p(y | x_k)^β, proposals scaled 2.38²/d times the narrower of the
  cloud's and the transition's covariance (Roberts & Rosenthal 2001).

Why the default is ``"linearized"``: with the topology switched off, SME sees what the
associated GPS rows give wherever the vehicles are apart, so its particle filter should
match `kf-known-da` there — the bootstrap filter does not (its draws from the motion
model mostly miss the 2N-dimensional likelihood), the linearized one does within Monte
Carlo noise (``tests/test_sme.py``); ``cooploc reproduce zhang2016`` and
``benchmarks/zhang2016.py`` measure both against the particle count.

Rao–Blackwellised (`rao_blackwellised`, linearized proposal)
-----------------------------------------------------------
Eq. (19) depends on the positions only, and Zhang's GPS rows are positions: the
velocities enter through the motion model alone. So the particles can sample the 2N
positions only and keep, per particle, the Gaussian p(v_k | p_{0:k}, y_{1:k}) in Kalman
form — the marginalized particle filter of Schön, Gustafsson & Nordlund (IEEE TSP 2005,
their model (18) with no linear part in the measurement), module `marginalized`. Each
step the prior kernel of a particle is the position marginal of its joint prediction,
N(μ_p^i, J_pp) with J = A_{:,v} P A_{:,v}ᵀ + Q; the linearized proposal, the weights and
the moves above run on those 10 dimensions (N = 5) instead of 20; then each particle's
velocities are conditioned on its sampled positions (the motion of the sampled substate
as a measurement of the linear one). A and Q are the same for every particle, so the
velocity covariance P is shared (one per vehicle), and the estimate's covariance is the
spread of the particles plus P. The relabelling permutes the velocity means with the
positions; it is skipped on a step where the vehicles' P differ (a vehicle entered
lately, so blocks are not exchangeable). The bootstrap proposal always samples the
whole state. In the joint mode the pseudo-measurements are of positions in every setup
(rows with velocities enter as their position marginal, `filter_base`), so the split holds
there; the per-radar mode does not use it.

Why it is the default (measured with the Gaussian pseudo-noise, before the exact density
below): paired over the same 10 runs at 8000 particles (about the same
CPU time per step as the full-state filter) it lowers the total error in CV / CT-2 /
CT-4 by 0.028 / 0.021 / 0.029 m, reaches the MHT that has exactly SME's information in
CV and CT-2 (+0.001 / +0.008 m), and in CT-4 moves `sme-pf` from above `kf-known-da` to
below it (−0.011 m at 8000 particles, not significant at 10 runs; −0.021 m, 90 %
interval −0.036 … −0.006, at 16000). Numbers and commands: ``docs/sme.md``, "Where
sme-pf loses".

The pseudo-likelihood (`pseudo_likelihood`)
-------------------------------------------
``"gaussian"`` (default, the paper's: a pseudo-noise covariance R_k in the SME space, §3.3,
whose details the paper takes from its refs. [12, 22]) weighs by eq. (19)'s Gaussian
pseudo-noise N(y; h(x) + b(x), R(x)) with exact moments. ``"exact"`` (ours) weighs by the
exact density of the sums of powers of Gaussian rows: the rows recovered from y by Newton's
identities (§3.2.3), summed over their N! associations, over the map's Jacobian, which
depends on y alone (`PseudoMeasurement.density`, ``docs/sme.md``, "The exact density").
Groups of more than 7 vehicles keep the Gaussian. The proposal is the same linearization
for both.

The default stays the paper's so that `sme-pf` is the method whose claims are checked;
``"exact"`` shows where that method loses. The Gaussian's state-dependent covariance R(x)
carries the map's Jacobian at the *particle*, |det R(x)|^{-1/2} ∝ ∏_{i<j} |c_i − c_j|^{-2} where the map is
linear, a spurious attraction between vehicles that are close (a particle with a pair 2 m
apart outweighs one with it at its true 4 m by e^{1.6}, GPS 0.5 m²); the exact density has
the Jacobian at the measured rows, the same for every particle. In CT-4 (58 runs, seed 0,
8000 particles, paired) the exact density takes `sme-pf` from 1.039 × the MHT with SME's information
(``reproduce/zhang2016_anonymous``) to 1.000 (0.998 … 1.001), and from −0.008 m to
−0.073 m (−0.077 … −0.069) against `kf-known-da`; over the 24 close steps from +0.117 m to
−0.100 m. CV and CT-2 stay at the MHT (1.000, 1.003; 23 and 25 runs); 8000 → 32000
particles change CT-4 by −0.001 m (−0.005 … +0.004). Its effective sample sizes are no
larger than the Gaussian's: what the Gaussian lost was its target, not particles.
Numbers, CV / CT-2 and commands: ``docs/sme.md``, "Where sme-pf loses".

Other choices the paper leaves open
-----------------------------------
- Relabelling. After each update the vehicle blocks of every particle are permuted to
  best match the predicted estimate (exhaustive over the N! permutations for N ≤ 7,
  numba; otherwise skipped); `relabel_iterations` > 1 repeats it against the relabelled
  mean. The likelihood and the (identical per-vehicle) motion model are symmetric, so
  this leaves the symmetrised posterior unchanged, but it keeps particles that swapped
  two crossing vehicles from being averaged into a point between them (the MMOSPA-style
  estimate of Crouse, Willett et al. 2011), and the predicted cloud unimodal for the
  linearization.
- `n_particles`: the default, 8000, was chosen from the ``zhang2016-cv`` curve of
  ``benchmarks/zhang2016.py`` (the numbers are in the benchmark's JSON; the full-state
  filter). Paired over the same runs the full-state filter's total error still falls
  there: 2000 → 8000 particles −0.06 m in CV, −0.12 m in CT-4, and 8000 → 32000 −0.04 m
  in CT-4 (1.90 / 1.78 / 1.74 m). The Rao–Blackwellised filter at 8000 is at the
  full-state filter's 32000 in CT-4 (1.745 m against 1.738 m, 10 runs) and 16000 gain
  it −0.010 m more (−0.022 … +0.002) (all with the Gaussian pseudo-noise). What
  `sme-pf` then still lost against `kf-known-da` in CT-4 was not the particles but the
  Gaussian pseudo-noise (above, "The pseudo-likelihood"; ``docs/sme.md``, "Where sme-pf
  loses").
- Resampling, effective sample size and the moments of the joint cloud come from
  `cooploc.particles` (`systematic_resample`, `effective_sample_size`,
  `marginal_moments`); a floor of 1e-9 on each block's covariance keeps it positive
  definite when the particles collapse.

In traffic (per-radar mode, `filter_base`): a particle cloud over the joint state of a
city (120 and more dimensions) cannot be kept, so the vehicles are per-vehicle Gaussians
and each group's pseudo-measurement (a radar's eq. 18, a GPS group's eq. 17) is applied
by a Gaussian particle filter (Kotecha & Djurić 2003, `_update_group`): `n_particles`
joint draws of the group from the linearized proposal above (one parent, the group's
Gaussian), weighted by the exact pseudo-likelihood over the linearized one, and
moment-matched back to the blocks.

`Estimate.info` adds ``ess`` (after the update, before any resampling), ``resampled``,
``stages`` (likelihood stages this step: tempering stages of the bootstrap proposal, 1
for the linearized one), ``acceptance`` (of the moves) and ``degenerate`` (every
likelihood was zero) to the keys of `filter_base`.

Complexity per step: linearized, O(d³ + d² D) for the linearization (d = N dx,
D = 2N + 1) and O(P d²) to draw, plus one likelihood pass (per particle: the exact density
O(N! N) at most, a few exponentials where vehicles are apart; the Gaussian one's moments O(N⁴)
in complex form, O(N³) per axis, and a 2N × 2N Cholesky) and `n_moves` more when it
resamples; bootstrap, S tempering stages with `n_moves` likelihood passes each. Plus
O(P N! N) for the relabelling.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np

from cooploc.errors import EstimatorError
from cooploc.estimators.sme.filter_base import _SmeFilter, _SmeParams
from cooploc.estimators.sme.proposal import LinearizedProposal, linearized_proposal
from cooploc.estimators.sme.pseudo_measurement import PseudoMeasurement
from cooploc.params import Params, param
from cooploc.particles import effective_sample_size, log_sum_exp, marginal_moments, systematic_resample
from cooploc.registry import register_estimator
from cooploc.types import Estimate, FloatArray, Frame, IntArray, Setup, StateSet

__all__ = ["SmePF", "SmePFParams"]

_MAX_EXHAUSTIVE = 7  # N! permutations up to 5040 for the relabelling


@dataclass(frozen=True)
class SmePFParams(_SmeParams):
    """`sme-pf` parameters.

    n_particles : particles of the joint state (default chosen by measurement: see
        `benchmarks/zhang2016.py` and the report of `cooploc reproduce zhang2016`).
    proposal : "linearized" (default: auxiliary particle filter with the linearized
        optimal proposal) or "bootstrap" (draws from the motion model, tempered; the
        paper's kind of particle filter). See the module docstring.
    linearization_iterations : statistical linear regressions per step of the linearized
        proposal (> 1: relinearize about the posterior, posterior linearization).
    resample_threshold : resample when ESS < threshold · n_particles.
    relabel : align the vehicle blocks of the particles to the predicted estimate.
    relabel_iterations : assignments per relabelling (> 1: against the relabelled mean).
    target_ess : ESS fraction each tempering stage keeps (bootstrap proposal).
    n_moves : Metropolis–Hastings sweeps after each resampling inside the update:
        independence moves with the linearized proposal, random-walk moves with the
        bootstrap one (0: none).
    max_stages : at most this many tempering stages per step (bootstrap proposal).
    rao_blackwellised : sample only the positions and keep each particle's velocities as
        a Gaussian (marginalized particle filter, Schön et al. 2005; module
        `marginalized`); default by measurement (module docstring). The linearized
        proposal only: the bootstrap one always samples the whole state.
    pseudo_likelihood : the density of the GPS pseudo-measurement (eq. 17) the particles
        are weighted by: "exact" — the exact density of the power sums of Gaussian rows
        (for N ≤ 7 vehicles a group; the Gaussian one above); "gaussian" — eq. (19)'s
        Gaussian pseudo-noise with exact moments (default: the paper's R_k; module docstring).
    """

    n_particles: int = param(8000, ge=2)
    proposal: Literal["linearized", "bootstrap"] = "linearized"
    linearization_iterations: int = param(1, ge=1)
    resample_threshold: float = param(0.5, ge=0, le=1)
    relabel: bool = True
    relabel_iterations: int = param(1, ge=1)
    target_ess: float = param(0.5, gt=0, lt=1)
    n_moves: int = param(2, ge=0)
    max_stages: int = param(20, ge=1)
    rao_blackwellised: bool = True
    pseudo_likelihood: Literal["gaussian", "exact"] = "gaussian"


@register_estimator
class SmePF(_SmeFilter):
    """SME particle filter over the joint state of all vehicles (the paper's method).

    Uses: GNSS rows (anonymous, or identified with the identities ignored) and the
    radar's topology; not odometry.
    """

    name: ClassVar[str] = "sme-pf"
    bound: ClassVar[str | None] = "oracle-pose"
    summary: ClassVar[str] = ("symmetric measurement equation particle filter: anonymous GPS "
                              "(sum of powers) + radar topology of unknown pose (Zhang 2016)")
    Params: ClassVar[type[Params]] = SmePFParams

    def __init__(self, setup: Setup, params: SmePFParams, rng: np.random.Generator) -> None:
        super().__init__(setup, params, rng)
        self.params: SmePFParams = params
        self.density = params.pseudo_likelihood
        P = params.n_particles
        self.particles = np.zeros((P, 0, self.dx))
        self.log_w = np.full(P, -np.log(P))
        self._L_Q = np.linalg.cholesky(self.Q + 1e-12 * np.eye(self.dx))
        self._perms: IntArray | None = None
        self._started = False
        # Rao–Blackwellised: the velocity entries of the particles hold E[v | p_{0:k}], and
        # `_lin_cov` (N, nl, nl) the shared Cov[v | p_{0:k}] of each vehicle slot
        self._lin = [i for i in range(self.dx) if i not in self.pos]
        self._lin_cov: FloatArray | None = np.zeros((0, len(self._lin), len(self._lin))) \
            if params.rao_blackwellised and params.proposal == "linearized" else None

    def _moments(self) -> tuple[FloatArray, FloatArray]:
        mean, cov = marginal_moments(self.particles, self.log_w)
        if self._lin_cov is not None:   # the mixture's covariance: spread of the means + Cov[v | p]
            cov[np.ix_(np.arange(cov.shape[0]), self._lin, self._lin)] += self._lin_cov
        return mean, cov + 1e-9 * np.eye(self.dx)  # keep SPD when particles collapse

    def _sync(self, frame: Frame) -> None:
        present = np.sort(frame.vehicles)
        if np.array_equal(present, self.ids):
            return
        keep = np.isin(self.ids, present)
        born = present[~np.isin(present, self.ids)]
        continuing = self.particles[:, keep]
        predicted = continuing[:, :, self.pos].mean(0) if continuing.shape[1] else np.zeros((0, 2))
        parts, ids = [continuing], [self.ids[keep]]
        if born.size:
            mean, cov = self._births(born, frame, predicted)
            L = np.linalg.cholesky(cov)
            white = self.rng.standard_normal((self.params.n_particles, born.size, self.dx))
            parts.append(mean + np.einsum("nij,pnj->pni", L, white))
            ids.append(born)
        ids_all = np.concatenate(ids)
        order = np.argsort(ids_all)
        self.ids = ids_all[order]
        self.particles = np.concatenate(parts, axis=1)[:, order]
        self._perms = None

    def _relabel(self, reference: FloatArray) -> None:
        """Permute each particle's vehicle blocks to best match `reference` (N, dx).

        With `relabel_iterations` > 1 the reference becomes the weighted mean of the
        relabelled cloud and the assignment is repeated (the fixed-point iteration of the
        MMOSPA estimate, Crouse, Willett et al. 2011) until no particle changes.
        """
        from cooploc.estimators.sme._kernels import best_permutations  # numba, on first use

        n = self.ids.size
        if not self.params.relabel or n < 2 or n > _MAX_EXHAUSTIVE:
            return
        if self._lin_cov is not None and not np.allclose(self._lin_cov, self._lin_cov[0], rtol=1e-9, atol=0):
            return   # slots of different Cov[v | p] (a vehicle entered lately): blocks not exchangeable
        if self._perms is None or self._perms.shape[1] != n:
            self._perms = np.array(list(itertools.permutations(range(n))), dtype=np.int64)
        for iteration in range(self.params.relabel_iterations):
            if iteration:
                reference = marginal_moments(self.particles, self.log_w)[0]
            diff = self.particles[:, None, :, :] - reference[None, :, None, :]     # (P, N_ref, N, dx)
            cost = np.ascontiguousarray((diff**2).sum(-1))                           # (P, i, j)
            best = self._perms[best_permutations(cost, self._perms)]                 # (P, N)
            moved = (best != np.arange(n)).any(axis=1)
            if not moved.any():
                break
            rows = np.flatnonzero(moved)
            self.particles[rows] = np.take_along_axis(self.particles[rows], best[rows][..., None], 1)

    def _log_prior(self, x: FloatArray, parents: FloatArray) -> FloatArray:
        """log p(x_k | x_{k−1}) up to a constant, summed over vehicle blocks: (P,)."""
        r = x - parents @ self.F.T
        white = np.linalg.solve(self._L_Q, r.reshape(-1, self.dx).T).T          # L⁻¹ r
        return -0.5 * (white**2).reshape(x.shape[0], -1).sum(-1)

    def _move(self, model: PseudoMeasurement, beta: float, loglik: FloatArray,
              parents: FloatArray) -> tuple[FloatArray, float]:
        """`n_moves` Metropolis–Hastings sweeps targeting p(x | x_{k−1}) p(y | x)^β.

        Random-walk proposals per vehicle block with covariance (2.38²/d) min(Σ̂, Q): the
        spread of the cloud Σ̂ or, when the cloud is wider, of the transition kernel Q
        that each particle's target is narrower than (d the joint dimension;
        Roberts & Rosenthal 2001). Returns the new log-likelihoods and the acceptance rate.
        """
        P, n, dx = self.particles.shape
        _, cov = self._moments()
        # per block, the narrower of Σ̂ and Q in the sense of their traces
        narrow = np.where((np.trace(cov, axis1=1, axis2=2) < np.trace(self.Q))[:, None, None],
                          cov, self.Q)
        L = np.linalg.cholesky(narrow * (2.38**2 / (n * dx)) + 1e-12 * np.eye(dx))   # (N, dx, dx)
        log_prior = self._log_prior(self.particles, parents)
        accepted = 0
        for _ in range(self.params.n_moves):
            proposal = self.particles + np.einsum(
                "nij,pnj->pni", L, self.rng.standard_normal(self.particles.shape))
            ll_new = model.log_likelihood(proposal[:, :, self.pos])
            lp_new = self._log_prior(proposal, parents)
            log_alpha = beta * (ll_new - loglik) + lp_new - log_prior
            accept = np.log(self.rng.random(P)) < np.nan_to_num(log_alpha, nan=-np.inf)
            self.particles[accept] = proposal[accept]
            loglik = np.where(accept, ll_new, loglik)
            log_prior = np.where(accept, lp_new, log_prior)
            accepted += int(accept.sum())
        return loglik, accepted / max(P * self.params.n_moves, 1)

    def _resample(self) -> IntArray:
        """Systematic resampling of the joint particles to equal weights: the parent of each (P,)."""
        idx = systematic_resample(self.log_w, self.rng)[0]   # one belief: row 0 of (1, P)
        self.particles = self.particles[idx]
        self.log_w = np.full(idx.size, -np.log(idx.size))
        return idx

    def _ess(self) -> float:
        return float(effective_sample_size(self.log_w))

    def _next_increment(self, loglik: FloatArray, remaining: float) -> float:
        """Largest δ ≤ remaining with ESS(w · p(y|x)^δ) ≥ target (bisection; Jasra et al. 2011)."""
        target = self.params.target_ess * self.log_w.size

        def ess(delta: float) -> float:
            return float(effective_sample_size(self.log_w + delta * loglik))

        if ess(remaining) >= target:
            return remaining
        low, high = 0.0, remaining
        for _ in range(30):
            mid = 0.5 * (low + high)
            low, high = (mid, high) if ess(mid) >= target else (low, mid)
        return max(low, remaining * 1e-3)

    def _update(self, model: PseudoMeasurement, parents: FloatArray, info: dict[str, Any]) -> None:
        """Tempered update (progressive correction) with resample-move between stages."""
        loglik = model.log_likelihood(self.particles[:, :, self.pos])
        finite = np.isfinite(loglik)
        if not finite.any():
            info["degenerate"] = True
            return
        loglik = np.where(finite, loglik, -1e300)
        beta, stages, rates = 0.0, 0, []
        while beta < 1.0:
            stages += 1
            remaining = 1.0 - beta
            delta = remaining if stages >= self.params.max_stages else self._next_increment(
                loglik, remaining)
            # w ∝ w p(y | x)^δ   (eq. 19 pseudo-likelihood, tempered)
            self.log_w = self.log_w + delta * loglik
            self.log_w -= log_sum_exp(self.log_w, axis=None)
            beta = 1.0 if delta >= remaining else beta + delta
            if beta < 1.0 or self._ess() < self.params.resample_threshold * self.log_w.size:
                idx = self._resample()
                parents, loglik = parents[idx], loglik[idx]
                if self.params.n_moves:
                    loglik, rate = self._move(model, beta, loglik, parents)
                    rates.append(rate)
        info["stages"] = stages
        info["acceptance"] = float(np.mean(rates)) if rates else None

    def _prior_kernel(self, frame: Frame) -> tuple[FloatArray, FloatArray]:
        """Each particle's prior N(μ_i, blockdiag Σ₀) at this step, vehicles in and out applied.

        Returns μ (P, N, dx) and the blocks of Σ₀ (N, dx, dx): A x_{k−1}^i and Q for
        vehicles that continue (eq. 16), the entry belief for vehicles that enter.
        Sets `ids` to the present vehicles.
        """
        present = np.sort(frame.vehicles)
        keep = np.isin(self.ids, present)
        born = present[~np.isin(present, self.ids)]
        mean = [self.particles[:, keep] @ self.F.T]
        cov = [np.repeat(self.Q[None], int(keep.sum()), axis=0)]
        if self._lin_cov is not None:   # J = A_{:,v} Cov[v | p] A_{:,v}ᵀ + Q (module `marginalized`)
            A_v = self.F[:, self._lin]
            cov[0] = cov[0] + A_v @ self._lin_cov[keep] @ A_v.T
        ids = [self.ids[keep]]
        if born.size:
            predicted = mean[0][:, :, self.pos].mean(0) if keep.any() else np.zeros((0, 2))
            b_mean, b_cov = self._births(born, frame, predicted)
            mean.append(np.broadcast_to(b_mean, (self.params.n_particles, *b_mean.shape)))
            cov.append(b_cov)
            ids.append(born)
        ids_all = np.concatenate(ids)
        order = np.argsort(ids_all)
        self.ids = ids_all[order]
        self._perms = None if born.size or not keep.all() else self._perms
        return np.concatenate(mean, axis=1)[:, order], np.concatenate(cov)[order]

    def _step_linearized(self, frame: Frame) -> Estimate:
        """One step with the linearized optimal proposal (module `proposal`).

        Auxiliary particle filter: parents j drawn by w_j λ_j, particles from their
        linearized posteriors, weights p(y | x) / N(y; H x + c, Λ). When the effective
        sample size falls below `resample_threshold`, the cloud is resampled and moved by
        `n_moves` independence Metropolis–Hastings sweeps with the same proposal.
        Rao–Blackwellised, all of this runs on the positions alone, with the prior kernels'
        position marginals, and each particle's velocities are then conditioned on its
        sampled positions (module `marginalized`).
        """
        mu, Sigma0 = self._prior_kernel(frame)
        info: dict[str, Any] = {"n_particles": self.params.n_particles, "stages": 0}
        n = self.ids.size
        if n == 0:
            self.particles = mu
            if self._lin_cov is not None:
                self._lin_cov = np.zeros((0, len(self._lin), len(self._lin)))
            info.update(set_valued=True, skipped=[], ess=float(self.params.n_particles), resampled=False)
            return Estimate(StateSet.empty(self.dx), None, info)
        # predicted per-vehicle moments: the spread of the kernels' means plus Σ₀
        mean, spread = marginal_moments(mu, self.log_w)
        model, pm_info = self._pseudo_measurement(frame, mean, spread + Sigma0)
        info.update(pm_info)
        info["resampled"] = False
        # what is sampled: the whole block, or (Rao–Blackwellised) its positions
        if self._lin_cov is None:
            x_mu, x_cov, x_pos = mu, Sigma0, self.pos
        else:
            from cooploc.estimators.sme.marginalized import motion_kernel

            x_cov, gain, lin_cov = motion_kernel(Sigma0, self.pos, self._lin)
            x_mu, x_pos = np.ascontiguousarray(mu[:, :, self.pos]), list(range(len(self.pos)))
        parents = np.arange(self.params.n_particles)
        if model.y_gnss is None and model.y_radar is None:
            # nothing measured: draw from the prior kernels (the motion model)
            L = np.linalg.cholesky(x_cov)
            self.particles = x_mu + np.einsum("nij,pnj->pni", L, self.rng.standard_normal(x_mu.shape))
        else:
            try:
                proposal = linearized_proposal(x_mu, x_cov, self.log_w, model, x_pos,
                                               self.params.linearization_iterations)
            except np.linalg.LinAlgError:
                # the linearization lost positive definiteness (vehicles on top of each other,
                # float64): this step draws from the motion model and weighs by p(y | x)
                parents = self._fallback_step(x_mu, x_cov, model, info, x_pos)
            else:
                # auxiliary particle filter (Pitt & Shephard 1999): parents by w_j λ_j ...
                parents = systematic_resample(self.log_w + proposal.log_predictive, self.rng)[0]
                centres = proposal.mean[parents]
                self.particles = proposal.draw(centres, self.rng)
                # ... then w ∝ p(y | x) / N(y; H x + c, Λ): p(x | x_j) λ_j / q(x | x_j, y) is
                # exactly the linearized likelihood, so only the linearization error weighs
                log_ratio = self._log_ratio(model, proposal, self.particles, x_pos)
                if not np.isfinite(log_ratio).any():
                    log_ratio = np.zeros_like(log_ratio)
                    info["degenerate"] = True
                self.log_w = log_ratio - log_sum_exp(log_ratio, axis=None)
                info["stages"] = 1
                info["ess"] = self._ess()
                if info["ess"] < self.params.resample_threshold * self.params.n_particles:
                    keep = self._resample()
                    parents = parents[keep]
                    info["resampled"] = True
                    if self.params.n_moves:
                        info["acceptance"] = self._independence_moves(model, proposal, centres[keep],
                                                                      log_ratio[keep], x_pos)
        if self._lin_cov is not None:
            from cooploc.estimators.sme.marginalized import condition_on_positions

            self.particles = condition_on_positions(mu[parents], self.particles, gain, self.pos, self._lin)
            self._lin_cov = lin_cov
        self._relabel(mean)
        info.setdefault("ess", self._ess())
        return self._estimate(info)

    def _fallback_step(self, mu: FloatArray, Sigma0: FloatArray, model: PseudoMeasurement,
                       info: dict[str, Any], pos: list[int]) -> IntArray:
        """A bootstrap update (draw from the prior kernels, weigh by the pseudo-likelihood);
        returns each particle's parent (P,)."""
        L = np.linalg.cholesky(Sigma0)
        self.particles = mu + np.einsum("nij,pnj->pni", L, self.rng.standard_normal(mu.shape))
        loglik = model.log_likelihood(self.particles[:, :, pos])
        self.log_w = self.log_w + np.where(np.isfinite(loglik), loglik, -np.inf)
        if not np.isfinite(self.log_w).any():
            self.log_w = np.zeros_like(self.log_w)
            info["degenerate"] = True
        self.log_w -= log_sum_exp(self.log_w, axis=None)
        info.update(stages=1, proposal_fallback=True, ess=self._ess())
        parents = np.arange(self.log_w.size)
        if info["ess"] < self.params.resample_threshold * self.params.n_particles:
            parents = self._resample()
            info["resampled"] = True
        return parents

    def _log_ratio(self, model: PseudoMeasurement, proposal: LinearizedProposal, x: FloatArray,
                   pos: list[int]) -> FloatArray:
        """log p(y | x) − log N(y; H x + c, Λ): the second-stage weight of particles x (P,)."""
        loglik = model.log_likelihood(x[:, :, pos])
        return np.where(np.isfinite(loglik), loglik, -np.inf) - proposal.linearized_log_likelihood(x)

    def _independence_moves(self, model: PseudoMeasurement, proposal: LinearizedProposal,
                            centres: FloatArray, log_ratio: FloatArray, pos: list[int]) -> float:
        """`n_moves` independence Metropolis–Hastings sweeps of the resampled particles.

        Target p(x | x_j) p(y | x) for each particle's parent j, proposal N(μ_j^+, Σ^+):
        the acceptance ratio reduces to the ratio of the second-stage weights. Returns
        the acceptance rate.
        """
        accepted = 0
        for _ in range(self.params.n_moves):
            candidate = proposal.draw(centres, self.rng)
            candidate_ratio = self._log_ratio(model, proposal, candidate, pos)
            log_alpha = np.nan_to_num(candidate_ratio - log_ratio, nan=-np.inf)
            accept = np.log(self.rng.random(log_alpha.size)) < log_alpha
            self.particles[accept] = candidate[accept]
            log_ratio = np.where(accept, candidate_ratio, log_ratio)
            accepted += int(accept.sum())
        return accepted / (self.params.n_moves * log_ratio.size)

    def _update_group(self, mean: FloatArray, cov: FloatArray, model: PseudoMeasurement
                      ) -> tuple[FloatArray, FloatArray]:
        """Per-radar mode: one group's independent Gaussian blocks updated by importance
        sampling (a Gaussian particle filter, Kotecha & Djurić 2003): `n_particles` joint
        draws of the group from the linearized proposal, weighted by the exact
        pseudo-likelihood over the linearized one, moment-matched back to the blocks."""
        P = self.params.n_particles
        prior = np.broadcast_to(mean, (P, *mean.shape))
        try:
            proposal = linearized_proposal(prior, cov, np.zeros(P), model, self.pos,
                                           self.params.linearization_iterations)
            x = proposal.draw(proposal.mean, self.rng)
            log_w = self._log_ratio(model, proposal, x, self.pos)
        except np.linalg.LinAlgError:
            # no positive definite linearization: draw from the prior, weigh by p(y | x)
            L = np.linalg.cholesky(cov)
            x = prior + np.einsum("nij,pnj->pni", L, self.rng.standard_normal(prior.shape))
            log_w = model.log_likelihood(x[:, :, self.pos])
        if not np.isfinite(log_w).any():   # the caller skips the group and says why
            raise EstimatorError(self.name, f"every one of the {P} particles of a group of {mean.shape[0]} "
                                 "vehicles has a vanishing pseudo-likelihood")
        m, c = marginal_moments(x, np.where(np.isfinite(log_w), log_w, -np.inf))
        return m, c + 1e-9 * np.eye(self.dx)

    def step(self, frame: Frame) -> Estimate:
        if self.per_radar:
            return self._step_per_radar(frame)
        if self.params.proposal == "linearized":
            return self._step_linearized(frame)
        parents = None  # x_{k−1} of each particle, for the move kernel
        if self.ids.size and self._started:
            parents = self.particles
            # predict: x_k = A x_{k−1} + w_k, every vehicle block (eq. 16)
            noise = self.rng.standard_normal(self.particles.shape) @ self._L_Q.T
            self.particles = self.particles @ self.F.T + noise
        self._started = True
        if not np.array_equal(np.sort(frame.vehicles), self.ids):
            self._sync(frame)
            parents = None  # blocks changed: no move kernel this step
        info: dict[str, Any] = {"n_particles": self.params.n_particles}
        n = self.ids.size
        if n == 0:
            info.update(set_valued=True, skipped=[], ess=float(self.params.n_particles),
                        resampled=False, stages=0)
            return Estimate(StateSet.empty(self.dx), None, info)
        mean, cov = self._moments()
        model, pm_info = self._pseudo_measurement(frame, mean, cov)
        info.update(pm_info)
        info["stages"] = 0
        if model.y_gnss is not None or model.y_radar is not None:
            if parents is None:
                # nothing to move against (first step, vehicles entered): one plain update
                self.log_w = self.log_w + model.log_likelihood(self.particles[:, :, self.pos])
                self.log_w = np.where(np.isfinite(self.log_w), self.log_w, -np.inf)
                if not np.isfinite(self.log_w).any():
                    self.log_w = np.zeros_like(self.log_w)
                    info["degenerate"] = True
                self.log_w -= log_sum_exp(self.log_w, axis=None)
                info["stages"] = 1
            else:
                self._update(model, parents, info)
        self._relabel(mean)
        ess = self._ess()
        info["ess"] = ess
        estimate = self._estimate(info)
        info["resampled"] = ess < self.params.resample_threshold * self.params.n_particles
        if info["resampled"]:
            self._resample()
        return estimate
