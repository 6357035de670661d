"""Sensor models: simulation of measurement batches and their likelihoods.

- `GnssPosition` — absolute position of a vehicle, Fröhle 2018 eq. (30):
  z = H x + w, H = [1 0]ᵀ ⊗ I_2 picks the position, w ~ N(0, W_s) with a covariance
  per vehicle s (W_s = σ_s² I_2 in the paper). `state_indices` selects other
  components (e.g. position and velocity for Brambilla 2020 eq. (3)).
- `RelativePosition` — vehicle-to-feature (V2F) relative position, Fröhle §V-A:
  z = H f_k − H x_s + w, i.e. H^(V2F) = [H, −H] on [f; x], w ~ N(0, W_s) with a
  covariance per sensing vehicle. The association is unknown to the receiver: rows
  carry `subject = -1` and their order is shuffled per vehicle; the true feature id is
  returned separately as the row's origin (truth). Optional missed detections
  (probability 1 − P_D) and Poisson clutter (rate λ per vehicle and step, uniform over
  a box in measurement space, origin −1).
- `AnonymousPosition` — absolute position rows that reach the fusion centre without
  the identity of the vehicle they came from (Zhang 2016 §3.2, "internal sensor"):
  z = H x + w as `GnssPosition`, but `sensor` = `subject` = −1 and rows shuffled; the
  true vehicle id is returned as the row's origin. Optional P_D and clutter.
- `InfrastructureRadar` — a road-side sensor with pose (t, θ) (position t ∈ R², yaw θ)
  that reports every vehicle in range in its own frame, anonymously (Zhang 2016 §3.2,
  Gulati §II): z = R(θ)ᵀ (H x − t) + w, w ~ N(0, W_radar). The pose is random per
  run and unknown to the estimators (it is kept in `Truth.sensor_poses`). A vehicle is
  reported when it lies within `max_range` of t and within the field of view: its
  bearing in the radar's frame, atan2 of the noise-free local position, is at most
  `field_of_view` (a half-angle about the radar's x axis, the boresight; π: all around,
  the papers' radar).
- `Odometry` — displacement of each vehicle since the previous step, in the global
  frame (Gulati eq. 4 for the constant-velocity model): z_k = H x_k − H x_{k−1} + w,
  w ~ N(0, W_s). A vehicle that enters at step k has no odometry row at k.

- `AngleOfArrival` — angle of arrival of a neighbour's V2V signal relative to the
  receiver's heading (issue 7, `papers/plbp_model_notes.md` "Model"):
  θ_{i←j} = wrap(atan2(p_{j,y} − p_{i,y}, p_{j,x} − p_{i,x}) − α_i) + w, w ~ N(0, σ_θ²),
  measured by two side-mounted linear arrays (normals at ±π/2 relative to the heading)
  that each see ±Δ around their normal; the transmitter's identity is known (it rides
  on the V2V message): `sensor` = receiver id, `subject` = transmitter id. The reading
  is wrapped to [−π, π).

Every simulator is vectorised over entities (and vehicle × feature pairs) and takes
the random generator as an argument.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from cooploc.errors import InvalidInputError
from cooploc.gaussian import gaussian_logpdf
from cooploc.geometry import to_local, wrap_angle
from cooploc.motion import sample_gaussian
from cooploc.types import Batch, FloatArray, IntArray, SensorModel, check_covariances, float_array

__all__ = [
    "AngleOfArrival",
    "AnonymousPosition",
    "GnssPosition",
    "InfrastructureRadar",
    "Odometry",
    "RelativePosition",
    "selection_matrix",
    "sensor_from_dict",
]


def selection_matrix(indices: tuple[int, ...], dim: int) -> FloatArray:
    """H (len(indices), dim) that picks the given state components."""
    H = np.zeros((len(indices), dim))
    H[np.arange(len(indices)), indices] = 1.0
    return H


@dataclass(frozen=True)
class _PerEntityCovariance:
    """Noise covariance per entity id, with a default for ids not listed."""

    covariances: Mapping[int, FloatArray] = field(default_factory=dict)
    default_cov: FloatArray | None = None
    state_indices: tuple[int, ...] = (0, 1)

    def __post_init__(self) -> None:
        dz = len(self.state_indices)
        cls = type(self).__name__
        covs = {}
        for key, value in dict(self.covariances).items():
            cov = float_array(f"{cls}.covariances[{key}]", value, (dz, dz))
            check_covariances(f"{cls}.covariances[{key}]", cov[None])
            covs[int(key)] = cov
        object.__setattr__(self, "covariances", covs)
        if self.default_cov is not None:
            cov = float_array(f"{cls}.default_cov", self.default_cov, (dz, dz))
            check_covariances(f"{cls}.default_cov", cov[None])
            object.__setattr__(self, "default_cov", cov)
        object.__setattr__(self, "state_indices", tuple(int(i) for i in self.state_indices))

    @property
    def dim(self) -> int:
        return len(self.state_indices)

    def covariance_of(self, ids: npt.ArrayLike) -> FloatArray:
        """(n, dz, dz) noise covariance of each entity id."""
        ids = np.asarray(ids, dtype=np.int64)
        if not self.covariances and self.default_cov is not None:  # one for all: no loop over ids
            return np.broadcast_to(self.default_cov, (ids.size, self.dim, self.dim)).copy()
        out = np.empty((ids.size, self.dim, self.dim))
        for i, entity in enumerate(ids.tolist()):
            cov = self.covariances.get(entity, self.default_cov)
            if cov is None:
                raise InvalidInputError(
                    f"{type(self).__name__} has no covariance for entity {entity} and no default_cov"
                )
            out[i] = cov
        return out

    def observation_matrix(self, dim: int) -> FloatArray:
        return selection_matrix(self.state_indices, dim)

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.name,  # type: ignore[attr-defined]
            "covariances": {str(k): v.tolist() for k, v in self.covariances.items()},
            "default_cov": None if self.default_cov is None else self.default_cov.tolist(),
            "state_indices": list(self.state_indices),
        }


@dataclass(frozen=True)
class GnssPosition(_PerEntityCovariance):
    """GNSS fix of each vehicle: z = H x + w, w ~ N(0, W_s) (Fröhle eq. 30)."""

    name: ClassVar[str] = "gnss-position"

    def measure(self, ids: npt.ArrayLike, states: FloatArray, rng: np.random.Generator) -> Batch:
        """One fix per vehicle: ids (n,), true states (n, dx) → Batch with sensor = subject = id."""
        ids = np.asarray(ids, dtype=np.int64)
        cov = self.covariance_of(ids)
        H = self.observation_matrix(states.shape[1])
        z = states @ H.T + sample_gaussian(cov, rng) if ids.size else np.zeros((0, self.dim))
        return Batch(z, cov, ids, ids)

    def log_likelihood(self, batch: Batch, states: FloatArray) -> FloatArray:
        """log p(z_m | x) for every row m against states (..., M, dx) aligned with rows."""
        H = self.observation_matrix(states.shape[-1])
        return gaussian_logpdf(batch.z - states @ H.T, batch.cov)


def _check_range(model: Any) -> None:
    """`max_range` of a sensor model: > 0 (``inf``: unlimited), stored as a float."""
    if not model.max_range > 0:
        raise InvalidInputError(f"{type(model).__name__}.max_range must be > 0, got {model.max_range!r}")
    object.__setattr__(model, "max_range", float(model.max_range))


@dataclass(frozen=True)
class RelativePosition(_PerEntityCovariance):
    """V2F relative position: z = H f − H x + w, covariance per sensing vehicle (Fröhle §V-A).

    `max_range` declares the sensing range R_s (m) the scenario applies through
    `measure`'s ``visible`` mask (``inf``: every feature is in range); estimators read it
    to tell a missed detection from a feature out of range.
    """

    name: ClassVar[str] = "relative-position"
    max_range: float = float("inf")

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_range(self)

    def to_dict(self) -> dict[str, Any]:
        # an unlimited range is left out, so setups without one keep their setup.json
        finite = {"max_range": self.max_range} if np.isfinite(self.max_range) else {}
        return {**super().to_dict(), **finite}

    def measure(
        self,
        vehicle_ids: npt.ArrayLike,
        vehicle_states: FloatArray,
        feature_ids: npt.ArrayLike,
        feature_states: FloatArray,
        rng: np.random.Generator,
        *,
        visible: npt.NDArray[np.bool_] | None = None,
        detection_probability: float = 1.0,
        clutter_rate: float = 0.0,
        clutter_region: FloatArray | None = None,
        shuffle: bool = True,
    ) -> tuple[Batch, IntArray]:
        """Detections of every visible feature by every vehicle.

        Parameters
        ----------
        vehicle_ids (n,), vehicle_states (n, dx), feature_ids (K,), feature_states (K, df).
        visible : (n, K) which pairs can be sensed (default: all).
        detection_probability : P_D, each visible pair is detected with this probability.
        clutter_rate : λ, Poisson mean of clutter rows per vehicle.
        clutter_region : (dz, 2) box in measurement space the clutter is uniform over.
        shuffle : permute the rows of each vehicle randomly (the receiver cannot tell order).

        Returns
        -------
        batch : rows with `sensor` = vehicle id and `subject` = -1.
        origin : (M,) true feature id of each row, -1 for clutter.
        """
        vehicle_ids = np.asarray(vehicle_ids, dtype=np.int64)
        feature_ids = np.asarray(feature_ids, dtype=np.int64)
        n, K = vehicle_ids.size, feature_ids.size
        if not 0.0 < detection_probability <= 1.0:
            raise InvalidInputError(
                f"detection_probability must lie in (0, 1], got {detection_probability!r}"
            )
        if clutter_rate < 0:
            raise InvalidInputError(f"clutter_rate must be >= 0, got {clutter_rate!r}")
        if clutter_rate > 0 and clutter_region is None:
            raise InvalidInputError("clutter_region is required when clutter_rate > 0")
        detected = np.ones((n, K), dtype=bool) if visible is None else np.array(visible, dtype=bool)
        if detected.shape != (n, K):
            raise InvalidInputError(f"visible must have shape {(n, K)}, got {detected.shape}")
        if detection_probability < 1.0:
            detected &= rng.random((n, K)) < detection_probability
        vi, fi = np.nonzero(detected)  # row-major: grouped by vehicle
        vehicle_states = np.asarray(vehicle_states, dtype=float)
        feature_states = np.asarray(feature_states, dtype=float)
        Hx = self.observation_matrix(vehicle_states.shape[1])
        Hf = self.observation_matrix(feature_states.shape[1])
        cov_vehicle = self.covariance_of(vehicle_ids)
        cov = cov_vehicle[vi]
        z = feature_states[fi] @ Hf.T - vehicle_states[vi] @ Hx.T
        if vi.size:
            z = z + sample_gaussian(cov, rng)
        sensor = vehicle_ids[vi]
        origin = feature_ids[fi]
        if clutter_rate > 0 and n:
            region = float_array("clutter_region", clutter_region, (self.dim, 2))
            counts = rng.poisson(clutter_rate, size=n)
            owner = np.repeat(np.arange(n), counts)
            low, high = region[:, 0], region[:, 1]
            z_clutter = low + (high - low) * rng.random((owner.size, self.dim))
            z = np.concatenate([z, z_clutter])
            cov = np.concatenate([cov, cov_vehicle[owner]])
            sensor = np.concatenate([sensor, vehicle_ids[owner]])
            origin = np.concatenate([origin, np.full(owner.size, -1, dtype=np.int64)])
        order = np.arange(sensor.size)
        if shuffle and sensor.size:
            # group rows by sensing vehicle (in frame order) and permute inside each group
            group = np.searchsorted(np.sort(vehicle_ids), sensor)
            order = np.lexsort((rng.random(sensor.size), group))
        batch = Batch(z[order], cov[order], sensor[order], np.full(sensor.size, -1, dtype=np.int64))
        return batch, origin[order]

    def log_likelihood(self, z: FloatArray, cov: FloatArray, feature: FloatArray,
                       vehicle: FloatArray) -> FloatArray:
        """log N(z; H f − H x, W), broadcast over leading dimensions of all arguments."""
        Hx = self.observation_matrix(vehicle.shape[-1])
        Hf = self.observation_matrix(feature.shape[-1])
        return gaussian_logpdf(z - (feature @ Hf.T - vehicle @ Hx.T), cov)


def _detect_and_clutter(
    z: FloatArray,
    cov: FloatArray,
    origin: IntArray,
    rng: np.random.Generator,
    *,
    detection_probability: float,
    clutter_rate: float,
    clutter_region: FloatArray | None,
    clutter_cov: FloatArray | None,
) -> tuple[FloatArray, FloatArray, IntArray]:
    """Thin rows with P_D, append Poisson(λ) clutter uniform over a box, and shuffle (one sensor)."""
    if not 0.0 < detection_probability <= 1.0:
        raise InvalidInputError(f"detection_probability must lie in (0, 1], got {detection_probability!r}")
    if clutter_rate < 0:
        raise InvalidInputError(f"clutter_rate must be >= 0, got {clutter_rate!r}")
    dz = z.shape[1]
    if detection_probability < 1.0:
        keep = rng.random(origin.size) < detection_probability
        z, cov, origin = z[keep], cov[keep], origin[keep]
    if clutter_rate > 0:
        if clutter_region is None or clutter_cov is None:
            raise InvalidInputError("clutter_region and a default_cov are required when clutter_rate > 0")
        region = float_array("clutter_region", clutter_region, (dz, 2))
        n_clutter = int(rng.poisson(clutter_rate))
        low, high = region[:, 0], region[:, 1]
        z = np.concatenate([z, low + (high - low) * rng.random((n_clutter, dz))])
        cov = np.concatenate([cov, np.broadcast_to(clutter_cov, (n_clutter, dz, dz))])
        origin = np.concatenate([origin, np.full(n_clutter, -1, dtype=np.int64)])
    order = rng.permutation(origin.size)
    return z[order], cov[order], origin[order]


@dataclass(frozen=True)
class AnonymousPosition(_PerEntityCovariance):
    """Absolute position rows without vehicle identity (Zhang 2016 §3.2 internal sensor).

    The covariance of a row is its vehicle's covariance (clutter rows use `default_cov`),
    so the receiver knows how noisy each row is but not whose it is.
    """

    name: ClassVar[str] = "anonymous-position"

    def measure(
        self,
        ids: npt.ArrayLike,
        states: FloatArray,
        rng: np.random.Generator,
        *,
        detection_probability: float = 1.0,
        clutter_rate: float = 0.0,
        clutter_region: FloatArray | None = None,
    ) -> tuple[Batch, IntArray]:
        """One row per detected vehicle, shuffled: Batch with sensor = subject = −1, and origin (M,)."""
        ids = np.asarray(ids, dtype=np.int64)
        states = np.asarray(states, dtype=float)
        cov = self.covariance_of(ids)
        H = self.observation_matrix(states.shape[1])
        z = states @ H.T + sample_gaussian(cov, rng) if ids.size else np.zeros((0, self.dim))
        z, cov, origin = _detect_and_clutter(
            z, cov, ids, rng, detection_probability=detection_probability, clutter_rate=clutter_rate,
            clutter_region=clutter_region, clutter_cov=self.default_cov,
        )
        anonymous = np.full(origin.size, -1, dtype=np.int64)
        return Batch(z, cov, anonymous, anonymous), origin

    def log_likelihood(self, z: FloatArray, cov: FloatArray, states: FloatArray) -> FloatArray:
        """log N(z; H x, W), broadcast over leading dimensions of all arguments."""
        H = self.observation_matrix(states.shape[-1])
        return gaussian_logpdf(z - states @ H.T, cov)


@dataclass(frozen=True)
class InfrastructureRadar(_PerEntityCovariance):
    """Road-side radar reporting vehicle positions in its own frame, anonymously (Zhang §3.2, Gulati §II).

    z = R(θ)ᵀ (H x − t) + w with the sensor pose [t_x, t_y, θ] unknown to estimators.
    Covariances are keyed by the radar's id (or `default_cov`). Only vehicles within
    `max_range` metres of the radar (``inf``: all) and within `field_of_view` rad of its
    boresight (the local x axis; a half-angle in (0, π], π: all around) are reported.
    """

    name: ClassVar[str] = "infrastructure-radar"
    max_range: float = float("inf")
    field_of_view: float = np.pi

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_range(self)
        fov = self.field_of_view
        if isinstance(fov, bool) or not isinstance(fov, (int, float, np.floating)) or not 0.0 < fov <= np.pi:
            raise InvalidInputError(
                f"InfrastructureRadar.field_of_view must be a half-angle in (0, π] rad, got {fov!r}")
        object.__setattr__(self, "field_of_view", float(fov))

    def in_view(self, local: FloatArray) -> npt.NDArray[np.bool_]:
        """Which points (n, 2) of the radar's own frame it reports: range and field of view."""
        local = np.asarray(local, dtype=float).reshape(-1, 2)
        seen = np.hypot(local[:, 0], local[:, 1]) <= self.max_range
        if self.field_of_view < np.pi:  # all around needs no bearing (and keeps the point under the radar)
            seen &= np.abs(np.arctan2(local[:, 1], local[:, 0])) <= self.field_of_view
        return seen

    def measure(
        self,
        sensor_id: int,
        pose: npt.ArrayLike,
        ids: npt.ArrayLike,
        states: FloatArray,
        rng: np.random.Generator,
        *,
        detection_probability: float = 1.0,
        clutter_rate: float = 0.0,
        clutter_region: FloatArray | None = None,
    ) -> tuple[Batch, IntArray]:
        """Rows of one radar at `pose` [x, y, yaw]: Batch with sensor = sensor_id, subject = −1; origin (M,).

        `clutter_region` (2, 2) is a box in the radar's own frame.
        """
        pose = float_array("pose", pose, (3,))
        ids = np.asarray(ids, dtype=np.int64)
        states = np.asarray(states, dtype=float)
        H = self.observation_matrix(states.shape[1])
        local = to_local(pose, states @ H.T)
        seen = self.in_view(local)
        ids, local = ids[seen], local[seen]
        noise_cov = self.covariance_of([sensor_id])[0]
        cov = np.broadcast_to(noise_cov, (ids.size, self.dim, self.dim)).copy()
        z = local + sample_gaussian(cov, rng) if ids.size else np.zeros((0, self.dim))
        z, cov, origin = _detect_and_clutter(
            z, cov, ids, rng, detection_probability=detection_probability, clutter_rate=clutter_rate,
            clutter_region=clutter_region, clutter_cov=noise_cov,
        )
        return Batch(z, cov, np.full(origin.size, int(sensor_id), dtype=np.int64),
                     np.full(origin.size, -1, dtype=np.int64)), origin

    def measure_many(
        self,
        sensor_ids: npt.ArrayLike,
        poses: npt.ArrayLike,
        ids: npt.ArrayLike,
        states: FloatArray,
        rng: np.random.Generator,
    ) -> tuple[Batch, IntArray]:
        """Rows of R radars at once, ids (R,) at poses (R, 3): one vectorised draw for all.

        Each radar reports what `measure` reports (range, field of view, its noise), without
        missed detections or clutter; the rows come grouped by radar in the order given and
        shuffled within each radar. Returns the Batch (sensor = the radar, subject = −1) and
        the origin (M,) of each row.
        """
        sensor_ids = np.asarray(sensor_ids, dtype=np.int64).reshape(-1)
        poses = float_array("poses", poses, (sensor_ids.size, 3))
        ids = np.asarray(ids, dtype=np.int64)
        states = np.asarray(states, dtype=float)
        points = states @ self.observation_matrix(states.shape[1]).T
        local = to_local(poses, points.reshape(-1, 2))                    # (R, n, 2)
        radar, vehicle = np.nonzero(self.in_view(local.reshape(-1, 2)).reshape(sensor_ids.size, ids.size))
        cov = self.covariance_of(sensor_ids)[radar]
        if not radar.size:
            z = np.zeros((0, self.dim))
        elif not self.covariances:  # one covariance for every radar: one factorisation
            z = local[radar, vehicle] + sample_gaussian(self.default_cov, rng, n=radar.size)
        else:
            z = local[radar, vehicle] + sample_gaussian(cov, rng)
        order = np.lexsort((rng.random(radar.size), radar))   # random order within each radar
        unknown = np.full(radar.size, -1, dtype=np.int64)
        return Batch(z[order], cov[order], sensor_ids[radar[order]], unknown), ids[vehicle[order]]

    def to_dict(self) -> dict[str, Any]:
        # all around is left out, so setups of radars without a field of view keep their setup.json
        narrow = {"field_of_view": self.field_of_view} if self.field_of_view < np.pi else {}
        return {**super().to_dict(), "max_range": self.max_range, **narrow}


@dataclass(frozen=True)
class Odometry(_PerEntityCovariance):
    """Displacement since the previous step, global frame (Gulati eq. 4): z = H x_k − H x_{k−1} + w."""

    name: ClassVar[str] = "odometry"

    def measure(
        self, ids: npt.ArrayLike, states: FloatArray, previous: FloatArray, rng: np.random.Generator
    ) -> Batch:
        """ids (n,), states (n, dx) at k and previous (n, dx) at k−1 → Batch with sensor = subject = id."""
        ids = np.asarray(ids, dtype=np.int64)
        cov = self.covariance_of(ids)
        H = self.observation_matrix(np.shape(states)[1])
        delta = (np.asarray(states, dtype=float) - np.asarray(previous, dtype=float)) @ H.T
        z = delta + sample_gaussian(cov, rng) if ids.size else np.zeros((0, self.dim))
        return Batch(z, cov, ids, ids)


@dataclass(frozen=True)
class AngleOfArrival:
    """AoA of a neighbour's signal relative to the receiver's heading, two side arrays.

    θ_{i←j} = wrap(atan2(Δp_y, Δp_x) − α_i) + w, Δp = p_j − p_i, w ~ N(0, σ²_θ), measured
    only where |wrap(θ − π/2)| ≤ Δ or |wrap(θ + π/2)| ≤ Δ (left or right array).

    Attributes
    ----------
    covariances : receiver id → (1, 1) noise variance σ²_θ in rad², for receivers
        whose arrays differ from the default.
    default_cov : (1, 1) σ²_θ of every other receiver.
    state_indices : indices of (p_x, p_y, α) in the vehicle state.
    field_of_view : Δ in rad, half-width of each array's field of view, at most and by
        default π/2: a linear array sees the half-plane on its side, so the two see all
        around (`papers/plbp_model_notes.md`).
    """

    name: ClassVar[str] = "angle-of-arrival"
    covariances: Mapping[int, FloatArray] = field(default_factory=dict)
    default_cov: FloatArray | None = None
    state_indices: tuple[int, ...] = (0, 1, 2)
    field_of_view: float = np.pi / 2

    def __post_init__(self) -> None:
        covs = {}
        for key, value in dict(self.covariances).items():
            cov = float_array(f"AngleOfArrival.covariances[{key}]", value, (1, 1))
            check_covariances(f"AngleOfArrival.covariances[{key}]", cov[None])
            covs[int(key)] = cov
        object.__setattr__(self, "covariances", covs)
        if self.default_cov is not None:
            cov = float_array("AngleOfArrival.default_cov", self.default_cov, (1, 1))
            check_covariances("AngleOfArrival.default_cov", cov[None])
            object.__setattr__(self, "default_cov", cov)
        indices = tuple(int(i) for i in self.state_indices)
        if len(indices) != 3 or len(set(indices)) != 3 or min(indices) < 0:
            raise InvalidInputError(
                f"AngleOfArrival.state_indices must be 3 distinct indices (p_x, p_y, α), got {indices}"
            )
        object.__setattr__(self, "state_indices", indices)
        fov = float(self.field_of_view)
        if not 0.0 < fov <= np.pi / 2:
            raise InvalidInputError(
                f"AngleOfArrival.field_of_view must lie in (0, π/2] rad, got {self.field_of_view!r}"
            )
        object.__setattr__(self, "field_of_view", fov)

    def variance_of(self, receivers: npt.ArrayLike) -> FloatArray:
        """(n, 1, 1) noise variance of each receiver id."""
        receivers = np.asarray(receivers, dtype=np.int64)
        if not self.covariances:  # the usual case: one variance for everybody
            if self.default_cov is None:
                raise InvalidInputError("AngleOfArrival has no default_cov and no per-receiver ones")
            return np.broadcast_to(self.default_cov, (receivers.size, 1, 1)).copy()
        out = np.empty((receivers.size, 1, 1))
        for r, entity in enumerate(receivers.tolist()):
            cov = self.covariances.get(entity, self.default_cov)
            if cov is None:
                raise InvalidInputError(f"AngleOfArrival has no variance for receiver {entity}")
            out[r] = cov
        return out

    def bearing(self, receiver: FloatArray, transmitter: FloatArray) -> FloatArray:
        """Noise-free θ_{i←j} (...,) for receiver (..., dx) and transmitter (..., dx) states."""
        ix, iy, ia = self.state_indices
        dx = transmitter[..., ix] - receiver[..., ix]
        dy = transmitter[..., iy] - receiver[..., iy]
        return wrap_angle(np.arctan2(dy, dx) - receiver[..., ia])

    def in_view(self, theta: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Whether relative angles θ fall in the left (+π/2) or right (−π/2) array's view."""
        theta = np.asarray(theta, dtype=float)
        if self.field_of_view >= np.pi / 2:  # the two half-planes cover every direction
            return np.ones(theta.shape, dtype=bool)
        return ((np.abs(wrap_angle(theta - np.pi / 2)) <= self.field_of_view)
                | (np.abs(wrap_angle(theta + np.pi / 2)) <= self.field_of_view))

    def measure(self, ids: npt.ArrayLike, states: FloatArray, links: npt.ArrayLike,
                rng: np.random.Generator) -> Batch:
        """AoA rows of every link, both directions, where in view.

        Parameters
        ----------
        ids : (n,) vehicle ids; states : (n, dx) their true states.
        links : (E, 2) undirected links as pairs of ids.

        Returns
        -------
        Batch
            z (M, 1) wrapped to [−π, π), `sensor` = receiver, `subject` = transmitter;
            rows ordered by link, receiver first-end first.
        """
        ids = np.asarray(ids, dtype=np.int64)
        states = np.asarray(states, dtype=float)
        links = np.asarray(links, dtype=np.int64).reshape(-1, 2)
        if links.size == 0:
            return Batch.empty(1)
        ends = np.stack([links, links[:, ::-1]], axis=1).reshape(-1, 2)   # (2E, 2) receiver, transmitter
        order = np.argsort(ids, kind="stable")
        pos = order[np.searchsorted(ids, ends, sorter=order)]
        if not np.array_equal(ids[pos], ends):
            raise InvalidInputError("AngleOfArrival.measure: links name ids that are not in ids")
        theta = self.bearing(states[pos[:, 0]], states[pos[:, 1]])
        seen = self.in_view(theta)
        receivers, transmitters = ends[seen, 0], ends[seen, 1]
        cov = self.variance_of(receivers)
        z = theta[seen] + np.sqrt(cov[:, 0, 0]) * rng.standard_normal(receivers.size)
        return Batch(wrap_angle(z)[:, None], cov, receivers, transmitters)

    def log_likelihood(self, batch: Batch, receiver: FloatArray, transmitter: FloatArray) -> FloatArray:
        """log N(wrap(z − θ); 0, σ²_θ) per row, states (..., M, dx) aligned with rows."""
        residual = wrap_angle(batch.z[:, 0] - self.bearing(receiver, transmitter))
        return gaussian_logpdf(residual[..., None], batch.cov)

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.name,
            "covariances": {str(k): v.tolist() for k, v in self.covariances.items()},
            "default_cov": None if self.default_cov is None else self.default_cov.tolist(),
            "state_indices": list(self.state_indices),
            "field_of_view": self.field_of_view,
        }


_SENSORS = (GnssPosition, RelativePosition, AnonymousPosition, InfrastructureRadar, Odometry,
            AngleOfArrival)


def sensor_from_dict(data: Mapping[str, Any]) -> SensorModel:
    """Rebuild a sensor model from its `to_dict()` form."""
    fields = dict(data)
    name = fields.pop("model", None)
    for model in _SENSORS:
        if model.name == name:
            covs = {int(k): np.asarray(v) for k, v in fields.pop("covariances", {}).items()}
            default = fields.pop("default_cov", None)
            return model(
                covariances=covs,
                default_cov=None if default is None else np.asarray(default),
                state_indices=tuple(fields.pop("state_indices", (0, 1))),
                **fields,
            )
    raise InvalidInputError(f"sensor model {name!r} is unknown; known: {[m.name for m in _SENSORS]}")
