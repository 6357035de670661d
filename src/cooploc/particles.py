"""Particle beliefs: log-weights, resampling, moments and the pairwise Gaussian kernel.

A belief is a weighted sample (Arulampalam et al. 2002, eq. (4); Fröhle 2018 eq. (27))

    b(x) ≈ Σ_l w_l δ(x − x_l),   Σ_l w_l = 1,

held as `Particles(samples (n, N_p, d), log_weights (n, N_p))`: a batch of n beliefs
(vehicles, features), weights in the log domain and normalised with `log_sum_exp`.
This module is the one home of the particle toolkit of every estimator (`rsu-bp`,
`icp-da-pf`, `sme-pf`):

- `log_sum_exp` — log Σ exp(x), stable, without SciPy's per-call overhead;
- `systematic_resample` — one uniform draw per belief, N_p evenly spaced points on the
  weight CDF (Arulampalam et al. 2002, Alg. 2); O(n N_p) with `searchsorted`;
- `effective_sample_size` — N_eff = (Σ_l w_l)² / Σ_l w_l² (degeneracy diagnostic);
- `weighted_moments` — mean and covariance of each belief (symmetrised, floored);
- `marginal_moments` — mean and covariance of each block of one joint belief whose
  particles carry one weight for all blocks (the joint vehicle state of `sme-pf`);
- `pair_kernel` / `pair_kernel_log_sum` — the hot loop of nonparametric BP with relative
  measurements (Fröhle eqs. (14), (21), (23)): for every block b (a sensor–feature–
  measurement triple) and every pair of particles (j, l)

      G[b, j, l] = N(z_b; a_{b,j} − c_{b,l}, W_b),

  with a = H f (feature particles), c = H x (vehicle particles). `pair_kernel`
  materialises G once as a `PairKernel` — float32 values with a float64 log-scale per
  row (each row divided by its largest entry, so nothing that matters underflows) —
  and β, γ, μ reuse it as matrix–vector products returning logs;
  `pair_kernel_log_sum` returns log Σ_l w_{b,l} G[b, j, l] (B, N_j) in float64 without
  storing G (for when the pairs do not fit in memory). Both whiten with the Cholesky
  factor W = L Lᵀ (u = L⁻¹(z − a), v = L⁻¹ c, so the exponent is −½‖u + v‖²) and run a
  numba `prange` loop over (b, j) whose inner loops over l are contiguous
  (`cooploc._particle_kernels`, compiled on first use). `pair_kernel_numpy` is the
  plain float64 broadcast they are checked and timed against: `benchmarks/rsu_bp.py`
  measures all three in one run (pair evaluations per second).

Complexity: O(B N_j N_l d) for the kernel; O(n N_p) for everything else.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from cooploc.errors import InvalidInputError
from cooploc.types import FloatArray, IntArray

__all__ = [
    "PairKernel",
    "Particles",
    "effective_sample_size",
    "log_sum_exp",
    "marginal_moments",
    "normalize_log_weights",
    "pair_kernel",
    "pair_kernel_log_sum",
    "pair_kernel_numpy",
    "propagate_linear",
    "resample",
    "sample_gaussians",
    "systematic_resample",
    "weighted_moments",
]

_LOG_2PI = np.log(2.0 * np.pi)


@dataclass(frozen=True, slots=True)
class Particles:
    """A batch of n particle beliefs.

    Attributes
    ----------
    samples : (n, N_p, d) support points.
    log_weights : (n, N_p) normalised log-weights (logsumexp over axis 1 is 0).
    """

    samples: FloatArray
    log_weights: FloatArray

    def __post_init__(self) -> None:
        samples = np.asarray(self.samples, dtype=float)
        lw = np.asarray(self.log_weights, dtype=float)
        if samples.ndim != 3 or lw.shape != samples.shape[:2]:
            raise InvalidInputError(
                f"Particles need samples (n, N_p, d) and log_weights (n, N_p), got "
                f"{samples.shape} and {lw.shape}")
        object.__setattr__(self, "samples", samples)
        object.__setattr__(self, "log_weights", lw)

    def __len__(self) -> int:
        return self.samples.shape[0]

    @property
    def n_particles(self) -> int:
        return self.samples.shape[1]

    @property
    def weights(self) -> FloatArray:
        """(n, N_p) normalised linear weights."""
        return np.exp(self.log_weights)

    def take(self, rows: npt.ArrayLike) -> Particles:
        rows = np.asarray(rows)
        return Particles(self.samples[rows], self.log_weights[rows])

    @classmethod
    def uniform(cls, samples: FloatArray) -> Particles:
        n, N, _ = np.shape(samples)
        return cls(samples, np.full((n, N), -np.log(N)) if N else np.zeros((n, 0)))


def log_sum_exp(x: npt.ArrayLike, axis: int | None = -1, keepdims: bool = False) -> FloatArray:
    """log Σ exp(x) along `axis` (every entry for None), stable; −inf where every term is −inf.

    The one log-sum-exp of cooploc's estimators: the same as `scipy.special.logsumexp`
    for real input, without its per-call overhead (≈ 0.1–0.5 ms of array-API dispatch,
    and tempering or association loops call it dozens of times a step). No warning is
    raised for all −inf input. A reduction over every entry returns a float.
    """
    x = np.asarray(x, dtype=float)
    top = x.max(axis=axis, keepdims=True, initial=-np.inf)
    safe = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.exp(x - safe).sum(axis=axis, keepdims=True)) + safe
    if keepdims:
        return out
    return float(out.reshape(())) if axis is None else np.squeeze(out, axis=axis)


def normalize_log_weights(log_weights: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Normalise (…, N_p) log-weights over the last axis: (normalised, log of the total).

    A belief whose weights are all zero (every entry −inf) comes back uniform with a
    total of −inf, so that no NaN can enter.
    """
    lw = np.asarray(log_weights, dtype=float)
    total = log_sum_exp(lw, axis=-1, keepdims=True) if lw.shape[-1] else np.zeros((*lw.shape[:-1], 1))
    dead = ~np.isfinite(total)
    out = np.where(dead, -np.log(max(lw.shape[-1], 1)), lw - np.where(dead, 0.0, total))
    return out, total[..., 0]


def effective_sample_size(log_weights: npt.ArrayLike) -> FloatArray:
    """N_eff = (Σ_l w_l)² / Σ_l w_l² of each belief (…,), from log-weights (…, N_p).

    The weights need not be normalised (tempering evaluates candidate weights before
    normalising them); for normalised ones this is 1 / Σ_l w_l².
    """
    lw = np.asarray(log_weights, dtype=float)
    return np.exp(2.0 * log_sum_exp(lw, axis=-1) - log_sum_exp(2.0 * lw, axis=-1))


def systematic_resample(log_weights: npt.ArrayLike, rng: np.random.Generator,
                        n_out: int | None = None) -> IntArray:
    """Systematic resampling of each belief: indices (n, n_out) into its particles.

    One uniform u ~ U[0, 1) per belief; the points (u + i) / n_out, i = 0..n_out−1, are
    located on the cumulative weights. Unbiased, lowest variance of the standard schemes.
    """
    lw = np.atleast_2d(np.asarray(log_weights, dtype=float))
    n, N = lw.shape
    n_out = N if n_out is None else int(n_out)
    cdf = np.cumsum(np.exp(lw - log_sum_exp(lw, axis=1, keepdims=True)), axis=1)
    cdf[:, -1] = 1.0                                            # guard round-off
    points = (rng.random((n, 1)) + np.arange(n_out)[None, :]) / n_out
    # searchsorted per row, vectorised by offsetting each row into its own interval
    offset = np.arange(n)[:, None] * 2.0
    idx = np.searchsorted((cdf + offset).ravel(), (points + offset).ravel(), side="right")
    return (idx.reshape(n, n_out) - np.arange(n)[:, None] * N).clip(0, N - 1)


def resample(particles: Particles, rng: np.random.Generator, which: npt.ArrayLike | None = None
             ) -> Particles:
    """Systematic resampling of the beliefs selected by `which` (mask; default all)."""
    which = np.ones(len(particles), bool) if which is None else np.asarray(which, bool)
    if not which.any():
        return particles
    samples, lw = particles.samples.copy(), particles.log_weights.copy()
    idx = systematic_resample(lw[which], rng)
    samples[which] = np.take_along_axis(samples[which], idx[:, :, None], axis=1)
    lw[which] = -np.log(particles.n_particles)
    return Particles(samples, lw)


def shrinkage_move(particles: Particles, rng: np.random.Generator, which: npt.ArrayLike | None = None
                   ) -> Particles:
    """Liu–West kernel move of resampled beliefs: x ← a x + (1 − a) x̄ + N(0, h² Σ).

    After resampling, a belief that collapsed onto a few particles keeps only copies of
    them, and the copies spread again only through process noise — slowly in the
    components that no measurement informs (e.g. velocity). Sampling from a Gaussian
    kernel density of the particles restores diversity; shrinking towards the mean with
    a = √(1 − h²) makes the new particles keep the weighted mean x̄ and covariance Σ of
    the old ones exactly, so the move adds no spread (Liu & West 2001, "Combined
    parameter and state estimation in simulation-based filtering", §3.3). h is
    Silverman's bandwidth for N particles in d dimensions, (4 / (N (d + 2)))^(1/(d+4)).
    `which` (mask; default all) selects the beliefs to move.
    """
    which = np.ones(len(particles), bool) if which is None else np.asarray(which, bool)
    if not which.any():
        return particles
    n, d = particles.n_particles, particles.samples.shape[2]
    h2 = (4.0 / (n * (d + 2))) ** (2.0 / (d + 4))
    a = np.sqrt(1.0 - h2)
    selected = Particles(particles.samples[which], particles.log_weights[which])
    mean, cov = weighted_moments(selected)
    noise = rng.standard_normal(selected.samples.shape) @ np.linalg.cholesky(h2 * cov).transpose(0, 2, 1)
    samples = particles.samples.copy()
    samples[which] = a * selected.samples + (1.0 - a) * mean[:, None, :] + noise
    return Particles(samples, particles.log_weights)


def weighted_moments(particles: Particles, min_variance: float = 1e-12) -> tuple[FloatArray, FloatArray]:
    """Weighted mean (n, d) and covariance (n, d, d) of each belief.

    The covariance is symmetrised and gets `min_variance` plus 1e-9 of its mean variance
    added to the diagonal, so that it stays positive definite even when every weight
    sits on one particle (degeneracy).
    """
    w = particles.weights
    x = particles.samples
    # matrix products: 4–5× faster than the equivalent einsum on (n, 600, 4) particle sets
    mean = (w[:, None, :] @ x)[:, 0, :]
    centred = x - mean[:, None, :]
    cov = (centred * w[:, :, None]).transpose(0, 2, 1) @ centred
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))
    d = x.shape[2]
    floor = min_variance + 1e-9 * np.trace(cov, axis1=1, axis2=2) / max(d, 1)
    return mean, cov + floor[:, None, None] * np.eye(d)


def marginal_moments(samples: FloatArray, log_weights: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Weighted mean (N, d) and covariance (N, d, d) of each block of one joint belief.

    A joint particle belief over N blocks (e.g. the vehicles of `sme-pf`) holds samples
    (P, N, d) and one log-weight per joint particle (P,) (need not be normalised); every
    block's marginal shares those weights:

        mean_n = Σ_p w_p x_{p,n},   cov_n = Σ_p w_p (x_{p,n} − mean_n)(x_{p,n} − mean_n)ᵀ.

    The covariances are symmetrised but not floored (unlike `weighted_moments`): the
    caller chooses how to keep a collapsed cloud positive definite.
    """
    lw = np.asarray(log_weights, dtype=float)
    w = np.exp(lw - log_sum_exp(lw, axis=None))
    mean = np.einsum("p,pni->ni", w, samples)
    centred = samples - mean
    cov = np.einsum("p,pni,pnj->nij", w, centred, centred)
    return mean, 0.5 * (cov + np.swapaxes(cov, -1, -2))


def sample_gaussians(mean: FloatArray, cov: FloatArray, n_particles: int,
                     rng: np.random.Generator) -> Particles:
    """Equal-weight samples (n, N_p, d) of the Gaussians N(mean (n, d), cov (n, d, d))."""
    mean, cov = np.asarray(mean, float), np.asarray(cov, float)
    n, d = mean.shape
    L = _cholesky(cov)
    noise = rng.standard_normal((n, n_particles, d))
    return Particles.uniform(mean[:, None, :] + np.einsum("nde,nle->nld", L, noise))


def propagate_linear(particles: Particles, F: FloatArray, Q: FloatArray,
                     rng: np.random.Generator) -> Particles:
    """x_l ← F x_l + w_l, w_l ~ N(0, Q): the prediction (10)–(11) by sampling.

    Q is (d, d) or per belief (n, d, d); weights are kept.
    """
    x = particles.samples
    n, N, d = x.shape
    Q = np.broadcast_to(np.asarray(Q, float), (n, d, d))
    L = _cholesky(Q)
    noise = rng.standard_normal((n, N, d)) @ L.transpose(0, 2, 1)        # L ε per particle
    return Particles(x @ np.asarray(F).T + noise, particles.log_weights)


def _cholesky(cov: FloatArray) -> FloatArray:
    """Lower factor of each PSD matrix; a zero matrix (no noise) gives a zero factor."""
    d = cov.shape[-1]
    scale = np.maximum(np.abs(cov).max(axis=(-2, -1), initial=0.0), 1e-300)
    try:
        return np.linalg.cholesky(cov + (1e-12 * scale)[..., None, None] * np.eye(d))
    except np.linalg.LinAlgError:
        raise InvalidInputError(f"covariance is not positive semi-definite: {cov}") from None


# ----------------------------------------------------------------------------
# the pair kernel
# ----------------------------------------------------------------------------


def _whiten(z: FloatArray, cov: FloatArray, a: FloatArray, c: FloatArray
            ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """u = L⁻¹(z − a) (B, N_j, d), vᵀ = L⁻¹ cᵀ (B, d, N_l), log normaliser (B,)."""
    z, cov = np.asarray(z, float), np.asarray(cov, float)
    a, c = np.asarray(a, float), np.asarray(c, float)
    B, dz = z.shape
    if cov.shape != (B, dz, dz) or a.ndim != 3 or c.ndim != 3 or a.shape[::2] != (B, dz) or (
            c.shape[::2] != (B, dz)):
        raise InvalidInputError(
            f"pair kernel needs z (B, d), cov (B, d, d), a (B, N_j, d), c (B, N_l, d); got "
            f"{z.shape}, {cov.shape}, {a.shape}, {c.shape}")
    L = np.linalg.cholesky(cov)
    # Only a − c matters: subtract one particle of c (per block) from both sets, in float64,
    # so that u and v are of the size of the spread and the pair distances, not of the
    # absolute position — UTM/ECEF coordinates (10⁵…10⁷ m) would otherwise lose their
    # metres in the float32 kernel and in ‖u + v‖² (cancellation of two huge numbers).
    if c.shape[1]:
        a, c = a - c[:, :1], c - c[:, :1]
    # u = L⁻¹(z − a), v = L⁻¹ c: one batched solve each ((B, d, d) against (B, d, N))
    u = np.ascontiguousarray(np.linalg.solve(L, np.swapaxes(z[:, None, :] - a, 1, 2)).transpose(0, 2, 1))
    vt = np.ascontiguousarray(np.linalg.solve(L, np.swapaxes(c, 1, 2)))          # (B, d, N_l)
    log_norm = -0.5 * dz * _LOG_2PI - np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
    return u, vt, log_norm


@dataclass(frozen=True, slots=True)
class PairKernel:
    """Kernel values of all particle pairs of B blocks, stored once and reused.

    G[b, j, l] = exp(log_scale[b, j]) · values[b, j, l]: `values` (B, N_j, N_l) float32
    in (0, 1] (each row scaled by its largest entry, so float32 loses no range that
    matters), `log_scale` (B, N_j) float64. Sums come back as logs.
    """

    values: npt.NDArray[np.float32]
    log_scale: FloatArray

    def dense(self) -> FloatArray:
        """G (B, N_j, N_l) in float64 (for tests and small problems)."""
        return np.exp(self.log_scale)[:, :, None] * self.values.astype(float)

    def log_sum_over_second(self, weights: FloatArray) -> FloatArray:
        """log Σ_l w[b, l] G[b, j, l], (B, N_j), for weights w (B, N_l) ≥ 0 (float64 sums,
        `_particle_kernels.row_sums`)."""
        from cooploc._particle_kernels import row_sums

        sums = np.empty(self.log_scale.shape)
        row_sums(self.values, np.ascontiguousarray(weights, dtype=float), sums)
        with np.errstate(divide="ignore"):
            return self.log_scale + np.log(sums)

    def log_sum_over_first(self, weights: FloatArray) -> FloatArray:
        """log Σ_j w[b, j] G[b, j, l], (B, N_l), for weights w (B, N_j) ≥ 0: each row's scale
        goes into its weight, relative to the largest, so the float64 sums
        (`_particle_kernels.column_sums`) cannot overflow."""
        from cooploc._particle_kernels import column_sums

        with np.errstate(divide="ignore"):
            lw = np.log(np.asarray(weights, dtype=float)) + self.log_scale
        top = lw.max(axis=1, keepdims=True)
        top = np.where(np.isfinite(top), top, 0.0)
        sums = np.empty((self.values.shape[0], self.values.shape[2]))
        column_sums(self.values, np.exp(lw - top), sums)
        with np.errstate(divide="ignore"):
            return top + np.log(sums)


def pair_kernel(z: FloatArray, cov: FloatArray, a: FloatArray, c: FloatArray,
                buffer: npt.NDArray[np.float32] | None = None) -> PairKernel:
    """G[b, j, l] = N(z_b; a_{b,j} − c_{b,l}, cov_b) for all pairs, as a `PairKernel`.

    Parameters
    ----------
    z : (B, d) measurements; cov : (B, d, d) their noise covariances (SPD).
    a : (B, N_j, d) first particle set mapped to measurement space (e.g. H f_j).
    c : (B, N_l, d) second particle set mapped to measurement space (e.g. H x_l).
    buffer : optional 1-D float32 array of at least B N_j N_l elements that the values
        are written to (the kernel's `values` is a view of it): a filter that builds a
        kernel every step reuses one buffer instead of asking the system for fresh
        zeroed pages of this size each time.
    """
    u, vt, log_norm = _whiten(z, cov, a, c)
    shape = (u.shape[0], u.shape[1], vt.shape[2])
    size = shape[0] * shape[1] * shape[2]
    if buffer is not None and buffer.dtype == np.float32 and buffer.ndim == 1 and buffer.size >= size:
        values = buffer[:size].reshape(shape)
    else:
        values = np.empty(shape, dtype=np.float32)
    shift = np.zeros(u.shape[:2])
    if values.size:
        from cooploc._particle_kernels import kernel_matrix

        kernel_matrix(u.astype(np.float32), vt.astype(np.float32), values, shift)
    return PairKernel(values, log_norm[:, None] + shift)


def pair_kernel_log_sum(z: FloatArray, cov: FloatArray, a: FloatArray, c: FloatArray,
                        weights: FloatArray) -> FloatArray:
    """log Σ_l w_{b,l} N(z_b; a_{b,j} − c_{b,l}, cov_b), (B, N_j), without storing the pairs.

    `weights` (B, N_l) ≥ 0 are linear weights of the c-particles (−inf where they sum to
    0). The sum over j for fixed l is the same call with the roles swapped:
    `pair_kernel_log_sum(-z, cov, c, a, w_a)`.
    """
    u, vt, log_norm = _whiten(z, cov, a, c)
    w = np.ascontiguousarray(np.broadcast_to(np.asarray(weights, float), (vt.shape[0], vt.shape[2])))
    out = np.empty(u.shape[:2])
    if out.size:
        with np.errstate(divide="ignore"):
            from cooploc._particle_kernels import kernel_sum

            kernel_sum(u, vt, log_norm, w, out)
    return out


def pair_kernel_numpy(z: FloatArray, cov: FloatArray, a: FloatArray, c: FloatArray) -> FloatArray:
    """The same G as `pair_kernel` by a plain NumPy broadcast in float64 (benchmark reference)."""
    u, vt, log_norm = _whiten(z, cov, a, c)
    r = u[:, :, None, :] + np.swapaxes(vt, 1, 2)[:, None, :, :]          # (B, N_j, N_l, d)
    return np.exp(log_norm[:, None, None] - 0.5 * (r**2).sum(-1))
