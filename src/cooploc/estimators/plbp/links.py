"""AoA link factors and Gaussian belief propagation on their linearized model.

Paper: "Cooperative Localization with Angular Measurements and Posterior Linearization"
(`papers/002_dfdb230c2e4252cd.txt`; equations restated in `papers/plbp_model_notes.md`).

Link factors
------------
The AoA rows of one vehicle pair (a, b) form one factor whose measurement vector is
z_ab = [θ_{a←b}, θ_{b←a}] (eqs. 2–5; `sensor` = receiver, `subject` = transmitter). An
end that did not measure (field of view) keeps a zero row with unit variance and no
correlation; once its model row is zeroed too (A = 0, c = 0, done by the
linearization) it is exactly the 1-row model, and every link keeps the same shape.
Two rows of one direction of one pair (not produced by our scenarios) become two links.

Gaussian BP (information form, flooding schedule)
-------------------------------------------------
On the linear model z = A [x_a; x_b] + c + e, e ~ N(0, R + Ω), with A = [A_a, A_b]:

    cavity of x_i for link f:  Λ_i − J_{f→i},  η_i − h_{f→i}
    S = R + Ω + A_j Σ_{j∖i} A_jᵀ
    J_{f→i} = A_iᵀ S⁻¹ A_i,   h_{f→i} = A_iᵀ S⁻¹ (z̃ − c − A_j μ_{j∖i})        (eq. 24)
    Λ_i = Σ_i⁻¹ + Σ_f J_{f→i},   η_i = Σ_i⁻¹ μ_i + Σ_f h_{f→i}                 (eq. 9)

One iteration updates every message, then every belief. Derivation: docs/plbp.md.

Complexity: a BP iteration is O(F dx³) for F links plus an O(F) scatter into the
vehicles, in the numba kernels of `plbp._kernels` (compiled on first use).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cooploc.gaussian import Gaussians, from_information, symmetrize, to_information
from cooploc.types import Batch, FloatArray, IntArray

__all__ = ["LinkBP", "LinkFactors", "gaussian_bp", "link_factors"]


@dataclass(frozen=True, slots=True)
class LinkFactors:
    """AoA link factors between vehicles (by position in the belief arrays).

    Attributes
    ----------
    a, b : (F,) the two vehicles of each link.
    z : (F, 2) [θ_{a←b}, θ_{b←a}] in rad; 0 where not measured.
    measured : (F, 2) which of the two was measured.
    R : (F, 2, 2) noise covariance: diag(σ²) on measured rows, 1 on missing ones.
    """

    a: IntArray
    b: IntArray
    z: FloatArray
    measured: np.ndarray
    R: FloatArray

    def __len__(self) -> int:
        return self.a.size


def link_factors(batch: Batch, ids: IntArray) -> LinkFactors:
    """Group AoA rows into link factors over vehicles `ids` (sorted or not).

    Rows whose receiver or transmitter is not in `ids`, or which measure a vehicle
    itself, are dropped. The two directions of a pair share one factor; a second row of
    the same direction starts another factor.
    """
    order = np.argsort(ids, kind="stable")
    if ids.size == 0 or len(batch) == 0:
        empty = np.zeros(0, np.int64)
        return LinkFactors(empty, empty, np.zeros((0, 2)), np.zeros((0, 2), bool), np.zeros((0, 2, 2)))
    rx = order[np.minimum(np.searchsorted(ids, batch.sensor, sorter=order), ids.size - 1)]
    tx = order[np.minimum(np.searchsorted(ids, batch.subject, sorter=order), ids.size - 1)]
    keep = (ids[rx] == batch.sensor) & (ids[tx] == batch.subject) & (rx != tx)
    rx, tx = rx[keep], tx[keep]
    z_rows, var_rows = batch.z[keep, 0], batch.cov[keep, 0, 0]
    lo, hi = np.minimum(rx, tx), np.maximum(rx, tx)
    comp = (rx != lo).astype(np.int64)               # 0: θ measured at `a` = lo, 1: at `b` = hi
    pair = lo * ids.size + hi
    rows = np.lexsort((comp, pair))                  # group rows by (pair, direction)
    key = pair[rows] * 2 + comp[rows]
    start = np.r_[0, np.flatnonzero(np.diff(key)) + 1]
    rank = np.empty(rows.size, np.int64)             # occurrence of the row within its group
    rank[rows] = np.arange(rows.size) - np.repeat(start, np.diff(np.r_[start, rows.size]))
    factor_key, factor = np.unique(pair * (rows.size + 1) + rank, return_inverse=True)
    F = factor_key.size
    a, b = np.zeros(F, np.int64), np.zeros(F, np.int64)
    a[factor], b[factor] = lo, hi
    z, measured, R = np.zeros((F, 2)), np.zeros((F, 2), bool), np.zeros((F, 2, 2))
    z[factor, comp], measured[factor, comp] = z_rows, True
    R[:, 0, 0] = R[:, 1, 1] = 1.0
    R[factor, comp, comp] = var_rows
    return LinkFactors(a, b, z, measured, R)


class LinkBP:
    """Running quantities of Gaussian BP in information form over link factors.

    Beliefs Λ (n, dx, dx), η (n, dx); messages J_a, h_a (F, dx, dx), (F, dx) into the
    `a` end of every link and J_b, h_b into the `b` end; all messages start uniform.
    """

    def __init__(self, prior: Gaussians, links: LinkFactors) -> None:
        self.links = links
        self.Lam0, self.eta0 = to_information(prior)
        F, d = len(links), prior.mean.shape[1]
        self.Ja, self.ha = np.zeros((F, d, d)), np.zeros((F, d))
        self.Jb, self.hb = np.zeros((F, d, d)), np.zeros((F, d))
        self.Lam, self.eta = self.Lam0.copy(), self.eta0.copy()

    def cavities(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(μ_a, Σ_a, μ_b, Σ_b) of every link's two cavities."""
        from cooploc.estimators.plbp import _kernels

        links = self.links
        mu_a, cov_a = _kernels.cavities(self.Lam, self.eta, links.a, self.Ja, self.ha)
        mu_b, cov_b = _kernels.cavities(self.Lam, self.eta, links.b, self.Jb, self.hb)
        return mu_a, cov_a, mu_b, cov_b

    def iterate(self, A: FloatArray, c: FloatArray, noise: FloatArray, z: FloatArray,
                cavities: tuple[FloatArray, ...] | None = None) -> None:
        """One flooding iteration: every message (eq. 24), then every belief (eq. 9).

        `cavities`: those of the current beliefs, if the caller has them already.
        """
        from cooploc.estimators.plbp import _kernels

        d = self.Lam0.shape[1]
        mu_a, cov_a, mu_b, cov_b = self.cavities() if cavities is None else cavities
        Aa, Ab = A[..., :d], A[..., d:]
        self.Ja, self.ha = _kernels.link_messages(Aa, Ab, mu_b, cov_b, c, noise, z)
        self.Jb, self.hb = _kernels.link_messages(Ab, Aa, mu_a, cov_a, c, noise, z)
        self.Lam, self.eta = _kernels.accumulate(self.Lam0, self.eta0, self.links.a, self.links.b,
                                                 self.Ja, self.ha, self.Jb, self.hb)

    def beliefs(self) -> Gaussians:
        """The current beliefs in moment form."""
        return from_information(symmetrize(self.Lam), self.eta)


def gaussian_bp(prior: Gaussians, links: LinkFactors, A: FloatArray, c: FloatArray,
                noise: FloatArray, iterations: int) -> Gaussians:
    """Gaussian BP on the linear model z = A [x_a; x_b] + c + e, e ~ N(0, noise), per link.

    prior : n Gaussians; A (F, dz, 2dx), c (F, dz), noise (F, dz, dz), measurements `links.z`.
    Exact marginals on a tree after as many iterations as its diameter.
    """
    bp = LinkBP(prior, links)
    for _ in range(iterations):
        bp.iterate(A, c, noise, links.z)
    return bp.beliefs()

