"""`cooploc.motion`: the models' matrices against the papers, and the simulators' statistics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad_vec

from cooploc.errors import InvalidInputError
from cooploc.motion import (
    ConstantTurn,
    ConstantVelocity,
    CVAccelerationInput,
    CVVelocityNoise,
    motion_from_dict,
    sample_gaussian,
    simulate,
    simulate_backward,
)
from helpers import assert_covariance_close

# Matrices built from closed forms by different arithmetic (kron vs literals): round-off.
EXACT_RTOL = 1e-14


# ----------------------------------------------------------------------------
# constant velocity: Fröhle eqs. (28)–(29)
# ----------------------------------------------------------------------------


@pytest.mark.parametrize(("dt", "r"), [(0.5, 0.1), (1.0, 2.0), (0.01, 0.3)])
def test_cv_matrices_equal_froehle_eqs_28_29(dt: float, r: float) -> None:
    model = ConstantVelocity(noise_density=r)
    # eq. (28): A = [[1, ΔT], [0, 1]] ⊗ I_2 on [p_x, p_y, v_x, v_y]
    A = np.array([
        [1.0, 0.0, dt, 0.0],
        [0.0, 1.0, 0.0, dt],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ])
    # eq. (29): R = r [[ΔT³/3, ΔT²/2], [ΔT²/2, ΔT]] ⊗ I_2
    a, b, c = dt**3 / 3, dt**2 / 2, dt
    R = r * np.array([
        [a, 0.0, b, 0.0],
        [0.0, a, 0.0, b],
        [b, 0.0, c, 0.0],
        [0.0, b, 0.0, c],
    ])
    np.testing.assert_allclose(model.transition_matrix(dt), A, rtol=EXACT_RTOL)
    np.testing.assert_allclose(model.noise_covariance(dt), R, rtol=EXACT_RTOL)
    assert model.control_matrix(dt) is None
    assert model.dim == 4


def test_cv_paper_values() -> None:
    # ΔT = 0.5 s, r = 0.1: position variance r ΔT³/3 = 0.1/24, velocity r ΔT = 0.05
    Q = ConstantVelocity(0.1).noise_covariance(0.5)
    np.testing.assert_allclose(np.diag(Q), [0.1 / 24, 0.1 / 24, 0.05, 0.05], rtol=EXACT_RTOL)
    np.testing.assert_allclose(Q[0, 2], 0.1 / 8, rtol=EXACT_RTOL)


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf])
def test_bad_dt_rejected(bad: float) -> None:
    with pytest.raises(InvalidInputError, match="dt"):
        ConstantVelocity(0.1).transition_matrix(bad)


def test_negative_noise_rejected() -> None:
    with pytest.raises(InvalidInputError, match="noise_density"):
        ConstantVelocity(-0.1)
    with pytest.raises(InvalidInputError, match="sigma_along"):
        CVAccelerationInput(-1.0, 1.0)


# ----------------------------------------------------------------------------
# constant turn
# ----------------------------------------------------------------------------


def test_constant_turn_zero_rate_is_cv() -> None:
    dt = 0.5
    np.testing.assert_array_equal(ConstantTurn(0.0, 0.1).transition_matrix(dt),
                                  ConstantVelocity(0.1).transition_matrix(dt))
    np.testing.assert_array_equal(ConstantTurn(0.0, 0.1).noise_covariance(dt),
                                  ConstantVelocity(0.1).noise_covariance(dt))


@pytest.mark.parametrize("omega", [1e-3, 1e-5, 1e-8, 1e-12, -1e-6])
def test_constant_turn_tends_to_cv(omega: float) -> None:
    # F(ω) − F_CV = O(ω ΔT²) (the velocity block is I + O(ωΔT), positions O(ωΔT²/2)),
    # so the distance must shrink at least linearly in ω.
    dt = 0.5
    diff = ConstantTurn(omega, 0.1).transition_matrix(dt) - ConstantVelocity(0.1).transition_matrix(dt)
    assert np.abs(diff).max() <= 2.0 * abs(omega) * dt + 1e-15


@pytest.mark.parametrize("omega", [0.3, -0.7, 2.0])
def test_constant_turn_rotates_velocity(omega: float) -> None:
    dt = 0.5
    F = ConstantTurn(omega, 0.1).transition_matrix(dt)
    c, s = np.cos(omega * dt), np.sin(omega * dt)
    np.testing.assert_allclose(F[2:, 2:], [[c, -s], [s, c]], rtol=EXACT_RTOL)  # v ← R(ωΔT) v
    np.testing.assert_array_equal(F[2:, :2], 0.0)                             # v ignores p
    np.testing.assert_array_equal(F[:2, :2], np.eye(2))
    # position advances by ∫₀^ΔT R(ωτ) v dτ (the vehicle drives along the arc)
    v = np.array([3.0, -1.0])

    def rot(tau: float) -> np.ndarray:
        return np.array([[np.cos(omega * tau), -np.sin(omega * tau)],
                         [np.sin(omega * tau), np.cos(omega * tau)]]) @ v

    arc, _ = quad_vec(rot, 0.0, dt, epsabs=1e-13)
    x = F @ np.r_[0.0, 0.0, v]
    np.testing.assert_allclose(x[:2], arc, rtol=1e-10)  # quadrature error ≲ 1e-13
    np.testing.assert_allclose(np.linalg.norm(x[2:]), np.linalg.norm(v), rtol=EXACT_RTOL)


def test_constant_turn_closes_a_circle() -> None:
    # n steps with n ω ΔT = 2π bring position and velocity back to the start
    n, dt = 40, 0.25
    omega = 2 * np.pi / (n * dt)
    F = ConstantTurn(omega, 0.1).transition_matrix(dt)
    x0 = np.array([5.0, -2.0, 1.5, 0.5])
    # n products of a rotation: round-off accumulates as n · eps
    np.testing.assert_allclose(np.linalg.matrix_power(F, n) @ x0, x0, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------
# CV with acceleration input (Brambilla 2020 eq. 1)
# ----------------------------------------------------------------------------


def test_acceleration_input_noise_along_and_cross() -> None:
    dt, s_along, s_cross = 0.1, 2.0, 0.5
    model = CVAccelerationInput(s_along, s_cross)
    B = np.array([[dt**2 / 2, 0], [0, dt**2 / 2], [dt, 0], [0, dt]])
    np.testing.assert_allclose(model.control_matrix(dt), B, rtol=EXACT_RTOL)
    # driving along +x: along-track noise on x, cross-track on y
    Qx = model.noise_covariance(dt, np.array([[0.0, 0.0, 10.0, 0.0]]))[0]
    np.testing.assert_allclose(Qx[2:, 2:], dt**2 * np.diag([s_along**2, s_cross**2]),
                               rtol=EXACT_RTOL)
    np.testing.assert_allclose(Qx[:2, :2], dt**4 / 4 * np.diag([s_along**2, s_cross**2]),
                               rtol=EXACT_RTOL)
    np.testing.assert_allclose(Qx[:2, 2:], dt**3 / 2 * np.diag([s_along**2, s_cross**2]),
                               rtol=EXACT_RTOL)
    # driving along −y: the axes swap
    Qy = model.noise_covariance(dt, np.array([[0.0, 0.0, 0.0, -3.0]]))[0]
    np.testing.assert_allclose(Qy[2:, 2:], dt**2 * np.diag([s_cross**2, s_along**2]),
                               rtol=0, atol=1e-15)  # cos(−π/2) is 6e-17, not 0
    assert np.linalg.matrix_rank(Qx) == 2  # driven through B: rank 2 of 4


def test_acceleration_input_noise_turns_with_heading(rng: np.random.Generator) -> None:
    dt = 0.2
    model = CVAccelerationInput(1.5, 0.3)
    states = rng.standard_normal((10, 4))
    Q = model.noise_covariance(dt, states)
    assert Q.shape == (10, 4, 4)
    Qx = model.noise_covariance(dt, np.array([[0.0, 0.0, 1.0, 0.0]]))[0]
    psi = np.arctan2(states[:, 3], states[:, 2])
    for i in range(10):
        c, s = np.cos(psi[i]), np.sin(psi[i])
        T = np.kron(np.eye(2), [[c, -s], [s, c]])  # rotate both position and velocity
        np.testing.assert_allclose(Q[i], T @ Qx @ T.T, rtol=0, atol=1e-14)  # round-off


# ----------------------------------------------------------------------------
# sampling and simulation (statistical; pass for any seed, see assert_covariance_close)
# ----------------------------------------------------------------------------


def test_sample_gaussian_covariance(rng: np.random.Generator) -> None:
    cov = np.array([[2.0, 0.6, 0.0], [0.6, 1.0, -0.3], [0.0, -0.3, 0.5]])
    draws = sample_gaussian(cov, rng, 20000)
    assert draws.shape == (20000, 3)
    assert_covariance_close(draws, cov)


def test_sample_gaussian_batched_and_singular(rng: np.random.Generator) -> None:
    # per-row covariances (n, d, d): one draw each
    n = 20000
    cov = np.array([[1.0, 0.9], [0.9, 1.0]])
    draws = sample_gaussian(np.repeat(cov[None], n, 0), rng)
    assert draws.shape == (n, 2)
    assert_covariance_close(draws, cov)
    # a singular covariance (rank 2 of 4, as CVAccelerationInput's Q) samples its range
    Q = CVAccelerationInput(1.0, 0.5).noise_covariance(0.5)[0]
    assert_covariance_close(sample_gaussian(Q, rng, n), Q)


@pytest.mark.parametrize("model", [ConstantVelocity(0.1), ConstantTurn(0.4, 0.2),
                                   CVAccelerationInput(1.0, 0.2), CVVelocityNoise(0.3, 0.1)],
                         ids=lambda m: m.name)
def test_simulate_backward_satisfies_forward_model(model, rng: np.random.Generator) -> None:
    n, T, dt = 4000, 6, 0.5
    x_last = 3.0 * rng.standard_normal((n, 4)) + np.array([0.0, 0.0, 5.0, 0.0])
    path = simulate_backward(model, x_last, T, dt, rng)
    assert path.shape == (T, n, 4)
    np.testing.assert_array_equal(path[-1], x_last)
    F = model.transition_matrix(dt)
    w = path[1:] - path[:-1] @ F.T  # x_k = F x_{k−1} + w_k
    if model.state_dependent_noise:
        # whiten each w_k with its own Q (drawn at x_k): ≈ standard normal on the range
        Q = np.stack([model.noise_covariance(dt, path[k]) for k in range(1, T)])
        for k in range(T - 1):
            eigval, eigvec = np.linalg.eigh(Q[k])
            white = np.einsum("nij,ni->nj", eigvec[:, :, 2:], w[k]) / np.sqrt(eigval[:, 2:])
            assert_covariance_close(white, np.eye(2))
            # and nothing outside the range of B (Q is singular): round-off only
            null = np.einsum("nij,ni->nj", eigvec[:, :, :2], w[k])
            np.testing.assert_allclose(null, 0.0, rtol=0, atol=1e-9 * np.abs(path).max())
    else:
        assert_covariance_close(w.reshape(-1, 4), model.noise_covariance(dt))


def test_simulate_forward_statistics(rng: np.random.Generator) -> None:
    model, n, T, dt = ConstantVelocity(0.3), 5000, 5, 0.5
    x0 = rng.standard_normal((n, 4))
    path = simulate(model, x0, T, dt, rng)
    np.testing.assert_array_equal(path[0], x0)
    w = path[1:] - path[:-1] @ model.transition_matrix(dt).T
    assert_covariance_close(w.reshape(-1, 4), model.noise_covariance(dt))


def test_simulate_forward_with_controls(rng: np.random.Generator) -> None:
    # zero acceleration noise: the path is F x + B u exactly
    model, dt = CVAccelerationInput(0.0, 0.0), 0.1
    x0 = np.array([[0.0, 0.0, 1.0, 0.0]])
    u = np.tile([[[0.5, -0.2]]], (4, 1, 1))
    path = simulate(model, x0, 4, dt, rng, controls=u)
    F, B = model.transition_matrix(dt), model.control_matrix(dt)
    x = x0[0]
    for k in range(1, 4):
        x = F @ x + B @ u[k, 0]
        np.testing.assert_allclose(path[k, 0], x, rtol=0, atol=1e-14)  # round-off


@pytest.mark.parametrize("model", [ConstantVelocity(0.1), ConstantTurn(0.4, 0.2),
                                   CVAccelerationInput(1.0, 0.2), CVVelocityNoise(0.3, 0.1)],
                         ids=lambda m: m.name)
def test_motion_from_dict_round_trip(model) -> None:
    again = motion_from_dict(model.to_dict())
    assert again == model
    assert type(again) is type(model)


def test_motion_from_dict_unknown_model() -> None:
    with pytest.raises(InvalidInputError, match="unknown"):
        motion_from_dict({"model": "teleport"})
