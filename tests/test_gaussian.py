"""`cooploc.gaussian` against trusted references and invariants.

Oracles: filterpy's `KalmanFilter` (the textbook equations, one belief at a time),
`scipy.stats.multivariate_normal` for log densities (and, through them, the NIS). Properties (hypothesis): the
Joseph-form covariance is symmetric positive semi-definite and never larger than the
prior; the information form is an exact re-parametrisation.
"""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.stats import multivariate_normal

from cooploc.gaussian import (
    Gaussians,
    from_information,
    gaussian_logpdf,
    information_update,
    kf_predict,
    kf_update,
    kf_update_nis,
    kf_update_relative,
    nis,
    symmetrize,
    to_information,
)

# filterpy forms S⁻¹ explicitly, we solve S K = H P; both are backward stable and the
# random problems below have condition numbers ≲ 1e3, so the two differ by round-off
# (~1e-13 relative). 1e-10 leaves three orders of margin and still catches any error
# in an equation (those are O(1)).
REFERENCE_RTOL = 1e-10
# Batched NumPy calls may take other BLAS paths than single ones: round-off only.
BATCH_RTOL = 1e-10
# Information-form round trips go through Cholesky factors and two triangular solves;
# error ≈ cond · eps ≈ 1e3 · 2e-16, so 1e-9 relative is generous but still tight.
INFO_RTOL = 1e-9


def random_spd(rng: np.random.Generator, d: int, n: int | None = None) -> np.ndarray:
    """Well-conditioned SPD matrices (d, d) or (n, d, d): A Aᵀ / d + 0.5 I."""
    shape = (d, d) if n is None else (n, d, d)
    A = rng.standard_normal(shape)
    return A @ np.swapaxes(A, -1, -2) / d + 0.5 * np.eye(d)


def random_problem(rng: np.random.Generator, n: int = 6):
    dx, dz, du = int(rng.integers(1, 7)), int(rng.integers(1, 4)), int(rng.integers(1, 3))
    return dict(
        mean=3.0 * rng.standard_normal((n, dx)),
        cov=random_spd(rng, dx, n),
        F=np.eye(dx) + 0.3 * rng.standard_normal((dx, dx)),
        Q=random_spd(rng, dx),
        B=rng.standard_normal((dx, du)),
        u=rng.standard_normal((n, du)),
        H=rng.standard_normal((dz, dx)),
        Hn=rng.standard_normal((n, dz, dx)),
        R=random_spd(rng, dz),
        Rn=random_spd(rng, dz, n),
        z=3.0 * rng.standard_normal((n, dz)),
    )


def filterpy_filter(mean: np.ndarray, cov: np.ndarray, dz: int) -> KalmanFilter:
    kf = KalmanFilter(dim_x=mean.size, dim_z=dz)
    kf.x = mean[:, None].copy()
    kf.P = cov.copy()
    return kf


@pytest.mark.parametrize("case", range(8))
def test_predict_equals_filterpy(rng: np.random.Generator, case: int) -> None:
    p = random_problem(rng)
    ours = kf_predict(Gaussians(p["mean"], p["cov"]), p["F"], p["Q"], p["B"], p["u"])
    for i in range(len(p["mean"])):
        kf = filterpy_filter(p["mean"][i], p["cov"][i], p["H"].shape[0])
        kf.predict(u=p["u"][i][:, None], B=p["B"], F=p["F"], Q=p["Q"])
        np.testing.assert_allclose(ours.mean[i], kf.x[:, 0], rtol=REFERENCE_RTOL,
                                   atol=REFERENCE_RTOL * np.abs(kf.x).max())
        np.testing.assert_allclose(ours.cov[i], kf.P, rtol=REFERENCE_RTOL,
                                   atol=REFERENCE_RTOL * np.abs(kf.P).max())


@pytest.mark.parametrize("case", range(8))
@pytest.mark.parametrize("per_belief", [False, True], ids=["shared-H-R", "per-belief-H-R"])
def test_update_equals_filterpy(rng: np.random.Generator, case: int, per_belief: bool) -> None:
    p = random_problem(rng)
    H, R = (p["Hn"], p["Rn"]) if per_belief else (p["H"], p["R"])
    ours = kf_update(Gaussians(p["mean"], p["cov"]), p["z"], H, R)
    for i in range(len(p["mean"])):
        Hi, Ri = (H[i], R[i]) if per_belief else (H, R)
        kf = filterpy_filter(p["mean"][i], p["cov"][i], Hi.shape[0])
        kf.update(p["z"][i][:, None], R=Ri, H=Hi)
        np.testing.assert_allclose(ours.mean[i], kf.x[:, 0], rtol=REFERENCE_RTOL,
                                   atol=REFERENCE_RTOL * np.abs(kf.x).max())
        np.testing.assert_allclose(ours.cov[i], kf.P, rtol=REFERENCE_RTOL,
                                   atol=REFERENCE_RTOL * np.abs(kf.P).max())


@pytest.mark.parametrize("case", range(4))
def test_batched_equals_one_at_a_time(rng: np.random.Generator, case: int) -> None:
    p = random_problem(rng)
    batch = Gaussians(p["mean"], p["cov"])
    predicted = kf_predict(batch, p["F"], p["Q"])
    updated = kf_update(predicted, p["z"], p["Hn"], p["Rn"])
    for i in range(len(batch)):
        one = kf_update(kf_predict(batch.take([i]), p["F"], p["Q"]), p["z"][[i]],
                        p["Hn"][[i]], p["Rn"][[i]])
        np.testing.assert_allclose(updated.mean[i], one.mean[0], rtol=BATCH_RTOL,
                                   atol=BATCH_RTOL * np.abs(one.mean).max())
        np.testing.assert_allclose(updated.cov[i], one.cov[0], rtol=BATCH_RTOL,
                                   atol=BATCH_RTOL * np.abs(one.cov).max())


def test_update_mutates_nothing(rng: np.random.Generator) -> None:
    p = random_problem(rng)
    before = {k: np.copy(v) for k, v in p.items()}
    kf_update(kf_predict(Gaussians(p["mean"], p["cov"]), p["F"], p["Q"]), p["z"], p["H"], p["R"])
    for key, value in before.items():
        np.testing.assert_array_equal(p[key], value, err_msg=f"{key} was modified")


def test_update_with_exact_measurement_of_a_broad_prior_returns_it() -> None:
    # analytic: scalar prior N(0, 1e6), z = 3 with R = 1 → mean 3·1e6/(1e6+1), P = 1e6/(1e6+1)
    post = kf_update(Gaussians(np.zeros((1, 1)), np.full((1, 1, 1), 1e6)), np.array([[3.0]]),
                     np.eye(1), np.eye(1))
    np.testing.assert_allclose(post.mean, [[3e6 / (1e6 + 1)]], rtol=1e-14)  # round-off only
    np.testing.assert_allclose(post.cov, [[[1e6 / (1e6 + 1)]]], rtol=1e-12)  # Joseph round-off


# ----------------------------------------------------------------------------
# Joseph form: properties
# ----------------------------------------------------------------------------

_entries = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)


@st.composite
def update_problems(draw: st.DrawFn):
    dx = draw(st.integers(1, 5))
    dz = draw(st.integers(1, 3))
    A = draw(arrays(np.float64, (dx, dx), elements=_entries))
    C = draw(arrays(np.float64, (dz, dz), elements=_entries))
    H = draw(arrays(np.float64, (dz, dx), elements=_entries))
    m = draw(arrays(np.float64, (dx,), elements=_entries))
    z = draw(arrays(np.float64, (dz,), elements=_entries))
    P = A @ A.T + 1e-3 * np.eye(dx)  # SPD, condition number up to ~1e5
    R = C @ C.T + 1e-3 * np.eye(dz)
    return m, P, z, H, R


# Tolerances of the property tests, relative to the largest prior variance: round-off
# of the Joseph products grows with cond(P) ≲ 1e5 here, i.e. ≲ 1e-11 relative.
PSD_ATOL_REL = 1e-9


@settings(max_examples=200, deadline=None)
@given(update_problems())
def test_joseph_covariance_is_symmetric_psd_and_shrinks(problem) -> None:
    m, P, z, H, R = problem
    post = kf_update(Gaussians(m[None], P[None]), z[None], H, R)
    cov = post.cov[0]
    np.testing.assert_array_equal(cov, cov.T)  # symmetrised exactly
    tol = PSD_ATOL_REL * np.abs(P).max()
    assert np.linalg.eigvalsh(cov).min() >= -tol, "posterior covariance not PSD"
    # a measurement never adds uncertainty: P_prior − P_post is PSD
    assert np.linalg.eigvalsh(P - cov).min() >= -tol, "posterior larger than prior"
    assert np.isfinite(post.mean).all()


@settings(max_examples=100, deadline=None)
@given(update_problems())
def test_predict_covariance_is_symmetric_psd(problem) -> None:
    m, P, _, _, _ = problem
    dx = m.size
    F = np.eye(dx) + np.tril(np.ones((dx, dx)), -1)
    pred = kf_predict(Gaussians(m[None], P[None]), F, 1e-3 * np.eye(dx))
    np.testing.assert_array_equal(pred.cov[0], pred.cov[0].T)
    assert np.linalg.eigvalsh(pred.cov[0]).min() > 0


# ----------------------------------------------------------------------------
# information form
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("case", range(4))
def test_information_round_trip(rng: np.random.Generator, case: int) -> None:
    p = random_problem(rng)
    belief = Gaussians(p["mean"], p["cov"])
    Lam, eta = to_information(belief)
    # Λ P = I and η = Λ m: the definition
    eye = np.broadcast_to(np.eye(Lam.shape[-1]), Lam.shape)
    np.testing.assert_allclose(Lam @ belief.cov, eye, rtol=0, atol=INFO_RTOL)
    np.testing.assert_allclose(eta, np.einsum("nij,nj->ni", Lam, belief.mean), rtol=INFO_RTOL)
    back = from_information(Lam, eta)
    np.testing.assert_allclose(back.mean, belief.mean, rtol=INFO_RTOL,
                               atol=INFO_RTOL * np.abs(belief.mean).max())
    np.testing.assert_allclose(back.cov, belief.cov, rtol=INFO_RTOL,
                               atol=INFO_RTOL * np.abs(belief.cov).max())
    np.testing.assert_array_equal(Lam, np.swapaxes(Lam, -1, -2))


@pytest.mark.parametrize("case", range(6))
@pytest.mark.parametrize("per_belief", [False, True], ids=["shared-H-R", "per-belief-H-R"])
def test_information_update_equals_kf_update(rng: np.random.Generator, case: int,
                                             per_belief: bool) -> None:
    p = random_problem(rng)
    H, R = (p["Hn"], p["Rn"]) if per_belief else (p["H"], p["R"])
    prior = Gaussians(p["mean"], p["cov"])
    expected = kf_update(prior, p["z"], H, R)
    Lam, eta = information_update(*to_information(prior), p["z"], H, R)
    got = from_information(Lam, eta)
    np.testing.assert_allclose(got.mean, expected.mean, rtol=INFO_RTOL,
                               atol=INFO_RTOL * np.abs(expected.mean).max())
    np.testing.assert_allclose(got.cov, expected.cov, rtol=INFO_RTOL,
                               atol=INFO_RTOL * np.abs(expected.cov).max())


# ----------------------------------------------------------------------------
# log density
# ----------------------------------------------------------------------------

# scipy evaluates the density through an eigendecomposition, we through Cholesky:
# round-off ~1e-13 on values of order 10.
LOGPDF_ATOL = 1e-9


@pytest.mark.parametrize("d", [1, 2, 4])
def test_logpdf_equals_scipy(rng: np.random.Generator, d: int) -> None:
    n = 7
    cov = random_spd(rng, d, n)
    residual = 2.0 * rng.standard_normal((n, d))
    got = gaussian_logpdf(residual, cov)
    want = [multivariate_normal(np.zeros(d), cov[i]).logpdf(residual[i]) for i in range(n)]
    assert got.shape == (n,)
    np.testing.assert_allclose(got, want, rtol=0, atol=LOGPDF_ATOL)


def test_logpdf_broadcasts(rng: np.random.Generator) -> None:
    # residuals (m, n, d) against covariances (n, d, d) and against one shared (d, d)
    m, n, d = 5, 3, 2
    cov = random_spd(rng, d, n)
    residual = rng.standard_normal((m, n, d))
    got = gaussian_logpdf(residual, cov)
    assert got.shape == (m, n)
    for j in range(n):
        want = multivariate_normal(np.zeros(d), cov[j]).logpdf(residual[:, j])
        np.testing.assert_allclose(got[:, j], want, rtol=0, atol=LOGPDF_ATOL)
    shared = gaussian_logpdf(residual, cov[0])
    want = multivariate_normal(np.zeros(d), cov[0]).logpdf(residual.reshape(-1, d))
    np.testing.assert_allclose(shared.ravel(), want, rtol=0, atol=LOGPDF_ATOL)


def test_symmetrize_is_exact() -> None:
    a = np.arange(9.0).reshape(3, 3) / 7
    s = symmetrize(a)
    np.testing.assert_array_equal(s, s.T)
    np.testing.assert_allclose(s, (a + a.T) / 2, rtol=1e-15)  # the definition


def test_block_diagonal_equals_scipy(rng):
    from scipy.linalg import block_diag

    from cooploc.gaussian import block_diagonal

    stacks = [rng.normal(size=(3, 4, 4)), rng.normal(size=(1, 7, 7)), np.zeros((0, 2, 2)),
              rng.normal(size=(2, 2, 2))]
    expected = block_diag(*[block for stack in stacks for block in stack])
    np.testing.assert_array_equal(block_diagonal(*stacks), expected)  # pure copies, exact
    assert block_diagonal().shape == (0, 0)


# -- normalised innovation squared (issue 16 item 8) ------------------------------------


def test_nis_of_hand_computed_updates() -> None:
    # 1-D: P⁻ = 3, R = 1 → S = 4; ν = 2 → NIS = 4 / 4 = 1
    _, one = kf_update_nis(Gaussians(np.zeros((1, 1)), np.full((1, 1, 1), 3.0)), np.array([[2.0]]),
                           np.eye(1), np.eye(1))
    # 2-D: S = diag(1, 2) + diag(1, 2) = diag(2, 4); ν = [3, 6] − [1, 2] = [2, 4] → 4/2 + 16/4 = 6
    _, two = kf_update_nis(Gaussians(np.array([[1.0, 2.0]]), np.diag([1.0, 2.0])[None]),
                           np.array([[3.0, 6.0]]), np.eye(2), np.diag([1.0, 2.0]))
    np.testing.assert_allclose([one[0], two[0]], [1.0, 6.0], rtol=1e-14)   # exact but for round-off
    np.testing.assert_allclose(nis(np.array([2.0, 4.0]), np.diag([2.0, 4.0])), 6.0, rtol=1e-14)


@pytest.mark.parametrize("case", range(6))
@pytest.mark.parametrize("per_belief", [False, True], ids=["shared-H-R", "per-belief-H-R"])
def test_nis_equals_explicit_inverse_and_scipy_density(rng: np.random.Generator, case: int,
                                                       per_belief: bool) -> None:
    p = random_problem(rng)
    H, R = (p["Hn"], p["Rn"]) if per_belief else (p["H"], p["R"])
    prior = Gaussians(p["mean"], p["cov"])
    post, ours = kf_update_nis(prior, p["z"], H, R)
    # the update itself is kf_update's, bit for bit
    plain = kf_update(prior, p["z"], H, R)
    assert np.array_equal(post.mean, plain.mean) and np.array_equal(post.cov, plain.cov)
    for i in range(len(p["mean"])):
        Hi, Ri = (H[i], R[i]) if per_belief else (H, R)
        S = Hi @ p["cov"][i] @ Hi.T + Ri
        nu = p["z"][i] - Hi @ p["mean"][i]
        explicit = nu @ np.linalg.inv(S) @ nu
        # log N(z; H m, S) = −(dz log 2π + log|S| + NIS) / 2
        dz = nu.size
        from_density = (-2.0 * multivariate_normal(Hi @ p["mean"][i], S).logpdf(p["z"][i])
                        - dz * np.log(2 * np.pi) - np.linalg.slogdet(S)[1])
        np.testing.assert_allclose(ours[i], explicit, rtol=REFERENCE_RTOL)
        # the density route loses absolute precision in log|S| + dz log 2π (~1e-14 each)
        np.testing.assert_allclose(ours[i], from_density, rtol=1e-8, atol=1e-10)


def test_nis_of_a_consistent_model_is_chi2(rng: np.random.Generator) -> None:
    # x ~ N(m, P), z = H x + w: the innovations are N(0, S), so Σ NIS ~ χ²(n dz)
    from scipy.stats import chi2

    n, dx, dz = 4000, 4, 2
    P = random_spd(rng, dx, n)
    mean = rng.standard_normal((n, dx))
    x = mean + np.einsum("nij,nj->ni", np.linalg.cholesky(P), rng.standard_normal((n, dx)))
    H, R = rng.standard_normal((dz, dx)), random_spd(rng, dz)
    z = x @ H.T + rng.standard_normal((n, dz)) @ np.linalg.cholesky(R).T
    _, values = kf_update_nis(Gaussians(mean, P), z, H, R)
    low, high = chi2.ppf([0.0005, 0.9995], n * dz)   # 99.9 %: a fixed seed, but no luck needed
    assert low <= values.sum() <= high


def test_nis_survives_the_square_root_fallback() -> None:
    # S = [[1, 1], [1, 1]] + 1e-20 I is singular in float64 (the fallback case of
    # test_estimator_failures); exactly, ν = [1, 3] gives NIS = 4²/(2 (2 + ε)) + 2²/(2 ε) ≈ 2e20
    prior = Gaussians(np.zeros((1, 2)), np.eye(2)[None])
    H = np.array([[1.0, 0.0], [1.0, 0.0]])
    post, values = kf_update_nis(prior, np.array([[1.0, 3.0]]), H, 1e-20 * np.eye(2))
    assert np.array_equal(post.mean, kf_update(prior, np.array([[1.0, 3.0]]), H, 1e-20 * np.eye(2)).mean)
    # QR of a pre-array spanning 10 orders of magnitude: ~1e-16 × 1e10 relative
    np.testing.assert_allclose(values, [2e20], rtol=1e-6)


# ----------------------------------------------------------------------------
# rows relating two states (stochastic cloning)
# ----------------------------------------------------------------------------

@pytest.mark.parametrize("case", range(4))
def test_relative_update_is_the_conditional_of_the_joint(rng: np.random.Generator, case: int) -> None:
    # x_{k−1} ~ N(m, P), x_k = F x_{k−1} + q, z = H x_k − H x_{k−1} + w: the posterior of
    # x_k is the Gaussian conditional of (x_k, z), built here from their joint moments
    # without any clone, and the likelihood is scipy's density of z
    p = random_problem(rng)
    n, dx = p["mean"].shape
    dz = p["H"].shape[0]
    F, Q, H, P, m = p["F"], p["Q"], p["H"], p["cov"], p["mean"]
    previous = Gaussians(m, P)
    predicted = kf_predict(previous, F, Q)
    post, nis_of, log_q = kf_update_relative(previous, predicted, F, p["z"], H, p["Rn"])
    for i in range(n):
        C_xx = F @ P[i] @ F.T + Q
        D = (F - np.eye(dx)) @ P[i] @ (F - np.eye(dx)).T + Q              # Cov(x_k − x_{k−1})
        C_xz = C_xx @ H.T - F @ P[i] @ H.T
        C_zz = H @ D @ H.T + p["Rn"][i]
        mz = H @ (F - np.eye(dx)) @ m[i]
        r = p["z"][i] - mz
        gain = np.linalg.solve(C_zz, C_xz.T).T
        np.testing.assert_allclose(post.mean[i], F @ m[i] + gain @ r, rtol=REFERENCE_RTOL, atol=1e-10)
        np.testing.assert_allclose(post.cov[i], C_xx - gain @ C_xz.T, rtol=REFERENCE_RTOL, atol=1e-10)
        np.testing.assert_allclose(nis_of[i], r @ np.linalg.solve(C_zz, r), rtol=REFERENCE_RTOL)
        want = multivariate_normal(mz, C_zz).logpdf(p["z"][i])
        np.testing.assert_allclose(log_q[i], want, rtol=0, atol=LOGPDF_ATOL)
    assert post.mean.shape == (n, dx) and nis_of.shape == log_q.shape == (n,) and dz >= 1
