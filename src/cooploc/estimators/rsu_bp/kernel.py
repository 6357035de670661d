"""The pair kernel of `rsu-bp` with known features and its weighted sums (Fröhle 2018 (14), (21), (23)).

For every block b — V2F row m of vehicle s against feature k — and every pair of a
feature particle j and a vehicle particle l,

    G[b, j, l] = N(z_b; a_kj − c_sl, W_b),   a = H f (feature), c = H x (vehicle),

and the BP messages need its weighted sums over l (β (14), γ (21)) and over j (μ (23)),
as logs. Two ways to compute them, the same numbers up to rounding:

- **Separable form** (`SeparableKernel`; used when every vehicle's rows share one noise
  covariance W_s, as in the paper's model). Whitened with W_s = L Lᵀ about reference
  points ā_k, c̄_s (the particle means): A_j = L⁻¹(a_kj − ā_k), C_l = L⁻¹(c_sl − c̄_s),
  ζ_b = L⁻¹(z_b − ā_k + c̄_s), so the whitened residual is ζ_b − A_j + C_l and

      log G[b, j, l] = log n_s + α_bj + γ_bl + x_jl,
      α_bj = −½‖ζ_b − A_j‖²,  γ_bl = −½‖C_l‖² − ζ_b·C_l,  x_jl = A_j·C_l,

  where n_s is the Gaussian's normaliser. Only x depends on both particles, and not on
  the row: E = exp(x − max_l x) is computed once per (vehicle, feature) — N_p²
  exponentials instead of M N_p², with M the vehicle's rows (x − max_l x in float64,
  rounded to float32, then `cooploc._expf.exp_inplace`: float32, vectorized) —
  and the sums over either index are products of E with weights that carry α, γ and
  the message weights in the log domain, each scaled by its largest entry:

      log Σ_l w_bl G[b, j, l] = log n_s + α_bj + r_j + h_b + log Σ_l E_jl e^{log w_bl + γ_bl − h_b},
      log Σ_j w_bj G[b, j, l] = log n_s + γ_bl + H_b + log Σ_j e^{log w_bj + α_bj + r_j − H_b} E_jl,

  with r_j = max_l x_jl and h_b, H_b the largest exponents in the sums, accumulated in
  float64 (`separable_rows` — which fills E and gives β's sums while a row of E is in
  cache — and `separable_columns`). Every factor is ≤ 1 and every term positive, so a
  sum carries only the float32 rounding of E, unless it falls below `TINY`: then terms
  that underflowed in E (beliefs very broad against a precise W) could matter, and the
  block is summed again by the direct float64 kernel (`particles.pair_kernel_log_sum`).
  Cost per step: O(S K N_p² (d + M)) — one exponential per particle pair of each
  (vehicle, feature), M multiply–adds per pair for each sum — and S K N_p² float32 stored.

- **Direct form** (rows with different covariances): `particles.pair_kernel`, one
  float32 exponential per pair of every block, stored (B N_p² float32), and the sums by
  one float64 pass over the stored values (`PairKernel.log_sum_over_second`, `_first`).

The separable form's compiled loops are in `rsu_bp._pair_sums`, the stored kernel's
in `cooploc._particle_kernels` (numba, imported on first use).

Both round the kernel to float32, the direct form after computing the exponent
−½‖u + v‖² itself in float32 (an absolute error of ~10⁻⁵ at q ~ 10²), the separable
one after computing x − max x in float64: its sums are within ~10⁻⁶ of the dense
float64 definition in the log, the direct form's within ~10⁻⁵ near the particles and
coarser far from them (tests/test_rsu_bp_kernel.py checks both).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.particles import pair_kernel_log_sum
from cooploc.types import FloatArray, IntArray

__all__ = ["TINY", "SeparableKernel"]

#: a scaled sum below this may hold terms that underflowed or lost precision in float32
#: (each below 1.5e-45): its block is summed directly instead
TINY = 1e-30


@dataclass(frozen=True, slots=True)
class SeparableKernel:
    """G of blocks b = (row, feature) grouped by (vehicle, feature), in the separable form.

    Attributes
    ----------
    blocks : (G, M) block index of each group's rows (padded); mask (G, M) the real ones.
    A : (G, N_j, d), C (G, d, N_l): the whitened particles of each group.
    E : (G, N_j, N_l) float32 exp(x − r) of each group; r (G, N_j) its row maxima.
    alpha : (B, N_j) α_bj + log n; gamma (B, N_l) γ_bl; group (B,) the group of each block.
    z, cov, a, c : the inputs, for the blocks summed directly (see module docstring).
    """

    blocks: IntArray
    mask: np.ndarray
    A: FloatArray
    C: FloatArray
    E: np.ndarray
    r: FloatArray
    alpha: FloatArray
    gamma: FloatArray
    group: IntArray
    z: FloatArray
    cov: FloatArray
    a: FloatArray
    c: FloatArray

    @classmethod
    def build(cls, z: FloatArray, cov: FloatArray, feature: FloatArray, vehicle: FloatArray,
              block_feature: IntArray, block_vehicle: IntArray, blocks: IntArray, mask: np.ndarray,
              weights: FloatArray, buffer: np.ndarray | None = None
              ) -> tuple[SeparableKernel, FloatArray]:
        """The kernel of B blocks and its first sums, log Σ_l w[b, l] G[b, j, l] (B, N_j).

        z (B, d), cov (B, d, d) — the same for all blocks of a vehicle; feature (K, N_j, d)
        = H f, vehicle (S, N_l, d) = H x; block b pairs feature `block_feature[b]` with
        vehicle `block_vehicle[b]`; `blocks`, `mask` (G, M) list the blocks of each
        (vehicle, feature) group, every group at least one; weights (B, N_l) ≥ 0. E is
        written to `buffer` (1-D float32, at least G N_j N_l) if given.
        """
        first = blocks[:, 0]
        gk, gs = block_feature[first], block_vehicle[first]
        L = np.linalg.cholesky(cov[first])                     # (G, d, d): W_s of the group
        a_ref, c_ref = feature.mean(axis=1), vehicle.mean(axis=1)   # ā_k (K, d), c̄_s (S, d)
        A = np.linalg.solve(L, np.swapaxes(feature[gk] - a_ref[gk][:, None], 1, 2))  # (G, d, N_j)
        C = np.linalg.solve(L, np.swapaxes(vehicle[gs] - c_ref[gs][:, None], 1, 2))  # (G, d, N_l)
        group = np.empty(len(z), dtype=np.int64)
        group[blocks[mask]] = np.nonzero(mask)[0]
        zeta = np.linalg.solve(L[group], (z - a_ref[block_feature] + c_ref[block_vehicle])[:, :, None])
        log_norm = (-0.5 * z.shape[1] * np.log(2 * np.pi)
                    - np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1))    # log n_s (G,)
        Ab, Cb = A[group], C[group]                                                 # (B, d, N)
        alpha = log_norm[group][:, None] - 0.5 * ((zeta - Ab) ** 2).sum(axis=1)   # (B, N_j)
        gamma = -((0.5 * Cb + zeta) * Cb).sum(axis=1)                              # (B, N_l)
        shape = (len(blocks), A.shape[2], C.shape[2])
        size = shape[0] * shape[1] * shape[2]
        if buffer is not None and buffer.dtype == np.float32 and buffer.size >= size:
            E = buffer[:size].reshape(shape)
        else:
            E = np.empty(shape, dtype=np.float32)
        kernel = cls(blocks, mask, np.ascontiguousarray(np.swapaxes(A, 1, 2)), np.ascontiguousarray(C), E,
                     np.zeros(shape[:2]), alpha, gamma, group, z, cov,
                     feature[block_feature], vehicle[block_vehicle])
        return kernel, kernel._over_second(weights, compute=True)

    def log_sum_over_second(self, weights: FloatArray) -> FloatArray:
        """log Σ_l w[b, l] G[b, j, l], (B, N_j), for weights (B, N_l) ≥ 0."""
        return self._over_second(weights, compute=False)

    def _over_second(self, weights: FloatArray, compute: bool) -> FloatArray:
        from cooploc.estimators.rsu_bp._pair_sums import separable_rows

        weights = np.asarray(weights, dtype=float)
        with np.errstate(divide="ignore"):
            h = np.log(weights) + self.gamma
        top = h.max(axis=1)
        live = np.isfinite(top)
        top = np.where(live, top, 0.0)
        sums = np.zeros(self.alpha.shape)
        separable_rows(self.A, self.C, self.blocks, self.mask, np.exp(h - top[:, None]), compute,
                       self.E, self.r, sums)
        with np.errstate(divide="ignore"):
            out = self.alpha + self.r[self.group] + top[:, None] + np.log(sums)
        redo = np.flatnonzero(live & (sums < TINY).any(axis=1))
        if redo.size:
            out[redo] = pair_kernel_log_sum(self.z[redo], self.cov[redo], self.a[redo], self.c[redo],
                                            weights[redo])
        return out

    def log_sum_over_first(self, weights: FloatArray) -> FloatArray:
        """log Σ_j w[b, j] G[b, j, l], (B, N_l), for weights (B, N_j) ≥ 0."""
        from cooploc.estimators.rsu_bp._pair_sums import separable_columns

        weights = np.asarray(weights, dtype=float)
        with np.errstate(divide="ignore"):
            h = np.log(weights) + self.alpha + self.r[self.group]
        top = h.max(axis=1)
        live = np.isfinite(top)
        top = np.where(live, top, 0.0)
        sums = np.zeros(self.gamma.shape)
        separable_columns(self.E, self.blocks, self.mask, np.exp(h - top[:, None]), sums)
        with np.errstate(divide="ignore"):
            out = self.gamma + top[:, None] + np.log(sums)
        redo = np.flatnonzero(live & (sums < TINY).any(axis=1))
        if redo.size:
            out[redo] = pair_kernel_log_sum(-self.z[redo], self.cov[redo], self.c[redo], self.a[redo],
                                            weights[redo])
        return out
