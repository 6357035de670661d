r"""Sparse nonlinear least squares with a banded normal matrix: Levenberg–Marquardt and marginals.

Model
-----
Minimise the cost ½‖e(x)‖² over x (n, d): n variables of d components each, ordered
so that the Gauss–Newton matrix H = JᵀJ of the whitened Jacobian J is banded (a factor
graph whose variables are numbered step by step, each factor joining a few nearby
steps). The problem is given as one callable, so this module knows nothing of graphs:

``linearize(x, jacobian)`` → ``(r, J)``
    ``jacobian=True``: the whitened residual r (m,) and its sparse Jacobian J (m, n d),
    columns ordered as ``x.ravel()``. With a robust loss, r and J are the IRLS-weighted
    √w r and √w J (weights held fixed), whose JᵀJ and Jᵀr are the Gauss–Newton
    Hessian and the gradient of the robust cost.
    ``jacobian=False``: a residual e whose ½‖e‖² is the cost at x, and None. Without a
    robust loss e = r; with one, the cost-equivalent residual of `huber_cost_residual`.

`solve_lm` is Levenberg–Marquardt as GTSAM runs it by default (Dellaert & Kaess,
"Factor Graphs for Robot Perception", 2017, §2.5 — the solver Gulati et al. 2017 use
for their eq. 17): each iteration solves the damped normal equations
(JᵀJ + λI) Δ = −Jᵀr; a step that lowers the cost is kept and λ ÷ 10, otherwise
λ × 10; it stops when the cost falls by less than a relative or absolute tolerance.

Complexity: one banded Cholesky per trial step, O(n d u²) for bandwidth u, instead of
the O((n d)³) of a dense solve. Marginal covariances (the d × d diagonal blocks of
H⁻¹ at the solution) come from the selected inverse of the band (Takahashi's
recursion, `cooploc._least_squares_kernels`, numba), also O(n d u²), never the dense
inverse.

`solve_lm_bordered` adds g *border* unknowns b that any factor may touch (a sensor's
pose seen at every step): JᵀJ is then an arrow — banded plus g dense last rows and
columns. Each trial eliminates the band through the g × g Schur complement, so the
band never fills in: O(n d u² + n d u g) per step; the marginals are the selected
inverse of the band plus a rank-g correction.

Choices: λ is added to the diagonal (λI, GTSAM's default, not Marquardt's λ diag H);
λ is kept in [1e-12, 1e10); the Huber loss is applied by iteratively reweighted least
squares, as GTSAM's ``noiseModel.Robust`` does.

SciPy (sparse matrices, banded Cholesky) and numba are imported on first use.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cooploc.types import FloatArray

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = [
    "BorderedLinearize",
    "LMResult",
    "Linearize",
    "banded_upper",
    "compile_kernels",
    "huber_cost_residual",
    "huber_sqrt_weights",
    "marginal_covariances",
    "selected_inverse",
    "solve_lm",
    "solve_lm_bordered",
    "whitener",
]

#: ``linearize(x, jacobian)`` → (residual, sparse Jacobian or None); see the module docstring
Linearize = Callable[[FloatArray, bool], "tuple[FloatArray, sp.spmatrix | None]"]
#: ``linearize(x, b, jacobian)``: the same with border unknowns b (`solve_lm_bordered`)
BorderedLinearize = Callable[[FloatArray, FloatArray, bool], "tuple[FloatArray, sp.spmatrix | None]"]


@dataclass(frozen=True)
class LMResult:
    """Solution of `solve_lm`.

    Attributes
    ----------
    x : (n, d) the minimiser found.
    cov : (n, d, d) marginal covariances of the variables at x, None if not asked for.
    iterations : LM iterations used.
    cost : ½‖e(x)‖² at x.
    border : (g,) the border unknowns found (`solve_lm_bordered`), else None.
    border_cov : (g, g) their marginal covariance, None if not asked for or no border.
    """

    x: FloatArray
    cov: FloatArray | None
    iterations: int
    cost: float
    border: FloatArray | None = None
    border_cov: FloatArray | None = None


def whitener(cov: FloatArray) -> FloatArray:
    """W (M, d, d) with WᵀW = cov⁻¹ for covariances (M, d, d): W = L⁻¹ for cov = L Lᵀ.

    A Gaussian residual ρ with covariance cov becomes the whitened W ρ, of unit covariance.
    """
    if cov.shape[0] == 0:
        return np.zeros(cov.shape)
    L = np.linalg.cholesky(cov)
    return np.linalg.solve(L, np.broadcast_to(np.eye(cov.shape[-1]), L.shape))


def huber_sqrt_weights(r: FloatArray, k: float) -> FloatArray:
    """√w of the Huber loss for whitened residuals r (IRLS): 1 where |r| ≤ k, √(k/|r|) outside.

    k ≤ 0 means no robust loss (all weights 1).
    """
    if k <= 0:
        return np.ones_like(r)
    a = np.abs(r)
    return np.where(a <= k, 1.0, np.sqrt(k / np.maximum(a, k)))


def huber_cost_residual(r: FloatArray, k: float) -> FloatArray:
    """e with ½e² = ρ(r), the Huber loss (½r² inside |r| ≤ k, k|r| − k²/2 outside); k ≤ 0: r."""
    outside = (k > 0) & (np.abs(r) > k)
    return np.where(outside, np.sqrt(np.maximum(2 * k * np.abs(r) - k * k, 0.0)), r)


def banded_upper(H: sp.spmatrix, min_bandwidth: int = 0) -> FloatArray:
    """Upper banded storage ab[u + i − j, j] = H[i, j] (i ≤ j) of a symmetric sparse H.

    u is H's upper bandwidth, at least `min_bandwidth` (so that whole d × d diagonal
    blocks lie inside the band); the layout of `scipy.linalg.cholesky_banded`.
    """
    coo = H.tocoo()
    upper = coo.col >= coo.row
    row, col, val = coo.row[upper], coo.col[upper], coo.data[upper]
    u = max(int((col - row).max()) if row.size else 0, min_bandwidth)
    ab = np.zeros((u + 1, H.shape[0]))
    np.add.at(ab, (u + row - col, col), val)
    return ab


def compile_kernels() -> None:
    """Compile (or load from numba's cache) the selected-inverse kernel now, not on first solve."""
    selected_inverse(np.ones((1, 1)))


def selected_inverse(U: FloatArray) -> FloatArray:
    """Entries of Σ = (UᵀU)⁻¹ inside the band, from the upper banded Cholesky factor U.

    Parameters
    ----------
    U : (u + 1, n) the factor in upper banded storage (`scipy.linalg.cholesky_banded`).

    Returns
    -------
    (u + 1, n) Σ in the same storage: S[u + i − j, j] = Σ_ij for 0 ≤ j − i ≤ u.
    """
    from cooploc._least_squares_kernels import banded_inverse

    return banded_inverse(U)


def marginal_covariances(J: sp.spmatrix, d: int) -> FloatArray:
    """The d × d diagonal blocks (n, d, d) of (JᵀJ)⁻¹ for a Jacobian J with n d columns."""
    from scipy.linalg import cholesky_banded

    H = (J.T @ J).tocsr()
    U = cholesky_banded(banded_upper(H, d - 1))
    return _diagonal_blocks(selected_inverse(U), d)


class _Banded:
    """The damped normal equations (JᵀJ + λI) Δ = −Jᵀr of a banded JᵀJ, solved for any λ."""

    def __init__(self, r: FloatArray, J: sp.spmatrix) -> None:
        self.g = J.T @ r
        self.ab = banded_upper((J.T @ J).tocsr())

    def step(self, lam: float) -> FloatArray:
        """Δ for damping λ; `LinAlgError` where the damped matrix is not positive definite."""
        from scipy.linalg import cho_solve_banded, cholesky_banded

        damped = self.ab.copy()
        damped[-1] += lam
        return -cho_solve_banded((cholesky_banded(damped), False), self.g)


class _Bordered:
    """(JᵀJ + λI) Δ = −Jᵀr where the last g columns of J (the border) may touch every row.

    With H = [[A, B], [Bᵀ, C]], A banded (n_a × n_a), B (n_a × g), C (g × g): the Schur
    complement S = C − Bᵀ A⁻¹ B (g × g, dense) gives the border's step, then one banded
    solve the rest — O(n_a u² + n_a u g) per λ, no fill-in of the band.
    """

    def __init__(self, r: FloatArray, J: sp.spmatrix, g: int, min_bandwidth: int = 0) -> None:
        J = J.tocsc()
        n_a = J.shape[1] - g
        Ja, Jb = J[:, :n_a], J[:, n_a:]
        self.n_a, self.g = n_a, g
        self.ab = banded_upper((Ja.T @ Ja).tocsr(), min_bandwidth)
        self.B = np.asarray((Ja.T @ Jb).todense())
        self.C = np.asarray((Jb.T @ Jb).todense())
        self.grad_a, self.grad_b = Ja.T @ r, Jb.T @ r

    def factor(self, lam: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Banded Cholesky U of A + λI, Y = (A + λI)⁻¹ B and the Schur complement S."""
        from scipy.linalg import cho_solve_banded, cholesky_banded

        damped = self.ab.copy()
        damped[-1] += lam
        U = cholesky_banded(damped)
        Y = cho_solve_banded((U, False), self.B) if self.n_a else np.zeros((0, self.g))
        S = self.C + lam * np.eye(self.g) - self.B.T @ Y
        return U, Y, 0.5 * (S + S.T)

    def step(self, lam: float) -> FloatArray:
        from scipy.linalg import cho_factor, cho_solve, cho_solve_banded

        U, Y, S = self.factor(lam)
        # eliminate the band: S Δ_b = −(g_b − Yᵀ g_a), then A Δ_a = −g_a − B Δ_b
        d_b = -cho_solve(cho_factor(S), self.grad_b - Y.T @ self.grad_a)
        d_a = -cho_solve_banded((U, False), self.grad_a + self.B @ d_b) if self.n_a else np.zeros(0)
        return np.concatenate([d_a, d_b])

    def marginals(self, d: int) -> tuple[FloatArray, FloatArray]:
        """Diagonal d × d blocks (n, d, d) of H⁻¹ over the band and the border's (g, g) block.

        H⁻¹ = [[A⁻¹ + Y S⁻¹ Yᵀ, −Y S⁻¹], [−S⁻¹ Yᵀ, S⁻¹]]: the band's blocks are those of the
        selected inverse of A plus the rank-g correction Y S⁻¹ Yᵀ.
        """
        U, Y, S = self.factor(0.0)
        S_inv = np.linalg.solve(S, np.eye(self.g))
        cov = _diagonal_blocks(selected_inverse(U), d)
        Yb = Y.reshape(-1, d, self.g)
        cov += np.einsum("nig,gh,njh->nij", Yb, S_inv, Yb)
        return cov, 0.5 * (S_inv + S_inv.T)


def _diagonal_blocks(S: FloatArray, d: int) -> FloatArray:
    """The d × d diagonal blocks (n, d, d) of a symmetric matrix in upper banded storage."""
    u = S.shape[0] - 1
    i = np.arange(S.shape[1] // d)
    cov = np.empty((i.size, d, d))
    for a in range(d):
        for b in range(a, d):
            cov[:, a, b] = cov[:, b, a] = S[u + a - b, d * i + b]
    return cov


def _levenberg_marquardt(linearize: Callable[[FloatArray, bool], tuple[FloatArray, sp.spmatrix | None]],
                         v0: FloatArray, system: Callable[[FloatArray, sp.spmatrix], _Banded | _Bordered],
                         max_iterations: int, relative_tolerance: float, absolute_tolerance: float,
                         lambda_initial: float) -> tuple[FloatArray, sp.spmatrix, int, float]:
    """The LM loop of `solve_lm` on a flat vector v; returns v, J at v, iterations, cost."""
    v = np.array(v0, dtype=float)
    lam = lambda_initial
    r, J = linearize(v, True)

    def cost_at(y: FloatArray) -> float:
        e = linearize(y, False)[0]
        return 0.5 * float(e @ e)

    cost = cost_at(v)
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 - reported
        equations = system(r, J)
        improved = False
        while lam < 1e10:
            try:
                step = equations.step(lam)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            cost_new = cost_at(v + step)
            if cost_new <= cost:
                v += step
                decrease = cost - cost_new
                cost = cost_new
                lam = max(lam / 10.0, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved:
            break
        r, J = linearize(v, True)
        if decrease <= absolute_tolerance or decrease <= relative_tolerance * max(cost, 1e-300):
            break
    return v, J, iterations, cost


def solve_lm(linearize: Linearize, x0: FloatArray, *, max_iterations: int = 100,
             relative_tolerance: float = 1e-5, absolute_tolerance: float = 1e-5,
             lambda_initial: float = 1e-5, covariances: bool = True) -> LMResult:
    """Levenberg–Marquardt on ½‖e(x)‖², GTSAM-style, from x0 (n, d).

    Each iteration solves (JᵀJ + λI) Δ = −Jᵀr with one banded Cholesky; a step is kept
    if it lowers the cost (λ ÷ 10), otherwise λ × 10. Stops like GTSAM's defaults: when
    the cost falls by less than `relative_tolerance` (relative) or `absolute_tolerance`,
    when no λ < 1e10 lowers the cost, or after `max_iterations`.

    Parameters
    ----------
    linearize : the problem (module docstring).
    x0 : (n, d) initial guess.
    covariances : also return the marginal covariances (n, d, d) at the solution.
    """
    shape = np.shape(x0)
    v, J, iterations, cost = _levenberg_marquardt(
        lambda v, jac: linearize(v.reshape(shape), jac), np.ravel(x0), _Banded,
        max_iterations, relative_tolerance, absolute_tolerance, lambda_initial)
    cov = marginal_covariances(J, shape[1]) if covariances else None
    return LMResult(v.reshape(shape), cov, iterations, cost)


def solve_lm_bordered(linearize: BorderedLinearize, x0: FloatArray, b0: FloatArray, *,
                      max_iterations: int = 100, relative_tolerance: float = 1e-5,
                      absolute_tolerance: float = 1e-5, lambda_initial: float = 1e-5,
                      covariances: bool = True) -> LMResult:
    """`solve_lm` with g border unknowns b that any factor may touch (e.g. a sensor's pose).

    ``linearize(x, b, jacobian)`` → (r, J) as in the module docstring, J's columns ordered
    as ``[x.ravel(), b]``: JᵀJ is banded except for its last g rows and columns (an
    arrow). Each LM trial eliminates the band by its Schur complement (`_Bordered`), so
    a step costs a banded Cholesky plus O(n d u g) — the band never fills in.

    Parameters
    ----------
    linearize : the problem.
    x0 : (n, d) initial guess of the banded unknowns.
    b0 : (g,) initial guess of the border.
    covariances : also return the marginal covariances of x (n, d, d) and of b (g, g).

    Returns
    -------
    LMResult with `border` and `border_cov` set.
    """
    shape, g = np.shape(x0), np.size(b0)
    n_x = int(np.prod(shape))
    v, J, iterations, cost = _levenberg_marquardt(
        lambda v, jac: linearize(v[:n_x].reshape(shape), v[n_x:], jac),
        np.concatenate([np.ravel(x0), np.ravel(b0)]), lambda r, J: _Bordered(r, J, g),
        max_iterations, relative_tolerance, absolute_tolerance, lambda_initial)
    cov = border_cov = None
    if covariances:
        r = np.zeros(J.shape[0])
        cov, border_cov = _Bordered(r, J, g, shape[1] - 1).marginals(shape[1])
    return LMResult(v[:n_x].reshape(shape), cov, iterations, cost, v[n_x:], border_cov)
