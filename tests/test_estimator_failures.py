"""Numerical trouble inside an estimator (issue 16 item 4): recovered where a square-root form
avoids it, otherwise an `EstimatorError` naming the estimator and what broke — never a NumPy
`LinAlgError`, a GTSAM `RuntimeError`, or an `InvalidInputError` with an array dump.

Each case is a recording made hostile by surgery: covariances scaled by many orders of
magnitude, a prior moved a million metres away, GNSS rows with near-singular covariances.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cooploc.errors import EstimatorError
from cooploc.estimators.base import checked_states
from cooploc.experiment import estimate
from cooploc.gaussian import Gaussians, kf_update, kf_update_square_root
from cooploc.registry import construct, get_estimator
from cooploc.types import Batch, Frame, Recording, StateSet
from helpers import preset_recording, run_estimator


def scaled_rows(recording: Recording, factor: float, kinds: tuple[str, ...] | None = None) -> Recording:
    """Every row covariance of `kinds` (default all) × factor."""
    frames = [Frame(f.k, f.t, f.vehicles, {
        kind: Batch(b.z, b.cov * factor, b.sensor, b.subject) if kinds is None or kind in kinds else b
        for kind, b in f.batches.items()}, f.links) for f in recording.frames]
    return dataclasses.replace(recording, frames=frames)


def scaled_prior(recording: Recording, factor: float = 1.0, shift: float = 0.0) -> Recording:
    """The vehicle prior with covariances × factor and positions moved by `shift` m."""
    prior = recording.setup.vehicle_prior
    mean = prior.mean.copy()
    mean[:, list(recording.setup.vehicle_layout.position)] += shift
    setup = dataclasses.replace(recording.setup, vehicle_prior=StateSet(prior.ids, mean, prior.cov * factor))
    return dataclasses.replace(recording, setup=setup)


def near_singular_rows(recording: Recording, kind: str, eps: float) -> Recording:
    """Rows of `kind` with covariance v [[1, 1 − eps], [1 − eps, 1]] (v: their mean variance)."""
    frames = []
    for f in recording.frames:
        batches = dict(f.batches)
        b = batches[kind]
        var = np.einsum("mii->m", b.cov) / 2
        batches[kind] = Batch(b.z, var[:, None, None] * np.array([[1, 1 - eps], [1 - eps, 1]]),
                              b.sensor, b.subject)
        frames.append(Frame(f.k, f.t, f.vehicles, batches, f.links))
    return dataclasses.replace(recording, frames=frames)


def assert_fails_cleanly(name: str, recording: Recording, says: str) -> None:
    cls = get_estimator(name)
    with pytest.raises(EstimatorError) as info:
        est = construct(cls, recording.setup, None, np.random.default_rng(0),
                        truth=recording.truth if cls.needs_truth else None)
        estimate(est, recording)   # with the smoother's final solve where there is one
    error = info.value
    assert error.estimator == name and says in error.what, str(error)
    assert "[[" not in str(error) and "\n" not in str(error), "no array dump, one line"


@pytest.fixture(scope="module")
def zhang() -> Recording:
    return preset_recording("zhang2016-cv", 0, {"n_steps": 10})


@pytest.fixture(scope="module")
def froehle() -> Recording:
    return preset_recording("froehle2018", 0, {"n_steps": 10})


@pytest.fixture(scope="module")
def gulati() -> Recording:
    return preset_recording("gulati-2v", 0, {"n_steps": 20})


# -- failures named ----------------------------------------------------------------


def test_sme_ukf_with_its_prior_a_million_metres_off(zhang):
    # before: numpy LinAlgError "Singular matrix" from K = C S⁻¹
    assert_fails_cleanly("sme-ukf", scaled_prior(zhang, shift=1e6), "innovation covariance")


def test_sme_ukf_with_a_prior_covariance_beyond_float64(zhang):
    # before: LinAlgError "Matrix is not positive definite" from the sigma points' Cholesky factor
    assert_fails_cleanly("sme-ukf", scaled_prior(zhang, 1e25), "sigma points")


def test_gm_phd_with_a_prior_covariance_beyond_float64(zhang):
    # before: LinAlgError from merge_components' Cholesky factor
    assert_fails_cleanly("gm-phd", scaled_prior(zhang, 1e25), "Joseph update")


def test_a_kalman_filter_whose_posterior_float64_cannot_hold_names_the_vehicle(froehle):
    # before: InvalidInputError "StateSet.cov[0] is not positive definite ... [[0.01, ..." as if
    # the user's input were wrong
    assert_fails_cleanly("gnss-kf", scaled_prior(froehle, 1e25), "covariance of vehicle 0")


def test_factor_graphs_with_covariances_thirty_orders_apart(gulati):
    # before: scipy LinAlgError "79-th leading minor not positive definite"
    hostile = scaled_rows(gulati, 1e-30, ("odometry", "radar"))
    assert_fails_cleanly("fg-topology-new", hostile, "information matrix")
    assert_fails_cleanly("fg-topology-old", hostile, "information matrix")


@pytest.mark.parametrize("surgery", ["near-singular GNSS", "odometry and radar × 1e-12"])
def test_isam2_on_an_indeterminate_system(gulati, surgery):
    # before: GTSAM RuntimeError "Indeterminate linear system ..." over twelve lines
    hostile = (near_singular_rows(gulati, "gnss", 1e-12) if surgery == "near-singular GNSS"
               else scaled_rows(gulati, 1e-12, ("odometry", "radar")))
    assert_fails_cleanly("fg-isam2", hostile, "Indeterminate linear system")


# -- recovered ---------------------------------------------------------------------


@pytest.mark.parametrize("factor", [1e-20, 1e-30])
def test_oracle_kf_recovers_from_rows_below_round_off(froehle, factor):
    # before: LinAlgError "Singular matrix": R vanishes in S = H P Hᵀ + R. The square-root
    # form never forms S, so the joint update goes through.
    hostile = scaled_prior(scaled_rows(froehle, factor), factor)
    estimates = run_estimator("oracle-kf", hostile)
    for frame, est in zip(hostile.frames, estimates, strict=True):
        # StateSet checked them symmetric positive definite (Cholesky); eigenvalues spanning
        # 24 orders of magnitude are beyond what eigvalsh resolves, so no stricter check here
        assert np.array_equal(est.vehicles.ids, np.sort(frame.vehicles))
    truth = hostile.truth
    errors = [np.linalg.norm(e.vehicles.mean[:, :2] - truth.vehicles_at(k, e.vehicles.ids)[:, :2], axis=1)
              for k, e in enumerate(estimates)]
    # the rows are trusted absolutely, so the error is the rows' own noise (GNSS σ ≈ 3.9 m)
    assert np.max(errors) < 20.0


def test_oracle_kf_recovers_from_a_prior_beyond_float64(froehle):
    # the dense joint filter failed here like gnss-kf ("covariance of vehicle 0"); the
    # component form falls back per component to the square-root update, whose posterior
    # after the first fix is that fix: the prior (× 1e25) carries no information
    hostile = scaled_prior(froehle, 1e25)
    estimates = run_estimator("oracle-kf", hostile)
    gnss = hostile.frames[0].batches["gnss"]
    first = estimates[0].vehicles
    # GNSS covariances 0.01 and 15 m²: what is left of the prior is ~1e-25 relative
    np.testing.assert_allclose(first.cov[:, :2, :2], gnss.cov[np.argsort(gnss.subject)], rtol=1e-6)
    for k, est in enumerate(estimates):
        assert np.array_equal(est.vehicles.ids, np.sort(hostile.frames[k].vehicles))


def test_square_root_update_equals_joseph_where_both_work():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(5, 4, 4))
    B = rng.normal(size=(5, 2, 2))
    prior = Gaussians(rng.normal(size=(5, 4)), A @ A.transpose(0, 2, 1) + np.eye(4))
    H, R, z = rng.normal(size=(2, 4)), B @ B.transpose(0, 2, 1) + np.eye(2), rng.normal(size=(5, 2))
    joseph, root = kf_update(prior, z, H, R), kf_update_square_root(prior, z, H, R)
    np.testing.assert_allclose(root.mean, joseph.mean, rtol=1e-10, atol=1e-12)   # round-off only
    np.testing.assert_allclose(root.cov, joseph.cov, rtol=1e-10, atol=1e-12)


def test_kf_update_falls_back_where_the_innovation_covariance_is_singular():
    # two fixes of one component with R = 1e-20: S = [[1, 1], [1, 1]] + 1e-20 I is singular in
    # float64; the exact posterior is their average with variance 0.5e-20
    prior = Gaussians(np.zeros((1, 2)), np.eye(2)[None])
    H = np.array([[1.0, 0.0], [1.0, 0.0]])
    post = kf_update(prior, np.array([[1.0, 3.0]]), H, 1e-20 * np.eye(2))
    # QR of a pre-array whose entries span 10 orders of magnitude: ~1e-16 × 1e10 relative
    np.testing.assert_allclose(post.mean, [[2.0, 0.0]], rtol=1e-6)
    np.testing.assert_allclose(post.cov[0], np.diag([0.5e-20, 1.0]), rtol=1e-6, atol=1e-26)


def test_checked_states_passes_good_beliefs_and_names_broken_ones():
    ids, mean, cov = np.array([4, 7]), np.zeros((2, 2)), np.repeat(np.eye(2)[None], 2, axis=0)
    states = checked_states("x", "vehicle", ids, mean, cov)
    assert isinstance(states, StateSet) and states.ids.tolist() == [4, 7]
    bad_mean = mean.copy()
    bad_mean[1, 0] = np.nan
    with pytest.raises(EstimatorError, match=r"^x failed: the belief of vehicle 7 is not finite"):
        checked_states("x", "vehicle", ids, bad_mean, cov)
    bad_cov = cov.copy()
    bad_cov[1] = [[1.0, 2.0], [2.0, 1.0]]
    with pytest.raises(EstimatorError, match=r"^x failed: the covariance of feature 7 is no longer"):
        checked_states("x", "feature", ids, mean, bad_cov)
