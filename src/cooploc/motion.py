"""Linear-Gaussian motion models in 2-D: x_k = F x_{k-1} + B u_k + w_k, w_k ~ N(0, Q).

State layout is [p_x, p_y, v_x, v_y] (m, m/s) for all three models, as in Fröhle et
al. 2018, eq. (28): A = [[1, ΔT], [0, 1]] ⊗ I_2.

- `ConstantVelocity` — Fröhle eqs. (28)–(29): continuous white-acceleration noise of
  spectral density r (m²/s³), Q = r [[ΔT³/3, ΔT²/2], [ΔT²/2, ΔT]] ⊗ I_2.
- `ConstantTurn` — coordinated turn with a known turn rate ω (rad/s) (Bar-Shalom,
  Li & Kirubarajan 2001, §11.7; Zhang et al. 2016, eq. 14). ω → 0 gives the CV model.
  The noise is the CV noise of the same density: exact for ω = 0, and for the small
  rates of the papers (|ωΔT| ≪ 1) the difference is below the round-off of a step.
- `CVAccelerationInput` — CV driven by a measured acceleration u (IMU), Brambilla et
  al. 2020, eq. (1): x_k = F x_{k-1} + B (u_k + n_k) with B = [ΔT²/2; ΔT] ⊗ I_2 and
  n_k ~ N(0, R(ψ) diag(σ²_a,∥, σ²_a,⊥) R(ψ)ᵀ), the along/cross-track axes turned to
  each vehicle's driving direction ψ = atan2(v_y, v_x). Q is then rank 2 (singular).
- `CVVelocityNoise` — CV whose velocity takes random-walk steps turned to the direction
  of motion, Brambilla 2020 §V-B for features (pedestrians on sidewalks):
  x_k = F x_{k-1} + G n_k, G = [ΔT; 1] ⊗ I_2, n_k ~ N(0, R(ψ) diag(σ²_v,∥, σ²_v,⊥) R(ψ)ᵀ).
  With σ = 0 it is the static (or constant-velocity) feature of §V-A.

- `RandomWalk` — pose random walk on [p_x, p_y, α] (m, m, rad): F = I, Q = ΔT diag(q_p,
  q_p, q_α). The prediction model of the `aoa-grid` tracking option (issue 7), where
  the state holds no velocity.

Simulation helpers sample forward (`simulate`) and backward in time
(`simulate_backward`: x_{k-1} = F⁻¹(x_k − w_k), so the forward relation holds exactly
for the drawn noise), as Williams 2015 §VI does for targets that cross at mid-run.

Complexity: O(n dx²) per step for n entities.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np

from cooploc.errors import InvalidInputError
from cooploc.geometry import rotation
from cooploc.types import FloatArray, MotionModel

__all__ = [
    "CVAccelerationInput",
    "CVVelocityNoise",
    "ConstantTurn",
    "ConstantVelocity",
    "RandomWalk",
    "motion_from_dict",
    "sample_gaussian",
    "simulate",
    "simulate_backward",
]


def _cv_blocks(dt: float) -> tuple[FloatArray, FloatArray]:
    F = np.kron(np.array([[1.0, dt], [0.0, 1.0]]), np.eye(2))                      # eq. (28)
    Q1 = np.kron(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]), np.eye(2))   # eq. (29) / r
    return F, Q1


def _check_dt(dt: float) -> float:
    if not np.isfinite(dt) or dt <= 0:
        raise InvalidInputError(f"dt must be a positive number of seconds, got {dt!r}")
    return float(dt)


class _Serialisable:
    """`to_dict` of every model: its name plus its dataclass fields."""

    __slots__ = ()
    name: ClassVar[str]

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.name, **asdict(self)}  # type: ignore[call-overload]


class _WhiteAcceleration(_Serialisable):
    """Noise of the CV model, eq. (29): Q = r [[ΔT³/3, ΔT²/2], [ΔT²/2, ΔT]] ⊗ I_2; no input."""

    __slots__ = ()
    noise_density: float
    state_dependent_noise: ClassVar[bool] = False

    def noise_covariance(self, dt: float, states: FloatArray | None = None) -> FloatArray:
        return self.noise_density * _cv_blocks(_check_dt(dt))[1]

    def control_matrix(self, dt: float) -> FloatArray | None:
        return None


@dataclass(frozen=True, slots=True)
class ConstantVelocity(_WhiteAcceleration):
    """Constant velocity (white-acceleration) model, Fröhle eqs. (28)–(29).

    Parameters
    ----------
    noise_density : r in m²/s³ (the paper's r = 0.1 "m²").
    """

    noise_density: float
    name: ClassVar[str] = "constant-velocity"
    dim: ClassVar[int] = 4

    def __post_init__(self) -> None:
        if not np.isfinite(self.noise_density) or self.noise_density < 0:
            raise InvalidInputError(
                f"ConstantVelocity.noise_density must be >= 0, got {self.noise_density!r}"
            )

    def transition_matrix(self, dt: float) -> FloatArray:
        return _cv_blocks(_check_dt(dt))[0]


@dataclass(frozen=True, slots=True)
class ConstantTurn(_WhiteAcceleration):
    """Coordinated turn with known rate (Zhang 2016, eq. 14).

    Parameters
    ----------
    turn_rate : ω in rad/s (positive = counter-clockwise).
    noise_density : white-acceleration density in m²/s³ (as `ConstantVelocity`).
    """

    turn_rate: float
    noise_density: float
    name: ClassVar[str] = "constant-turn"
    dim: ClassVar[int] = 4

    def __post_init__(self) -> None:
        if not np.isfinite(self.turn_rate):
            raise InvalidInputError(f"ConstantTurn.turn_rate must be finite, got {self.turn_rate!r}")
        if not np.isfinite(self.noise_density) or self.noise_density < 0:
            raise InvalidInputError(
                f"ConstantTurn.noise_density must be >= 0, got {self.noise_density!r}"
            )

    def transition_matrix(self, dt: float) -> FloatArray:
        dt = _check_dt(dt)
        wt = self.turn_rate * dt
        if abs(wt) < 1e-9:  # series limit: the closed form divides by ω
            return _cv_blocks(dt)[0]
        s, c, w = np.sin(wt), np.cos(wt), self.turn_rate
        return np.array([
            [1.0, 0.0, s / w, -(1.0 - c) / w],
            [0.0, 1.0, (1.0 - c) / w, s / w],
            [0.0, 0.0, c, -s],
            [0.0, 0.0, s, c],
        ])


@dataclass(frozen=True, slots=True)
class CVAccelerationInput(_Serialisable):
    """CV driven by a measured acceleration, Brambilla 2020 eq. (1).

    Parameters
    ----------
    sigma_along, sigma_cross : standard deviations (m/s²) of the acceleration noise
        along and across the driving direction.
    """

    sigma_along: float
    sigma_cross: float
    name: ClassVar[str] = "cv-acceleration-input"
    dim: ClassVar[int] = 4
    state_dependent_noise: ClassVar[bool] = True  # Q turns with the driving direction

    def __post_init__(self) -> None:
        for key in ("sigma_along", "sigma_cross"):
            value = getattr(self, key)
            if not np.isfinite(value) or value < 0:
                raise InvalidInputError(f"CVAccelerationInput.{key} must be >= 0, got {value!r}")

    def transition_matrix(self, dt: float) -> FloatArray:
        return _cv_blocks(_check_dt(dt))[0]

    def control_matrix(self, dt: float) -> FloatArray:
        dt = _check_dt(dt)
        return np.kron(np.array([[dt**2 / 2], [dt]]), np.eye(2))

    def noise_covariance(self, dt: float, states: FloatArray | None = None) -> FloatArray:
        """Q (n, 4, 4) = B R(ψ) diag(σ∥², σ⊥²) R(ψ)ᵀ Bᵀ; ψ from each state's velocity."""
        return _turned_noise(self.control_matrix(dt), self.sigma_along, self.sigma_cross, states)


@dataclass(frozen=True, slots=True)
class CVVelocityNoise(_Serialisable):
    """CV with a velocity random walk along/across the direction of motion (Brambilla §V-B).

    Parameters
    ----------
    sigma_along, sigma_cross : standard deviations (m/s) of the velocity step per ΔT
        along and across the direction of motion (paper: v_f/100 and half of that).
    """

    sigma_along: float
    sigma_cross: float
    name: ClassVar[str] = "cv-velocity-noise"
    dim: ClassVar[int] = 4
    state_dependent_noise: ClassVar[bool] = True

    def __post_init__(self) -> None:
        for key in ("sigma_along", "sigma_cross"):
            value = getattr(self, key)
            if not np.isfinite(value) or value < 0:
                raise InvalidInputError(f"CVVelocityNoise.{key} must be >= 0, got {value!r}")

    def transition_matrix(self, dt: float) -> FloatArray:
        return _cv_blocks(_check_dt(dt))[0]

    def control_matrix(self, dt: float) -> FloatArray | None:
        return None

    def noise_covariance(self, dt: float, states: FloatArray | None = None) -> FloatArray:
        """Q (n, 4, 4) = G R(ψ) diag(σ∥², σ⊥²) R(ψ)ᵀ Gᵀ with G = [ΔT; 1] ⊗ I_2."""
        G = np.kron(np.array([[_check_dt(dt)], [1.0]]), np.eye(2))
        return _turned_noise(G, self.sigma_along, self.sigma_cross, states)


def _turned_noise(G: FloatArray, sigma_along: float, sigma_cross: float,
                  states: FloatArray | None) -> FloatArray:
    """G R(ψ) diag(σ∥², σ⊥²) R(ψ)ᵀ Gᵀ per state, ψ = atan2(v_y, v_x) (ψ = 0 when at rest)."""
    states = np.zeros((1, 4)) if states is None else np.atleast_2d(states)
    rot = rotation(np.arctan2(states[:, 3], states[:, 2]))                  # (n, 2, 2)
    noise = rot @ np.diag([sigma_along**2, sigma_cross**2]) @ rot.transpose(0, 2, 1)
    Q = G @ noise @ G.T
    return 0.5 * (Q + Q.transpose(0, 2, 1))


@dataclass(frozen=True, slots=True)
class RandomWalk(_Serialisable):
    """Random walk of a pose [p_x, p_y, α]: x_k = x_{k-1} + w_k, w_k ~ N(0, ΔT diag(q_p, q_p, q_α)).

    Parameters
    ----------
    position_density : q_p in m²/s (per axis).
    heading_density : q_α in rad²/s.
    """

    position_density: float
    heading_density: float
    name: ClassVar[str] = "random-walk"
    dim: ClassVar[int] = 3
    state_dependent_noise: ClassVar[bool] = False

    def __post_init__(self) -> None:
        for key in ("position_density", "heading_density"):
            value = getattr(self, key)
            if not np.isfinite(value) or value < 0:
                raise InvalidInputError(f"RandomWalk.{key} must be >= 0, got {value!r}")

    def transition_matrix(self, dt: float) -> FloatArray:
        _check_dt(dt)
        return np.eye(3)

    def noise_covariance(self, dt: float, states: FloatArray | None = None) -> FloatArray:
        q = self.position_density
        return _check_dt(dt) * np.diag([q, q, self.heading_density])


_MODELS = (ConstantVelocity, ConstantTurn, CVAccelerationInput, CVVelocityNoise, RandomWalk)


def motion_from_dict(data: Mapping[str, Any]) -> MotionModel:
    """Rebuild a motion model from its `to_dict()` form."""
    fields = dict(data)
    name = fields.pop("model", None)
    for model in _MODELS:
        if model.name == name:
            return model(**fields)
    raise InvalidInputError(
        f"motion model {name!r} is unknown; known: {[m.name for m in _MODELS]}"
    )


def sample_gaussian(cov: FloatArray, rng: np.random.Generator, n: int | None = None) -> FloatArray:
    """Zero-mean Gaussian draws with covariance `cov` (d, d) or per row (n, d, d).

    Factorises by Cholesky; singular (PSD) covariances, such as the rank-2 Q of
    `CVAccelerationInput`, fall back to `eigh`. Returns (n, d).
    """
    cov = np.asarray(cov, dtype=float)
    count = cov.shape[0] if cov.ndim == 3 else (1 if n is None else n)
    white = rng.standard_normal((count, cov.shape[-1]))
    return np.einsum("...ij,...j->...i", _square_root(cov), white)


def _square_root(cov: FloatArray) -> FloatArray:
    """A matrix L with L Lᵀ = cov (batched)."""
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        eigval, eigvec = np.linalg.eigh(cov)
        return eigvec * np.sqrt(np.clip(eigval, 0.0, None))[..., None, :]


def _noise_draws(model: MotionModel, dt: float, n_draws: int, n: int,
                 rng: np.random.Generator) -> FloatArray | None:
    """All (n_draws, n, dx) noise draws at once where Q does not depend on the state."""
    if model.state_dependent_noise:
        return None
    root = _square_root(model.noise_covariance(dt))
    return rng.standard_normal((n_draws, n, model.dim)) @ root.T


def simulate(
    model: MotionModel,
    x0: FloatArray,
    n_steps: int,
    dt: float,
    rng: np.random.Generator,
    controls: FloatArray | None = None,
) -> FloatArray:
    """Sample a trajectory forward: returns (n_steps, n, dx) with x0 (n, dx) at step 0.

    `controls` (n_steps, n, du) is the true input u_k of steps 1.. (row 0 unused); the
    driving noise enters through Q.
    """
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    F = model.transition_matrix(dt)
    B = model.control_matrix(dt)
    noise = _noise_draws(model, dt, max(n_steps - 1, 0), x0.shape[0], rng)
    out = np.empty((n_steps, *x0.shape))
    out[0] = x0
    for k in range(1, n_steps):
        w = noise[k - 1] if noise is not None else sample_gaussian(
            model.noise_covariance(dt, out[k - 1]), rng)
        out[k] = out[k - 1] @ F.T + w
        if B is not None and controls is not None:
            out[k] += controls[k] @ B.T
    return out


def simulate_backward(
    model: MotionModel, x_last: FloatArray, n_steps: int, dt: float, rng: np.random.Generator
) -> FloatArray:
    """Sample backward in time from x_last (n, dx): returns (n_steps, n, dx) ending at x_last.

    x_{k-1} = F⁻¹(x_k − w_k), w_k ~ N(0, Q), so that x_k = F x_{k-1} + w_k holds exactly.
    """
    x_last = np.atleast_2d(np.asarray(x_last, dtype=float))
    F_inv_T = np.linalg.inv(model.transition_matrix(dt)).T  # F is a fixed, well-conditioned 4×4
    noise = _noise_draws(model, dt, max(n_steps - 1, 0), x_last.shape[0], rng)
    out = np.empty((n_steps, *x_last.shape))
    out[-1] = x_last
    for k in range(n_steps - 1, 0, -1):
        w = noise[k - 1] if noise is not None else sample_gaussian(
            model.noise_covariance(dt, out[k]), rng)
        out[k - 1] = (out[k] - w) @ F_inv_T
    return out
