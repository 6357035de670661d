"""The compiled small-matrix solves of `cooploc.gaussian` against `np.linalg`.

`to_information`, `from_information`, `gaussian_logpdf` and `spd_solve` factor each matrix
of a stack by a compiled Cholesky loop (`cooploc._gaussian_kernels`) instead of one
LAPACK call per matrix. Oracle: the `np.linalg` forms they replaced (Cholesky, LU solves,
`slogdet`), on random SPD stacks of d = 1 … 6 with condition numbers from 1 to 1e12.
Two backward-stable algorithms differ by about κ(A)·ε relative, so the tolerance is
`ROUND_OFF` · κ: 1e-12 and below for the well-conditioned stacks, looser only as far as
the conditioning forces. Failures (not positive definite, NaN) raise `LinAlgError` as
`np.linalg.cholesky` does.
"""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.gaussian import Gaussians, from_information, gaussian_logpdf, spd_solve, to_information

# two backward-stable results differ by ≲ c d κ ε; c d ε ≤ 1e-14 · d for these sizes
ROUND_OFF = 1e-14


def spd_stack(rng: np.random.Generator, n: int, d: int, log10_cond: float) -> np.ndarray:
    """n random SPD matrices Q diag(λ) Qᵀ with eigenvalues spread over 10^log10_cond, scaled
    by a random power of ten (entries of 1e-4 … 1e4, as variances in m² and (m/s)²)."""
    Q = np.linalg.qr(rng.standard_normal((n, d, d)))[0]
    lam = 10.0 ** rng.uniform(-log10_cond, 0.0, (n, d))
    lam[:, 0] = 1.0
    A = (Q * lam[:, None, :]) @ Q.transpose(0, 2, 1) * 10.0 ** rng.uniform(-4, 4, (n, 1, 1))
    return 0.5 * (A + A.transpose(0, 2, 1))


def _tolerance(A: np.ndarray) -> np.ndarray:
    return ROUND_OFF * A.shape[-1] * np.linalg.cond(A)


CASES = [(d, c) for d in (1, 2, 3, 4, 6) for c in (0.0, 3.0, 8.0, 12.0)]


@pytest.mark.parametrize(("d", "log10_cond"), CASES)
def test_information_form_matches_linalg(d: int, log10_cond: float) -> None:
    rng = np.random.default_rng(d * 100 + int(log10_cond))
    P = spd_stack(rng, 300, d, log10_cond)
    m = rng.standard_normal((300, d)) * 10.0
    Lam, eta = to_information(Gaussians(m, P))
    inv = np.linalg.inv(P)
    tol = _tolerance(P)
    scale = np.abs(inv).max(axis=(1, 2))
    assert (np.abs(Lam - inv).max(axis=(1, 2)) <= tol * scale).all()
    assert (Lam == Lam.transpose(0, 2, 1)).all()                         # exactly symmetric
    ref_eta = np.einsum("nij,nj->ni", inv, m)
    assert (np.abs(eta - ref_eta).max(axis=1) <= tol * scale * np.abs(m).max(axis=1)).all()
    back = from_information(P, m)                                          # the same map
    np.testing.assert_array_equal(back.cov, Lam)
    np.testing.assert_array_equal(back.mean, eta)


@pytest.mark.parametrize(("d", "log10_cond"), CASES)
def test_spd_solve_and_logpdf_match_linalg(d: int, log10_cond: float) -> None:
    rng = np.random.default_rng(d * 100 + int(log10_cond) + 1)
    C = spd_stack(rng, 300, d, log10_cond)
    r = rng.standard_normal((300, d))
    x = spd_solve(C, r)
    ref = np.linalg.solve(C, r[..., None])[..., 0]
    tol = _tolerance(C)
    assert (np.abs(x - ref).max(axis=1) <= tol * np.abs(ref).max(axis=1)).all()
    logpdf = gaussian_logpdf(r, C)
    _, log_det = np.linalg.slogdet(C)
    ref_logpdf = -0.5 * (d * np.log(2 * np.pi) + log_det + np.einsum("ni,ni->n", r, ref))
    # the quadratic form carries κ ε relative error, log det an absolute d ε |log λ|
    assert (np.abs(logpdf - ref_logpdf) <= tol * (np.abs(ref_logpdf) + np.abs(log_det) + 1.0)).all()


def test_well_conditioned_agree_to_1e12() -> None:
    # the brief's bar: κ ≤ 1e2, entries over eight orders of magnitude
    rng = np.random.default_rng(7)
    for d in (2, 4):
        P = spd_stack(rng, 2000, d, 2.0)
        m = rng.standard_normal((2000, d))
        Lam, eta = to_information(Gaussians(m, P))
        inv = np.linalg.inv(P)
        np.testing.assert_allclose(Lam, inv, rtol=1e-12, atol=1e-12 * np.abs(inv).max())
        ref_eta = np.einsum("nij,nj->ni", inv, m)
        np.testing.assert_allclose(eta, ref_eta, rtol=1e-12, atol=1e-12 * np.abs(ref_eta).max())
        np.testing.assert_allclose(gaussian_logpdf(m, P), multivariate_logpdf(m, P), rtol=1e-12)


def multivariate_logpdf(r: np.ndarray, C: np.ndarray) -> np.ndarray:
    """log N(r; 0, C) by `np.linalg` only (slogdet and solve)."""
    d = r.shape[-1]
    q = np.einsum("...i,...i->...", r, np.linalg.solve(C, r[..., None])[..., 0])
    return -0.5 * (d * np.log(2 * np.pi) + np.linalg.slogdet(C)[1] + q)


def test_batch_shapes_and_broadcasting() -> None:
    rng = np.random.default_rng(3)
    C = spd_stack(rng, 6, 2, 1.0).reshape(2, 3, 2, 2)
    r = rng.standard_normal((5, 1, 1, 2))
    out = gaussian_logpdf(r, C)                                 # (5, 2, 3)
    assert out.shape == (5, 2, 3)
    ref = multivariate_logpdf(np.broadcast_to(r, (5, 2, 3, 2)), np.broadcast_to(C, (5, 2, 3, 2, 2)))
    np.testing.assert_allclose(out, ref, rtol=1e-12)
    Lam, eta = to_information(Gaussians(rng.standard_normal((2, 3, 2)), C))
    assert Lam.shape == (2, 3, 2, 2) and eta.shape == (2, 3, 2)
    one = from_information(C[0, 0], np.ones(2))                  # a single matrix
    np.testing.assert_allclose(one.cov, np.linalg.inv(C[0, 0]), rtol=1e-12)
    empty = to_information(Gaussians(np.zeros((0, 4)), np.zeros((0, 4, 4))))
    assert empty[0].shape == (0, 4, 4) and empty[1].shape == (0, 4)


@pytest.mark.parametrize("bad", ["indefinite", "singular"])
def test_not_positive_definite_raises_as_linalg(bad: str) -> None:
    C = np.repeat(np.eye(3)[None], 4, 0)
    C[2] = {"indefinite": np.diag([1.0, -1.0, 1.0]), "singular": np.diag([1.0, 0.0, 1.0])}[bad]
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(C)                                    # the reference raises ...
    with pytest.raises(np.linalg.LinAlgError):
        to_information(Gaussians(np.zeros((4, 3)), C))           # ... and so do these
    with pytest.raises(np.linalg.LinAlgError):
        from_information(C, np.zeros((4, 3)))
    with pytest.raises(np.linalg.LinAlgError):
        gaussian_logpdf(np.zeros((4, 3)), C)
    with pytest.raises(np.linalg.LinAlgError):
        spd_solve(C, np.zeros((4, 3)))


def test_nan_propagates_as_linalg() -> None:
    # np.linalg.cholesky does not raise on NaN (LAPACK's pivot test is ≤ 0): NaN results
    C = np.repeat(np.eye(3)[None], 3, 0)
    C[1, 1, 1] = np.nan
    assert not np.isnan(np.linalg.cholesky(C)[[0, 2]]).any() and np.isnan(np.linalg.cholesky(C)[1]).any()
    Lam, eta = to_information(Gaussians(np.ones((3, 3)), C))
    assert np.isnan(Lam[1]).any() and np.isnan(eta[1]).any()
    np.testing.assert_array_equal(Lam[[0, 2]], np.repeat(np.eye(3)[None], 2, 0))
    logpdf = gaussian_logpdf(np.ones((3, 3)), C)
    assert np.isnan(logpdf[1]) and np.isfinite(logpdf[[0, 2]]).all()


def test_only_the_lower_triangle_is_read_as_linalg_cholesky() -> None:
    rng = np.random.default_rng(5)
    C = spd_stack(rng, 50, 4, 2.0)
    junk = C + np.triu(rng.standard_normal((50, 4, 4)), 1)       # upper triangle changed
    np.testing.assert_allclose(gaussian_logpdf(np.ones((50, 4)), junk),
                               multivariate_logpdf(np.ones((50, 4)), C), rtol=1e-12)
