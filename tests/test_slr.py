"""Sigma points and statistical linear regression (`cooploc.gaussian`) against analytic values.

Oracles: an affine h is its own SLR with Ω = 0 (both point sets integrate degree-3
polynomials exactly); for h(x) = x² under N(m, P) the exact SLR is A = 2m, c = P − m²,
Ω = 2P², which the 1-D unscented set with w₀ = 2/3 reproduces (it matches the fourth
moment 3P²); the branch correction makes the SLR of a bearing equivariant under a
quarter turn of the scene, also when the bearing crosses ±π.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cooploc.errors import InvalidInputError
from cooploc.gaussian import SIGMA_POINT_METHODS, sigma_points, statistical_linear_regression
from cooploc.geometry import wrap_angle

# Round-off of the sigma-point sums and one 6×6 solve on well-conditioned covariances.
EXACT = 1e-9


def _random_gaussians(rng: np.random.Generator, n: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    mean = rng.normal(size=(n, d))
    X = rng.normal(size=(n, d, d))
    return mean, X @ X.transpose(0, 2, 1) + 0.5 * np.eye(d)


@pytest.mark.parametrize("method", SIGMA_POINT_METHODS)
def test_sigma_points_match_mean_and_covariance(method: str, rng: np.random.Generator) -> None:
    mean, cov = _random_gaussians(rng, 5, 4)
    chi, w = sigma_points(mean, cov, method)
    assert chi.shape == (5, w.size, 4) and np.all(w > 0)
    np.testing.assert_allclose(w.sum(), 1.0, rtol=0, atol=EXACT)
    np.testing.assert_allclose(np.einsum("s,nsd->nd", w, chi), mean, rtol=0, atol=EXACT)
    centred = chi - mean[:, None]
    np.testing.assert_allclose(np.einsum("s,nsi,nsj->nij", w, centred, centred), cov,
                               rtol=0, atol=EXACT)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), d=st.integers(1, 6), dz=st.integers(1, 3),
       method=st.sampled_from(SIGMA_POINT_METHODS))
def test_slr_of_an_affine_function_is_that_function(seed: int, d: int, dz: int, method: str) -> None:
    rng = np.random.default_rng(seed)
    mean, cov = _random_gaussians(rng, 3, d)
    M, b = rng.normal(size=(dz, d)), rng.normal(size=dz)
    A, c, Omega = statistical_linear_regression(mean, cov, lambda x: x @ M.T + b, method=method)
    np.testing.assert_allclose(A, np.broadcast_to(M, A.shape), rtol=0, atol=EXACT)
    np.testing.assert_allclose(c, np.broadcast_to(b, c.shape), rtol=0, atol=EXACT)
    np.testing.assert_allclose(Omega, 0.0, rtol=0, atol=EXACT)


def test_slr_of_a_square_matches_the_exact_moments() -> None:
    m, P = np.array([[0.7], [-2.0]]), np.array([[[0.3]], [[1.5]]])
    A, c, Omega = statistical_linear_regression(m, P, lambda x: x**2, method="unscented",
                                                central_weight=2.0 / 3.0)
    # Cov(x, x²) = 2 m P, E[x²] = m² + P, Var(x²) = 4 m² P + 2 P²
    np.testing.assert_allclose(A[:, 0, 0], 2 * m[:, 0], rtol=0, atol=EXACT)
    np.testing.assert_allclose(c[:, 0], P[:, 0, 0] - m[:, 0] ** 2, rtol=0, atol=EXACT)
    np.testing.assert_allclose(Omega[:, 0, 0], 2 * P[:, 0, 0] ** 2, rtol=0, atol=EXACT)


def _bearing(x: np.ndarray) -> np.ndarray:
    """Bearing of a point (x, y) seen from the origin, wrapped to [−π, π): (..., 1)."""
    return wrap_angle(np.arctan2(x[..., 1], x[..., 0]))[..., None]


@pytest.mark.parametrize("method", SIGMA_POINT_METHODS)
def test_branch_correction_makes_bearing_slr_rotation_equivariant(method: str) -> None:
    # a point 10 m away straddling the negative x axis (bearing ±π) with 3 m spread:
    # its sigma points' bearings jump between +π and −π
    cov = np.diag([9.0, 9.0])[None]
    near_cut = np.array([[-10.0, 0.2]])
    reference = np.array([[np.pi - 0.01]])           # the measurement, on the + side of the cut
    A, c, Omega = statistical_linear_regression(near_cut, cov, _bearing, method=method,
                                                angular=[True], reference=reference)
    # the same geometry rotated by −π/2: the bearing is far from the cut. (A quarter turn
    # maps the sigma-point set of an isotropic covariance onto itself; other angles do not.)
    phi = -np.pi / 2
    R = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])
    A_r, c_r, Omega_r = statistical_linear_regression(
        near_cut @ R.T, R @ cov @ R.T, _bearing, method=method, angular=[True],
        reference=wrap_angle(reference + phi))
    np.testing.assert_allclose(Omega, Omega_r, rtol=1e-9, atol=0)
    np.testing.assert_allclose(A, A_r @ R, rtol=1e-9, atol=1e-12)
    # z̄ = A x̄ + c moves with the rotation, on the measurement's branch
    z_bar, z_bar_r = A[0] @ near_cut[0] + c[0], A_r[0] @ (R @ near_cut[0]) + c_r[0]
    np.testing.assert_allclose(wrap_angle(z_bar_r - z_bar - phi), 0.0, rtol=0, atol=1e-9)
    assert abs(z_bar[0] - reference[0, 0]) < 0.1
    # linearization error: about (σ/r)² ≈ 0.09 rad² scaled by the fourth-order terms, not
    # the (2π)² · ¼ ≈ 10 rad² of a regression across the cut
    assert Omega[0, 0, 0] < 0.05


def test_without_the_correction_the_cut_ruins_the_regression() -> None:
    cov = np.diag([9.0, 9.0])[None]
    _, _, Omega = statistical_linear_regression(np.array([[-10.0, 0.2]]), cov, _bearing)
    assert Omega[0, 0, 0] > 1.0  # the reason for eq. (15)


def test_bad_method_is_rejected() -> None:
    with pytest.raises(InvalidInputError, match="sigma point method"):
        sigma_points(np.zeros((1, 2)), np.eye(2)[None], "gauss-hermite")
    with pytest.raises(InvalidInputError, match="central_weight"):
        sigma_points(np.zeros((1, 2)), np.eye(2)[None], "unscented", central_weight=1.0)
