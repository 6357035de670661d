"""The vehicle side of `rsu-bp` with potential features: messages μ and posterior particles.

`VehicleMessages` holds the step's messages μ_{k,s} from the features to the vehicles
(Fröhle eq. (23) with existence, `rsu_bp.tracking` step 6) so that they can be evaluated
at any particles. `posterior_samples` draws the particles of b_s = φ_s χ_s Π_k μ_{k,s}
(26) by defensive importance sampling (Hesterberg, "Weighted average importance sampling
and defensive mixture distributions", Technometrics 1995): a mixture of a Gaussian close
to the posterior, the single-association hypotheses, and the own track, weighted by
target over mixture density.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from cooploc.gaussian import Gaussians, from_information, symmetrize
from cooploc.particles import Particles, effective_sample_size, normalize_log_weights, weighted_moments
from cooploc.types import FloatArray, IntArray, StateSet

__all__ = ["VehicleMessages", "draw", "group_log_sum", "log_normal_rows", "posterior_samples"]

_LOG_2PI = float(np.log(2.0 * np.pi))

def _inverse_cholesky(cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """L⁻¹ (…, d, d) with L Lᵀ = cov, and log det cov (…,)."""
    L = np.linalg.cholesky(cov)
    eye = np.broadcast_to(np.eye(cov.shape[-1]), cov.shape)
    return np.linalg.solve(L, eye), 2.0 * np.log(np.diagonal(L, axis1=-2, axis2=-1)).sum(-1)


def _log_normal(residual: FloatArray, inv_chol: FloatArray, log_det: FloatArray) -> FloatArray:
    """log N(r; 0, C) for residuals (P, N, d), one covariance per pair (P): L⁻¹ (P, d, d)."""
    white = residual @ np.swapaxes(inv_chol, 1, 2)
    d = residual.shape[-1]
    return -0.5 * (d * _LOG_2PI + log_det[:, None] + np.einsum("pnd,pnd->pn", white, white))


def log_normal_rows(residual: FloatArray, cov: FloatArray) -> FloatArray:
    """log N(r; 0, C_p) for residuals (P, N, d) and one covariance per row (P, d, d)."""
    return _log_normal(residual, *_inverse_cholesky(cov))


def log_gauss_groups(offset: FloatArray, cov: FloatArray, log_coef: FloatArray, sample_of: IntArray,
                     group: IntArray, n_groups: int, samples: FloatArray, H: FloatArray) -> FloatArray:
    """log Σ_{p ∈ g} exp(c_p) N(a_p + H x_l; 0, C_p) for every group g and particle l, (G, N).

    Pair p: residual offset a_p (P, d), covariance C_p (P, d, d), log coefficient c_p,
    particle set `sample_of[p]` of `samples` (A, N, dx), group `group[p]` (−inf rows
    for groups without pairs). One compiled pass (`rsu_bp._kernels`), nothing of size
    pairs × particles stored.
    """
    out = np.full((n_groups, samples.shape[1]), -np.inf)
    if not offset.shape[0]:
        return out
    from cooploc.estimators.rsu_bp._kernels import group_log_gauss
    order = np.argsort(group, kind="stable")
    inv_chol, log_det = _inverse_cholesky(cov[order])
    d = offset.shape[1]
    coef = log_coef[order] - 0.5 * (d * _LOG_2PI + log_det)
    counts = np.bincount(group, minlength=n_groups)
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    group_log_gauss(np.ascontiguousarray(offset[order]), np.ascontiguousarray(inv_chol), coef,
                    sample_of[order].astype(np.int64), starts, np.ascontiguousarray(samples),
                    np.ascontiguousarray(H, dtype=float), out)
    return out


def group_log_sum(values: FloatArray, group: IntArray, n_groups: int) -> FloatArray:
    """log Σ exp over rows of the same group (rows sorted by group), (n_groups, …); −inf if none."""
    out = np.full((n_groups, *values.shape[1:]), -np.inf)
    if not values.shape[0]:
        return out
    starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
    top = np.maximum.reduceat(values, starts, axis=0)
    safe = np.where(np.isfinite(top), top, 0.0)
    counts = np.diff(np.r_[starts, values.shape[0]])
    with np.errstate(divide="ignore"):
        out[group[starts]] = safe + np.log(np.add.reduceat(np.exp(values - np.repeat(safe, counts, axis=0)),
                                                           starts, axis=0))
    return out


@dataclass
class VehicleMessages:
    """The messages μ_{k,s} of one step (step 6), to evaluate at any vehicle particles.

    Per gated row–feature pair p: the vehicle s_p, its (s, k) group, the residual offset
    a_p = z − H f̃ (so the residual at x is a_p + H x), covariance W + H P̃ Hᵀ and log
    coefficient log(r⁻ P_D ν); per group the miss term log(1 − r⁻ P_D p_{k,s}).
    """

    n_vehicles: int
    Hx: FloatArray
    vehicle: IntArray
    group: IntArray
    group_vehicle: IntArray
    offset: FloatArray
    cov: FloatArray
    log_coef: FloatArray
    log_miss: FloatArray

    def on(self, index: IntArray, n_vehicles: int) -> VehicleMessages:
        """The same messages with vehicle s renumbered index[s] among n_vehicles."""
        return dataclasses.replace(self, n_vehicles=n_vehicles, vehicle=index[self.vehicle],
                                   group_vehicle=index[self.group_vehicle])

    def log_mu(self, samples: FloatArray) -> FloatArray:
        """Σ_k log μ_{k,s}(x_l) (S, N), each message scaled to a maximum of 1."""
        S, N = samples.shape[0], samples.shape[1]
        out = np.zeros((S, N))
        if not self.vehicle.size:
            return out
        log_msg = log_gauss_groups(self.offset, self.cov, self.log_coef, self.vehicle, self.group,
                                   self.log_miss.size, samples, self.Hx)
        log_msg = np.logaddexp(self.log_miss[:, None], log_msg)
        log_msg -= log_msg.max(axis=1, keepdims=True)
        # Σ over each vehicle's groups: one sort and a segment sum, not np.add.at on (G, N)
        order = np.argsort(self.group_vehicle, kind="stable")
        owner = self.group_vehicle[order]
        starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
        out[owner[starts]] = np.add.reduceat(log_msg[order], starts, axis=0)
        return out

    def hypotheses(self, mean: FloatArray, cov: FloatArray) -> Gaussians:
        """Per pair p, the vehicle's belief updated with "row p came from its feature" alone.

        Each is where the vehicle must be if that association holds; a vehicle with a wide
        belief and several rows is localised by the hypotheses on which the rows agree.
        """
        Hx = self.Hx
        prior_cov = cov[self.vehicle]
        S = self.cov + Hx @ prior_cov @ Hx.T
        gain = np.linalg.solve(S, Hx @ prior_cov).transpose(0, 2, 1)               # P Hᵀ S⁻¹
        innovation = -self.offset - mean[self.vehicle] @ Hx.T                       # H x = −a
        post_mean = mean[self.vehicle] + np.einsum("pij,pj->pi", gain, innovation)
        post_cov = symmetrize(prior_cov - gain @ Hx @ prior_cov)
        return Gaussians(post_mean, post_cov)

    def subset(self, keep: np.ndarray) -> VehicleMessages:
        """The messages to the vehicles `keep` (S,) bool only, renumbered 0, 1, … in order."""
        pairs, groups = keep[self.vehicle], keep[self.group_vehicle]
        v_new, g_new = np.cumsum(keep) - 1, np.cumsum(groups) - 1
        return VehicleMessages(int(keep.sum()), self.Hx, v_new[self.vehicle[pairs]], g_new[self.group[pairs]],
                               v_new[self.group_vehicle[groups]], self.offset[pairs], self.cov[pairs],
                               self.log_coef[pairs], self.log_miss[groups])

    def gaussian(self, mean: FloatArray, cov: FloatArray, at: Gaussians | None = None) -> Gaussians:
        """The vehicles' beliefs times each message's dominant component, in closed form.

        Every row enters as x ≈ −H⁻ a_p (covariance C_p = W + H P̃ Hᵀ) weighted by its
        share of the message under the belief: the weight of component p in the Gaussian
        mixture N(x; x̄, P) μ_{k,s}(x), c_p N(a_p + H x̄; 0, C_p + H P Hᵀ) against the miss
        term (the evidence of each component, exact for one message). A Gaussian close to
        the posterior, from which the particles are drawn (the importance weights then
        correct the rest). The share at the mean alone, N(a_p + H x̄; 0, C_p), vanishes
        for a precise row whenever the belief's mean is a few σ_W off, and the Gaussian
        then ignores the rows.

        `at` (default: the belief itself) is where the shares are evaluated: with `at` a
        first estimate of the posterior, the shares are the E-step and the product the
        M-step of one EM iteration for the mode of the posterior mixture.
        """
        if not self.vehicle.size:
            return Gaussians(mean, cov)
        at = Gaussians(mean, cov) if at is None else at
        Hx = self.Hx
        Cinv = np.linalg.inv(self.cov)
        resid = self.offset + at.mean[self.vehicle] @ Hx.T
        evidence = self.cov + Hx @ at.cov[self.vehicle] @ Hx.T                      # C_p + H P Hᵀ
        log_l = log_normal_rows(resid[:, None, :], evidence)[:, 0]
        terms = self.log_coef + log_l
        total = np.logaddexp(self.log_miss[self.group], group_log_sum(terms, self.group,
                                                                       self.log_miss.size)[self.group])
        share = np.exp(terms - total)
        lam, eta = np.linalg.inv(cov), np.zeros_like(mean)
        eta = np.einsum("sij,sj->si", lam, mean)
        np.add.at(lam, self.vehicle, np.einsum("ji,pjk,kl->pil", Hx, Cinv, Hx) * share[:, None, None])
        np.add.at(eta, self.vehicle, np.einsum("ji,pjk,pk->pi", Hx, Cinv, -self.offset) * share[:, None])
        return from_information(symmetrize(lam), eta)


#: the unknown-feature model draws vehicle particles from its Gaussian proposal widened by this
PROPOSAL_SPREAD = 1.5
#: shares of (that Gaussian, single-association hypotheses, own track) in the proposal
PROPOSAL_SHARES = (0.5, 0.3, 0.2)
#: a vehicle whose importance weights keep an ESS below this share of N_p is drawn again
#: from the proposal re-centred on the first draw's estimate (`posterior_samples`)
REFINE_SHARE = 0.1


def draw(mean: FloatArray, cov: FloatArray, n: int, rng: np.random.Generator) -> FloatArray:
    """(S, n, d) samples of N(mean_s, cov_s) (batched matrix products, no einsum)."""
    z = rng.standard_normal((mean.shape[0], n, mean.shape[1]))
    return mean[:, None] + z @ np.swapaxes(np.linalg.cholesky(cov), 1, 2)


def posterior_samples(own: StateSet, messages: VehicleMessages, n_particles: int, rng: np.random.Generator
                      ) -> tuple[FloatArray, FloatArray]:
    """Particles of b_s = φ_s χ_s Π_k μ_{k,s} by defensive importance sampling.

    Drawn from the own track alone, a 0.3 m posterior inside an 8 m fix keeps a
    handful of particles; drawn from one Gaussian (`VehicleMessages.gaussian`) alone, a
    wrong dominant association is never corrected. The proposal mixes three parts
    (`PROPOSAL_SHARES`; Hesterberg 1995, defensive importance sampling): that
    Gaussian widened by `PROPOSAL_SPREAD`; the single-association hypotheses
    (`VehicleMessages.hypotheses`, equal shares per vehicle); the own track.

    A vehicle entering with a 15 m fix and ten rows, each gated with several features,
    has a posterior of a few decimetres in one of several modes; the Gaussian built at
    the track's mean can sit in another, and the weights then fall on one or two
    particles. Where the ESS stays below `REFINE_SHARE` N_p, the vehicle is drawn
    again from the same mixture with that Gaussian rebuilt at the first draw's
    weighted moments (one EM step towards the mode the draw found; adaptive
    importance sampling, Cappé, Guillin, Marin & Robert, "Population Monte Carlo",
    J. Comput. Graph. Stat. 2004), and those particles replace the first.
    """
    samples, log_w = _defensive_draw(own, messages, n_particles, rng, None)
    again = effective_sample_size(log_w) < REFINE_SHARE * n_particles
    if again.any():
        first = Gaussians(*weighted_moments(Particles(samples[again], log_w[again])))
        part = StateSet(own.ids[again], own.mean[again], own.cov[again])
        samples[again], log_w[again] = _defensive_draw(part, messages.subset(again), n_particles, rng, first)
    return samples, log_w


def _defensive_draw(own: StateSet, messages: VehicleMessages, n_particles: int, rng: np.random.Generator,
                    at: Gaussians | None) -> tuple[FloatArray, FloatArray]:
    """One draw of `posterior_samples`' mixture, its Gaussian part built at `at` (None: the track)."""
    N = n_particles
    S, dx = own.mean.shape
    near = messages.gaussian(own.mean, own.cov, at)
    near = Gaussians(near.mean, PROPOSAL_SPREAD**2 * near.cov)
    hyp = messages.hypotheses(own.mean, own.cov)
    n_hyp = np.bincount(messages.vehicle, minlength=S)
    shares = np.array(PROPOSAL_SHARES)
    counts = np.round(shares * N).astype(int)
    counts[0] = N - counts[1:].sum()
    # part 1: near; part 2: a hypothesis drawn per particle (near where a vehicle has none)
    samples = np.empty((S, N, dx))
    samples[:, :counts[0]] = draw(near.mean, near.cov, counts[0], rng)
    start, stop = counts[0], counts[0] + counts[1]
    first = np.concatenate([[0], np.cumsum(n_hyp)[:-1]])
    order = np.argsort(messages.vehicle, kind="stable")
    offset = (rng.random((S, counts[1])) * n_hyp[:, None]).astype(np.int64)
    pick = order[np.minimum(first[:, None] + offset, max(order.size - 1, 0))] \
        if order.size else np.zeros((S, counts[1]), np.int64)
    has = n_hyp > 0
    z = rng.standard_normal((S, counts[1], dx))
    if messages.vehicle.size:
        L = np.linalg.cholesky(hyp.cov)
        drawn = hyp.mean[pick] + (L[pick] @ z[..., None])[..., 0]
    else:
        drawn = np.zeros((S, counts[1], dx))
    fallback = near.mean[:, None] + z @ np.swapaxes(np.linalg.cholesky(near.cov), 1, 2)
    samples[:, start:stop] = np.where(has[:, None, None], drawn, fallback)
    samples[:, stop:] = draw(own.mean, own.cov, N - stop, rng)
    # the proposal density at every particle
    each, eye = np.arange(S), np.eye(dx)
    log_own = log_gauss_groups(-own.mean, own.cov, np.zeros(S), each, each, S, samples, eye)
    log_near = log_gauss_groups(-near.mean, near.cov, np.zeros(S), each, each, S, samples, eye)
    log_hyp = log_near.copy()
    if messages.vehicle.size:
        summed = log_gauss_groups(-hyp.mean, hyp.cov, np.zeros(len(hyp)), messages.vehicle,
                                  messages.vehicle, S, samples, eye)
        log_hyp = np.where(has[:, None], summed - np.log(np.maximum(n_hyp, 1))[:, None], log_near)
    with np.errstate(divide="ignore"):
        log_q = np.logaddexp(np.logaddexp(np.log(shares[0]) + log_near, np.log(shares[1]) + log_hyp),
                             np.log(shares[2]) + log_own)
    return samples, normalize_log_weights(log_own - log_q + messages.log_mu(samples))[0]

