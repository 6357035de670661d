"""Tests of `cooploc.least_squares` (banded Levenberg–Marquardt and the selected inverse).

Oracles: SciPy's `least_squares` (trust-region reflective, with its own Huber loss) on
a small banded problem — a 2-D chain with a prior, between factors and range factors
two links apart —, the dense inverse of JᵀJ for the marginal covariances and the
selected inverse, and the definitions of the Huber loss and of whitening.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.linalg import cholesky_banded
from scipy.optimize import least_squares as scipy_least_squares

from cooploc.least_squares import (
    banded_upper,
    huber_cost_residual,
    huber_sqrt_weights,
    marginal_covariances,
    selected_inverse,
    solve_lm,
    solve_lm_bordered,
    whitener,
)

# both solvers stop at relative cost changes ~1e-14 of a well-conditioned problem
# (prior, links of σ 0.5 m and 0.1 m); with the Huber loss IRLS converges only linearly
# near its kinks: over 200 seeds the minimisers differed by < 2e-6 m (0.1 mm: margin)
X_ATOL_M = 1e-4
COST_RTOL = 1e-9
# the selected inverse and a dense LU inverse of a well-conditioned matrix agree to
# round-off, O(κ ε) with κ ≤ 1e3 here
INVERSE_RTOL = 1e-9


class Chain:
    """x (n, 2): a prior on x_0, between rows x_{i+1} − x_i − d_i and rows two links apart.

    The rows two links apart are ranges ‖x_{i+2} − x_i‖ − ρ_i (nonlinear), or with
    `linear=True` displacements x_{i+2} − x_i − e_i, which make the Huber cost convex
    (one minimum); `outliers` shifts every fourth between row by 20 σ.
    """

    sigma_prior, sigma_between, sigma_two = 1.0, 0.5, 0.1

    def __init__(self, rng: np.random.Generator, n: int = 15, linear: bool = False,
                 outliers: bool = False) -> None:
        # a path heading roughly east in steps of ~10 m: ranges two links apart are long
        truth = np.cumsum(np.array([10.0, 0.0]) + rng.normal(0, 2, (n, 2)), axis=0)
        self.n, self.linear = n, linear
        self.a = truth[0] + rng.normal(0, self.sigma_prior, 2)
        self.d = np.diff(truth, axis=0) + rng.normal(0, self.sigma_between, (n - 1, 2))
        two = truth[2:] - truth[:-2]
        if linear:
            self.two = two + rng.normal(0, self.sigma_two, two.shape)
        else:
            self.two = np.linalg.norm(two, axis=1) + rng.normal(0, self.sigma_two, n - 2)
        if outliers:
            self.d[::4] += 20 * self.sigma_between
        self.x0 = truth + rng.normal(0, 0.5, truth.shape)

    def residual(self, x: np.ndarray) -> np.ndarray:
        two = x[2:] - x[:-2]
        if not self.linear:
            two = np.linalg.norm(two, axis=1)
        return np.concatenate([(x[0] - self.a) / self.sigma_prior,
                               ((x[1:] - x[:-1] - self.d) / self.sigma_between).ravel(),
                               ((two - self.two) / self.sigma_two).ravel()])

    def jacobian(self, x: np.ndarray) -> sp.csr_matrix:
        n = self.n
        J = sp.lil_matrix((self.residual(x).size, 2 * n))
        J[0, 0] = J[1, 1] = 1.0 / self.sigma_prior
        for i in range(n - 1):
            for c in range(2):
                J[2 + 2 * i + c, 2 * i + c] = -1.0 / self.sigma_between
                J[2 + 2 * i + c, 2 * (i + 1) + c] = 1.0 / self.sigma_between
        row0 = 2 + 2 * (n - 1)
        if self.linear:
            for i in range(n - 2):
                for c in range(2):
                    J[row0 + 2 * i + c, 2 * i + c] = -1.0 / self.sigma_two
                    J[row0 + 2 * i + c, 2 * (i + 2) + c] = 1.0 / self.sigma_two
            return J.tocsr()
        diff = x[2:] - x[:-2]
        unit = diff / np.linalg.norm(diff, axis=1, keepdims=True) / self.sigma_two
        for i in range(n - 2):
            J[row0 + i, 2 * i:2 * i + 2] = -unit[i]
            J[row0 + i, 2 * (i + 2):2 * (i + 2) + 2] = unit[i]
        return J.tocsr()

    def linearize(self, k: float = 0.0):
        """The `solve_lm` callable, with the Huber loss of threshold k on every row (k > 0)."""

        def linearize(x: np.ndarray, jacobian: bool = True):
            r = self.residual(x)
            if not jacobian:
                return huber_cost_residual(r, k), None
            w = huber_sqrt_weights(r, k)
            return w * r, sp.diags(w) @ self.jacobian(x)

        return linearize


def scipy_solution(chain: Chain, k: float = 0.0):
    kwargs = {"loss": "huber", "f_scale": k} if k > 0 else {}
    return scipy_least_squares(
        lambda v: chain.residual(v.reshape(-1, 2)), chain.x0.ravel(),
        jac=lambda v: chain.jacobian(v.reshape(-1, 2)).toarray(), method="trf",
        xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=1000, **kwargs)


TIGHT = {"relative_tolerance": 1e-14, "absolute_tolerance": 1e-14, "max_iterations": 500}


def test_lm_finds_scipy_minimum(rng: np.random.Generator) -> None:
    chain = Chain(rng)
    ours = solve_lm(chain.linearize(), chain.x0, **TIGHT)
    ref = scipy_solution(chain)
    assert ref.success
    np.testing.assert_allclose(ours.x.ravel(), ref.x, atol=X_ATOL_M)
    np.testing.assert_allclose(ours.cost, ref.cost, rtol=COST_RTOL)
    assert 1 <= ours.iterations < TIGHT["max_iterations"]


def test_robust_lm_finds_scipy_huber_minimum(rng: np.random.Generator) -> None:
    """IRLS with √w held fixed per iteration reaches the minimum of the Huber cost (convex
    here, so both solvers must find the same one)."""
    k = 1.5
    chain = Chain(rng, linear=True, outliers=True)
    ours = solve_lm(chain.linearize(k), chain.x0, **TIGHT)
    ref = scipy_solution(chain, k)
    assert ref.success
    assert (np.abs(chain.residual(ours.x)) > k).sum() >= 3  # the outliers are in the tails
    np.testing.assert_allclose(ours.x.ravel(), ref.x, atol=X_ATOL_M)
    np.testing.assert_allclose(ours.cost, ref.cost, rtol=COST_RTOL)


def test_lm_covariances_are_blocks_of_the_dense_inverse(rng: np.random.Generator) -> None:
    chain = Chain(rng)
    result = solve_lm(chain.linearize(), chain.x0)
    J = chain.jacobian(result.x)
    dense = np.linalg.inv((J.T @ J).toarray())  # oracle: the dense inverse
    blocks = np.array([dense[2 * v:2 * v + 2, 2 * v:2 * v + 2] for v in range(chain.n)])
    np.testing.assert_allclose(result.cov, blocks, rtol=INVERSE_RTOL,
                               atol=INVERSE_RTOL * np.abs(blocks).max())
    assert solve_lm(chain.linearize(), chain.x0, covariances=False).cov is None


def random_banded(rng: np.random.Generator, n: int, u: int) -> np.ndarray:
    """A well-conditioned symmetric positive-definite matrix (n, n) of bandwidth u."""
    M = rng.normal(size=(n, n))
    B = np.triu(np.tril(M + M.T, u), -u)
    return B + np.diag(np.abs(B).sum(axis=1) + 1.0)  # strictly diagonally dominant: SPD


@pytest.mark.parametrize("u", [0, 1, 4])
def test_selected_inverse_equals_dense_inverse_inside_the_band(u: int, rng: np.random.Generator) -> None:
    n = 30
    H = random_banded(rng, n, u)
    ab = banded_upper(sp.csr_matrix(H))
    assert ab.shape == (u + 1, n)
    S = selected_inverse(cholesky_banded(ab))
    dense = np.linalg.inv(H)
    i, j = np.triu_indices(n)
    inside = j - i <= u
    np.testing.assert_allclose(S[u + i[inside] - j[inside], j[inside]], dense[i[inside], j[inside]],
                               rtol=INVERSE_RTOL, atol=INVERSE_RTOL * np.abs(dense).max())


def test_banded_upper_is_lapack_upper_storage(rng: np.random.Generator) -> None:
    H = random_banded(rng, 8, 2)
    ab = banded_upper(sp.csr_matrix(H), min_bandwidth=3)  # padded to u = 3
    assert ab.shape == (4, 8)
    i, j = np.triu_indices(8)
    inside = j - i <= 3
    np.testing.assert_array_equal(ab[3 + i[inside] - j[inside], j[inside]], H[i[inside], j[inside]])


@pytest.mark.parametrize("d", [1, 2, 3])
def test_marginal_covariances_of_a_banded_jacobian(d: int, rng: np.random.Generator) -> None:
    """JᵀJ of an upper-bidiagonal J has bandwidth 1: for d = 3 the blocks are wider than
    the band, which is padded so that they are whole."""
    n = 12
    J = sp.diags([rng.uniform(1, 2, n * d), rng.normal(0, 0.5, n * d - 1)], [0, 1]).tocsr()
    dense = np.linalg.inv((J.T @ J).toarray())
    blocks = np.array([dense[d * v:d * v + d, d * v:d * v + d] for v in range(n)])
    np.testing.assert_allclose(marginal_covariances(J, d), blocks, rtol=INVERSE_RTOL,
                               atol=INVERSE_RTOL * np.abs(blocks).max())


def test_huber_residual_and_weights_are_the_huber_loss(rng: np.random.Generator) -> None:
    k = 1.3
    r = rng.normal(0, 3, 200)
    rho = np.where(np.abs(r) <= k, 0.5 * r**2, k * np.abs(r) - 0.5 * k**2)
    np.testing.assert_allclose(0.5 * huber_cost_residual(r, k) ** 2, rho, rtol=1e-12)
    # IRLS: w r = ρ'(r), the gradient of the loss
    np.testing.assert_allclose(huber_sqrt_weights(r, k) ** 2 * r, np.clip(r, -k, k), rtol=1e-12)
    np.testing.assert_array_equal(huber_sqrt_weights(r, 0.0), np.ones_like(r))
    np.testing.assert_array_equal(huber_cost_residual(r, 0.0), r)


def test_whitener_gives_unit_covariance(rng: np.random.Generator) -> None:
    A = rng.normal(size=(5, 3, 3))
    cov = A @ A.transpose(0, 2, 1) + 0.1 * np.eye(3)
    W = whitener(cov)
    np.testing.assert_allclose(W @ cov @ W.transpose(0, 2, 1), np.broadcast_to(np.eye(3), cov.shape),
                               atol=1e-10)
    assert whitener(np.zeros((0, 2, 2))).shape == (0, 2, 2)


def test_bordered_lm_is_the_dense_solution_with_a_global_offset(rng: np.random.Generator) -> None:
    """The chain seen by a sensor with an unknown offset b (2,): rows x_i + b − y_i on every
    variable (an arrow normal matrix). SciPy on the dense problem gives the minimum, the
    dense inverse of JᵀJ the marginals."""
    chain = Chain(rng)
    n = chain.n
    y = chain.x0 + np.array([3.0, -2.0]) + rng.normal(0, 0.3, (n, 2))
    sigma_y = 0.3

    def residual(v: np.ndarray) -> np.ndarray:
        x, b = v[:2 * n].reshape(n, 2), v[2 * n:]
        return np.concatenate([chain.residual(x), ((x + b - y) / sigma_y).ravel()])

    def jacobian(v: np.ndarray) -> sp.csr_matrix:
        x = v[:2 * n].reshape(n, 2)
        J_y = sp.hstack([sp.identity(2 * n), sp.csr_matrix(np.tile(np.eye(2), (n, 1)))]) / sigma_y
        J_chain = sp.hstack([chain.jacobian(x), sp.csr_matrix((chain.residual(x).size, 2))])
        return sp.vstack([J_chain, J_y]).tocsr()

    def linearize(x: np.ndarray, b: np.ndarray, jac: bool = True):
        v = np.concatenate([x.ravel(), b])
        return residual(v), (jacobian(v) if jac else None)

    ours = solve_lm_bordered(linearize, chain.x0, np.zeros(2), **TIGHT)
    ref = scipy_least_squares(residual, np.concatenate([chain.x0.ravel(), np.zeros(2)]),
                              jac=lambda v: jacobian(v).toarray(), method="trf",
                              xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=1000)
    assert ref.success
    np.testing.assert_allclose(np.concatenate([ours.x.ravel(), ours.border]), ref.x, atol=X_ATOL_M)
    J = jacobian(ref.x).toarray()
    Sigma = np.linalg.inv(J.T @ J)
    blocks = np.array([Sigma[2 * i:2 * i + 2, 2 * i:2 * i + 2] for i in range(n)])
    # zero cross terms differ by round-off: absolute tolerance at 1e-9 of the variances
    np.testing.assert_allclose(ours.cov, blocks, rtol=INVERSE_RTOL, atol=1e-9 * blocks.max())
    np.testing.assert_allclose(ours.border_cov, Sigma[2 * n:, 2 * n:], rtol=INVERSE_RTOL,
                               atol=1e-9 * Sigma.max())
