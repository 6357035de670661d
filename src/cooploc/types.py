"""The data model every scenario, estimator and metric speaks (DESIGN §2).

All arrays are NumPy float64 (ids int64) in SI units: m, s, rad. Entities — vehicles,
features, infrastructure sensors — carry stable integer ids; per-step arrays are keyed
by id, never by position, because vehicles enter and leave.

The containers are frozen dataclasses whose arrays are made read-only. They validate
at construction: a wrong shape, a NaN or inf, a covariance that is not symmetric
positive definite, or a duplicated id raises `InvalidInputError` whose message names
the field and shows the offending value.

- `Batch`: one kind of measurement at one step, one row per measurement.
- `Frame`: everything measured at step k.
- `StateLayout`: which state components are position, velocity, heading.
- `StateSet`: a batch of Gaussian beliefs keyed by id (estimates, priors).
- `Setup`: static knowledge an estimator may use.
- `Truth`: true states, presence and measurement origins (for metrics only).
- `Recording`: a whole simulated (or recorded) run.
- `Estimate`: what an estimator returns from `step`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from cooploc.errors import InvalidInputError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = [
    "AssociationTruth",
    "Batch",
    "Estimate",
    "FloatArray",
    "Frame",
    "IntArray",
    "MotionModel",
    "Recording",
    "SensorModel",
    "Setup",
    "StateLayout",
    "StateSet",
    "Truth",
]

# Relative tolerance for the symmetry check of covariances: round-off from a
# Joseph-form update is ~1e-15 relative; anything beyond 1e-8 is a user error.
_SYMMETRY_RTOL = 1e-8


# ----------------------------------------------------------------------------
# validation helpers (one home: every container below uses these)
# ----------------------------------------------------------------------------


def _show(value: Any) -> str:
    """Short printable form of an offending value for error messages."""
    text = np.array2string(np.asarray(value), precision=6, threshold=12, separator=", ")
    return text if len(text) <= 200 else text[:197] + "..."


def _frozen(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


def float_array(name: str, value: Any, shape: Sequence[int | None]) -> FloatArray:
    """Convert to a finite float64 array of the given shape (None = any length).

    Raises `InvalidInputError` naming `name` on a wrong shape or a non-finite entry.
    """
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{name} must be numeric, got {value!r}") from exc
    if array.ndim != len(shape) or any(
        want is not None and have != want for have, want in zip(array.shape, shape, strict=True)
    ):
        wanted = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise InvalidInputError(f"{name} must have shape {wanted}, got {array.shape}")
    bad = ~np.isfinite(array)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InvalidInputError(f"{name}{list(where)} is not finite: {array[where]}")
    return _frozen(array)


def int_array(name: str, value: Any, shape: Sequence[int | None]) -> IntArray:
    """Convert to an int64 array of the given shape; non-integral values are rejected."""
    raw = np.asarray(value)
    if raw.size and not (
        np.issubdtype(raw.dtype, np.integer)
        or (np.issubdtype(raw.dtype, np.floating) and np.all(np.mod(raw, 1) == 0))
    ):
        raise InvalidInputError(f"{name} must hold integer ids, got {_show(raw)}")
    array = np.array(raw, dtype=np.int64)
    if raw.size == 0:
        array = array.reshape([0 if s is None else s for s in shape])
    if array.ndim != len(shape) or any(
        want is not None and have != want for have, want in zip(array.shape, shape, strict=True)
    ):
        wanted = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise InvalidInputError(f"{name} must have shape {wanted}, got {array.shape}")
    return _frozen(array)


def check_unique(name: str, ids: IntArray) -> None:
    """Raise if an id occurs twice."""
    values, counts = np.unique(ids, return_counts=True)
    if (counts > 1).any():
        raise InvalidInputError(f"{name} has duplicate ids: {values[counts > 1].tolist()}")


def check_covariances(name: str, cov: FloatArray) -> None:
    """Raise unless every matrix of the batch `cov (n, d, d)` is symmetric positive definite."""
    if cov.shape[0] == 0:
        return
    if cov.shape[1:] == (1, 1):  # 1 × 1 (angles): positive definite iff positive, no factorisation
        bad = np.flatnonzero(cov[:, 0, 0] <= 0)
        if bad.size:
            i = int(bad[0])
            raise InvalidInputError(f"{name}[{i}] is not positive definite (smallest eigenvalue "
                                    f"{cov[i, 0, 0]:.3g}): {_show(cov[i])}")
        return
    scale = np.maximum(np.abs(cov).max(axis=(1, 2)), np.finfo(float).tiny)
    asym = np.abs(cov - cov.transpose(0, 2, 1)).max(axis=(1, 2)) > _SYMMETRY_RTOL * scale
    if asym.any():
        i = int(np.flatnonzero(asym)[0])
        raise InvalidInputError(f"{name}[{i}] is not symmetric: {_show(cov[i])}")
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        eig = np.linalg.eigvalsh(cov).min(axis=1)
        i = int(np.flatnonzero(eig <= 0)[0]) if (eig <= 0).any() else int(np.argmin(eig))
        raise InvalidInputError(
            f"{name}[{i}] is not positive definite (smallest eigenvalue {eig[i]:.3g}): "
            f"{_show(cov[i])}"
        ) from None


def lookup_ids(ids: IntArray, wanted: npt.ArrayLike) -> tuple[IntArray, npt.NDArray[np.bool_]]:
    """Vectorised lookup of `wanted` ids in unsorted `ids`: (position, found) per wanted id.

    Where an id is not found its position is 0 and meaningless.
    """
    wanted = np.asarray(wanted, dtype=np.int64)
    if ids.size == 0:
        return np.zeros(wanted.shape, dtype=np.int64), np.zeros(wanted.shape, dtype=bool)
    order = np.argsort(ids, kind="stable")
    pos = order[np.minimum(np.searchsorted(ids, wanted, sorter=order), ids.size - 1)]
    return pos, ids[pos] == wanted


def index_of(ids: IntArray, wanted: npt.ArrayLike, name: str = "ids") -> IntArray:
    """Positions of `wanted` ids inside `ids`; raise if any is missing."""
    pos, found = lookup_ids(ids, wanted)
    if not found.all():
        missing = np.asarray(wanted, dtype=np.int64)[~found]
        raise InvalidInputError(f"{name}: unknown ids {missing.tolist()}")
    return pos


# ----------------------------------------------------------------------------
# containers
# ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Batch:
    """One kind of measurement at one step, one row per measurement.

    Attributes
    ----------
    z : (M, dz) measured values.
    cov : (M, dz, dz) noise covariance of each row (symmetric positive definite).
    sensor : (M,) id of the entity that measured, -1 where the receiver cannot tell.
    subject : (M,) id of the measured entity, -1 where the association is unknown.
        The order of rows of one sensor is arbitrary (scenarios shuffle it).
    """

    z: FloatArray
    cov: FloatArray
    sensor: IntArray
    subject: IntArray

    def __post_init__(self) -> None:
        z = np.asarray(self.z)
        if z.ndim != 2:
            raise InvalidInputError(f"Batch.z must have shape (M, dz), got {z.shape}")
        m, dz = z.shape
        object.__setattr__(self, "z", float_array("Batch.z", z, (m, dz)))
        cov = float_array("Batch.cov", self.cov, (m, dz, dz))
        check_covariances("Batch.cov", cov)
        object.__setattr__(self, "cov", cov)
        object.__setattr__(self, "sensor", int_array("Batch.sensor", self.sensor, (m,)))
        object.__setattr__(self, "subject", int_array("Batch.subject", self.subject, (m,)))

    @classmethod
    def empty(cls, dz: int) -> Batch:
        """A batch with no rows of dimension `dz`."""
        return cls(np.zeros((0, dz)), np.zeros((0, dz, dz)), np.zeros(0, int), np.zeros(0, int))

    def __len__(self) -> int:
        return self.z.shape[0]

    @property
    def dim(self) -> int:
        """Dimension dz of one measurement."""
        return self.z.shape[1]

    def select(self, rows: npt.ArrayLike) -> Batch:
        """The sub-batch of the given rows (boolean mask or integer index)."""
        rows = np.asarray(rows)
        return Batch(self.z[rows], self.cov[rows], self.sensor[rows], self.subject[rows])

    def components(self, idx: npt.ArrayLike) -> Batch:
        """The rows cut to their components `idx` (in that order) and the matching block of
        each covariance: for Gaussian rows z = H x + w, the exact marginal of those components."""
        idx = np.asarray(idx, dtype=np.int64)
        return Batch(self.z[:, idx], self.cov[:, idx[:, None], idx[None, :]], self.sensor, self.subject)


@dataclass(frozen=True, slots=True)
class Frame:
    """Everything measured at step `k`, time `t` (s).

    Attributes
    ----------
    k : step index (0-based).
    t : time in s.
    vehicles : (n,) ids of the vehicles present at this step.
    batches : measurement batches keyed by kind (`"gnss"`, `"v2f"`, `"radar"`,
        `"odometry"`, `"imu"`, `"aoa"`); a missing kind means nothing of that kind.
    links : (E, 2) V2V communication edges between present vehicles (undirected).
    """

    k: int
    t: float
    vehicles: IntArray
    batches: Mapping[str, Batch] = field(default_factory=dict)
    links: IntArray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))

    def __post_init__(self) -> None:
        if isinstance(self.k, bool) or not isinstance(self.k, (int, np.integer)) or self.k < 0:
            raise InvalidInputError(f"Frame.k must be a non-negative integer, got {self.k!r}")
        object.__setattr__(self, "k", int(self.k))
        t = float_array("Frame.t", self.t, ())
        object.__setattr__(self, "t", float(t))
        vehicles = int_array("Frame.vehicles", self.vehicles, (None,))
        check_unique("Frame.vehicles", vehicles)
        object.__setattr__(self, "vehicles", vehicles)
        batches = dict(self.batches)
        for kind, batch in batches.items():
            if not isinstance(kind, str) or not isinstance(batch, Batch):
                raise InvalidInputError(
                    f"Frame.batches must map kind names to Batch, got {kind!r}: "
                    f"{type(batch).__name__}"
                )
        object.__setattr__(self, "batches", MappingProxyType(batches))
        links = int_array("Frame.links", self.links, (None, 2))
        if links.size:
            absent = ~np.isin(links, vehicles)
            if absent.any():
                raise InvalidInputError(
                    f"Frame.links refer to vehicles not present: {np.unique(links[absent]).tolist()}"
                )
            loops = links[:, 0] == links[:, 1]
            if loops.any():
                raise InvalidInputError(f"Frame.links has self-links: {links[loops].tolist()}")
        object.__setattr__(self, "links", links)

    def batch(self, kind: str, dim: int) -> Batch:
        """The batch of `kind`, or an empty batch of dimension `dim` if there is none."""
        found = self.batches.get(kind)
        return Batch.empty(dim) if found is None else found


@dataclass(frozen=True, slots=True)
class StateLayout:
    """Which components of a state vector are position, velocity and heading.

    Attributes
    ----------
    dim : state dimension.
    position : indices of the position components (m), e.g. (0, 1).
    velocity : indices of the velocity components (m/s), or None.
    heading : index of the heading component (rad), or None.
    """

    dim: int
    position: tuple[int, ...]
    velocity: tuple[int, ...] | None = None
    heading: int | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.dim, (int, np.integer)) or self.dim < 1:
            raise InvalidInputError(f"StateLayout.dim must be a positive integer, got {self.dim!r}")
        object.__setattr__(self, "position", tuple(int(i) for i in self.position))
        if self.velocity is not None:
            object.__setattr__(self, "velocity", tuple(int(i) for i in self.velocity))
        used = list(self.position) + list(self.velocity or ()) + (
            [] if self.heading is None else [int(self.heading)]
        )
        if not self.position or any(i < 0 or i >= self.dim for i in used):
            raise InvalidInputError(
                f"StateLayout indices must lie in [0, {self.dim}), got position={self.position}, "
                f"velocity={self.velocity}, heading={self.heading}"
            )
        if len(set(used)) != len(used):
            raise InvalidInputError(f"StateLayout indices overlap: {used}")

    @classmethod
    def position_velocity(cls, ndim: int = 2) -> StateLayout:
        """The CV layout [p_1..p_ndim, v_1..v_ndim] used by Fröhle eq. (28)."""
        return cls(2 * ndim, tuple(range(ndim)), tuple(range(ndim, 2 * ndim)))

    def to_dict(self) -> dict[str, Any]:
        return {
            "dim": self.dim,
            "position": list(self.position),
            "velocity": None if self.velocity is None else list(self.velocity),
            "heading": self.heading,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> StateLayout:
        velocity = data.get("velocity")
        return cls(
            int(data["dim"]),
            tuple(data["position"]),
            None if velocity is None else tuple(velocity),
            data.get("heading"),
        )


@dataclass(frozen=True, slots=True)
class StateSet:
    """A batch of Gaussian beliefs keyed by entity id.

    Attributes
    ----------
    ids : (n,) entity ids, unique.
    mean : (n, dx) means.
    cov : (n, dx, dx) covariances, symmetric positive definite.
    """

    ids: IntArray
    mean: FloatArray
    cov: FloatArray

    def __post_init__(self) -> None:
        ids = int_array("StateSet.ids", self.ids, (None,))
        check_unique("StateSet.ids", ids)
        mean = np.asarray(self.mean)
        dx = mean.shape[1] if mean.ndim == 2 else None
        mean = float_array("StateSet.mean", mean, (ids.size, dx))
        dx = mean.shape[1]
        cov = float_array("StateSet.cov", self.cov, (ids.size, dx, dx))
        check_covariances("StateSet.cov", cov)
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", cov)

    def __len__(self) -> int:
        return self.ids.size

    @classmethod
    def empty(cls, dim: int) -> StateSet:
        return cls(np.zeros(0, int), np.zeros((0, dim)), np.zeros((0, dim, dim)))

    def take(self, ids: npt.ArrayLike) -> StateSet:
        """The beliefs of the given ids, in that order."""
        rows = index_of(self.ids, np.asarray(ids, dtype=np.int64), "StateSet.take")
        return StateSet(self.ids[rows], self.mean[rows], self.cov[rows])

    def to_dict(self) -> dict[str, Any]:
        # "dim" too: an empty set has no rows to show it, and from_dict reads it back
        return {"ids": self.ids.tolist(), "mean": self.mean.tolist(), "cov": self.cov.tolist(),
                "dim": int(self.mean.shape[1])}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> StateSet:
        """Inverse of `to_dict`; shapes are checked, not reshaped into place."""
        ids = int_array("StateSet.ids", data["ids"], (None,))
        dim = int(data["dim"]) if data.get("dim") is not None else (
            len(data["mean"][0]) if len(data["mean"]) else 0)
        mean = float_array("StateSet.mean", data["mean"] if ids.size else np.zeros((0, dim)),
                           (ids.size, dim))
        cov = float_array("StateSet.cov", data["cov"] if ids.size else np.zeros((0, dim, dim)),
                          (ids.size, dim, dim))
        return cls(ids, mean, cov)


# ----------------------------------------------------------------------------
# the models a Setup holds (implementations: cooploc.motion, cooploc.sensors)
# ----------------------------------------------------------------------------


@runtime_checkable
class MotionModel(Protocol):
    """A linear-Gaussian motion model x_k = F x_{k-1} + B u_k + w_k."""

    name: ClassVar[str]
    dim: int
    state_dependent_noise: ClassVar[bool]

    def transition_matrix(self, dt: float) -> FloatArray:
        """F (dx, dx)."""
        ...

    def noise_covariance(self, dt: float, states: FloatArray | None = None) -> FloatArray:
        """Q, (dx, dx) or per entity (n, dx, dx) where it depends on the state."""
        ...

    def control_matrix(self, dt: float) -> FloatArray | None:
        """B (dx, du), or None for a model without input."""
        ...

    def to_dict(self) -> dict[str, Any]: ...


@runtime_checkable
class SensorModel(Protocol):
    """A sensor that produces one kind of `Batch`."""

    name: ClassVar[str]

    def to_dict(self) -> dict[str, Any]: ...


@dataclass(frozen=True)
class Setup:
    """Static knowledge an estimator may use (never truth).

    Attributes
    ----------
    dt : step length in s.
    n_steps : number of steps of the run.
    vehicle_layout, vehicle_motion : state layout and motion model of the vehicles.
    vehicle_prior : prior beliefs of the vehicles known at the start (by id). A vehicle
        that enters later without a prior is initialised from its first GNSS fix with
        `birth_cov` (see `cooploc.estimators.base.birth_beliefs`).
    sensors : the sensor models by measurement kind (same keys as `Frame.batches`).
    feature_layout, feature_motion, feature_prior : the same for features, or None.
    birth_cov : (dx, dx) covariance of a vehicle that enters without a prior, centred
        on its first GNSS fix (default: broad, see `estimators.base.default_birth_cov`).
    detection_probability : P_D of feature detections (1 = always detected).
    clutter_rate : mean number of clutter detections per sensor and step (Poisson).
    clutter_region : (d, 2) lower/upper bounds of the clutter region per axis, or None.
    infrastructure_ids : ids of infrastructure sensors (radars, RSUs).
    description : one line saying what this setup models.
    """

    dt: float
    n_steps: int
    vehicle_layout: StateLayout
    vehicle_motion: MotionModel
    vehicle_prior: StateSet
    sensors: Mapping[str, SensorModel]
    feature_layout: StateLayout | None = None
    feature_motion: MotionModel | None = None
    feature_prior: StateSet | None = None
    birth_cov: FloatArray | None = None
    detection_probability: float = 1.0
    clutter_rate: float = 0.0
    clutter_region: FloatArray | None = None
    infrastructure_ids: tuple[int, ...] = ()
    description: str = ""

    def __post_init__(self) -> None:
        if not np.isfinite(self.dt) or self.dt <= 0:
            raise InvalidInputError(f"Setup.dt must be a positive number of seconds, got {self.dt!r}")
        if int(self.n_steps) != self.n_steps or self.n_steps < 1:
            raise InvalidInputError(f"Setup.n_steps must be a positive integer, got {self.n_steps!r}")
        dx = self.vehicle_layout.dim
        if self.vehicle_motion.dim != dx:
            raise InvalidInputError(
                f"Setup.vehicle_motion has dimension {self.vehicle_motion.dim}, "
                f"vehicle_layout.dim is {dx}"
            )
        if len(self.vehicle_prior) and self.vehicle_prior.mean.shape[1] != dx:
            raise InvalidInputError(
                f"Setup.vehicle_prior.mean must have {dx} columns, "
                f"got {self.vehicle_prior.mean.shape[1]}"
            )
        if self.feature_layout is not None:
            df = self.feature_layout.dim
            if self.feature_motion is None or self.feature_motion.dim != df:
                raise InvalidInputError(
                    f"Setup.feature_motion must be a motion model of dimension {df}, "
                    f"got {self.feature_motion!r}"
                )
            if self.feature_prior is not None and len(self.feature_prior) and (
                self.feature_prior.mean.shape[1] != df
            ):
                raise InvalidInputError(
                    f"Setup.feature_prior.mean must have {df} columns, "
                    f"got {self.feature_prior.mean.shape[1]}"
                )
        if self.birth_cov is not None:
            birth = float_array("Setup.birth_cov", self.birth_cov, (dx, dx))
            check_covariances("Setup.birth_cov", birth[None])
            object.__setattr__(self, "birth_cov", birth)
        if not 0.0 < self.detection_probability <= 1.0:
            raise InvalidInputError(
                f"Setup.detection_probability must lie in (0, 1], got {self.detection_probability!r}"
            )
        if not np.isfinite(self.clutter_rate) or self.clutter_rate < 0:
            raise InvalidInputError(f"Setup.clutter_rate must be >= 0, got {self.clutter_rate!r}")
        if self.clutter_region is not None:
            region = float_array("Setup.clutter_region", self.clutter_region, (None, 2))
            if (region[:, 1] <= region[:, 0]).any():
                raise InvalidInputError(
                    f"Setup.clutter_region needs lower < upper per axis, got {_show(region)}"
                )
            object.__setattr__(self, "clutter_region", region)
        object.__setattr__(self, "sensors", MappingProxyType(dict(self.sensors)))
        object.__setattr__(self, "infrastructure_ids", tuple(int(i) for i in self.infrastructure_ids))


@dataclass(frozen=True)
class Truth:
    """True states and measurement origins of a run (read by metrics, never by estimators).

    Attributes
    ----------
    vehicle_ids : (N,) ids of every vehicle that appears in the run.
    vehicle_states : (T, N, dx) true vehicle states; rows where absent are zero.
    vehicle_present : (T, N) bool presence of each vehicle at each step.
    feature_ids, feature_states, feature_present : the same for features (K may be 0).
    origin : per step, per batch kind, (M,) the id of the entity each row came from, or
        -1 for clutter. For relative measurements (V2F) this is the measured feature.
    sensor_poses : (P, 3) pose [x, y, yaw] (m, m, rad) of each infrastructure sensor
        in `setup.infrastructure_ids` order; (0, 3) when there are none.
    vehicle_heading : (T, N) true heading α (rad, counter-clockwise from the x axis,
        wrapped to [−π, π)) of each vehicle, zero where absent, for a scenario that knows
        it although `Setup.vehicle_layout` has no heading component (SUMO traffic, whose
        angle-of-arrival rows depend on it); None (the default) otherwise. The truth
        of an estimator that tracks a heading beside the layout's components; where the
        layout has a heading, `vehicle_states` holds it and metrics score it from there.
    """

    vehicle_ids: IntArray
    vehicle_states: FloatArray
    vehicle_present: npt.NDArray[np.bool_]
    feature_ids: IntArray
    feature_states: FloatArray
    feature_present: npt.NDArray[np.bool_]
    origin: Sequence[Mapping[str, IntArray]]
    sensor_poses: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    vehicle_heading: FloatArray | None = None

    def __post_init__(self) -> None:
        vids = int_array("Truth.vehicle_ids", self.vehicle_ids, (None,))
        check_unique("Truth.vehicle_ids", vids)
        states = np.asarray(self.vehicle_states)
        if states.ndim != 3:
            raise InvalidInputError(f"Truth.vehicle_states must have shape (T, N, dx), got {states.shape}")
        n_steps = states.shape[0]
        states = float_array("Truth.vehicle_states", states, (n_steps, vids.size, None))
        present = np.array(self.vehicle_present, dtype=bool)
        if present.shape != (n_steps, vids.size):
            raise InvalidInputError(
                f"Truth.vehicle_present must have shape {(n_steps, vids.size)}, got {present.shape}"
            )
        fids = int_array("Truth.feature_ids", self.feature_ids, (None,))
        check_unique("Truth.feature_ids", fids)
        fstates = np.asarray(self.feature_states, dtype=float)
        df = fstates.shape[2] if fstates.ndim == 3 else None
        fstates = float_array("Truth.feature_states", fstates, (n_steps, fids.size, df))
        fpresent = np.array(self.feature_present, dtype=bool)
        if fpresent.shape != (n_steps, fids.size):
            raise InvalidInputError(
                f"Truth.feature_present must have shape {(n_steps, fids.size)}, got {fpresent.shape}"
            )
        if len(self.origin) != n_steps:
            raise InvalidInputError(f"Truth.origin must have {n_steps} steps, got {len(self.origin)}")
        # origins made with their frames on demand (`cooploc.streams`) stay so
        origin = self.origin if getattr(self.origin, "is_stream", False) else tuple(
            MappingProxyType({kind: int_array(f"Truth.origin[{k}][{kind!r}]", rows, (None,))
                              for kind, rows in step.items()})
            for k, step in enumerate(self.origin)
        )
        poses = float_array("Truth.sensor_poses", self.sensor_poses, (None, 3))
        if self.vehicle_heading is not None:
            heading = float_array("Truth.vehicle_heading", self.vehicle_heading, (n_steps, vids.size))
            object.__setattr__(self, "vehicle_heading", heading)
        for name, value in (("vehicle_ids", vids), ("vehicle_states", states),
                            ("vehicle_present", _frozen(present)), ("feature_ids", fids),
                            ("feature_states", fstates), ("feature_present", _frozen(fpresent)),
                            ("origin", origin), ("sensor_poses", poses)):
            object.__setattr__(self, name, value)

    @classmethod
    def always_present(cls, vehicle_ids: npt.ArrayLike, vehicle_states: npt.ArrayLike,
                       origin: Sequence[Mapping[str, IntArray]],
                       feature_ids: npt.ArrayLike | None = None,
                       feature_states: npt.ArrayLike | None = None,
                       sensor_poses: npt.ArrayLike | None = None) -> Truth:
        """The truth of a run whose vehicles (and features, if any) are present at every
        step: states (T, N, dx) and (T, K, df); no features gives K = 0 with df = dx."""
        states = np.asarray(vehicle_states, dtype=float)
        n_steps, n_vehicles, dx = states.shape
        features = (np.zeros((n_steps, 0, dx)) if feature_states is None
                    else np.asarray(feature_states, dtype=float))
        return cls(
            vehicle_ids=vehicle_ids,
            vehicle_states=states,
            vehicle_present=np.ones((n_steps, n_vehicles), dtype=bool),
            feature_ids=np.zeros(0, dtype=np.int64) if feature_ids is None else feature_ids,
            feature_states=features,
            feature_present=np.ones(features.shape[:2], dtype=bool),
            origin=origin,
            sensor_poses=np.zeros((0, 3)) if sensor_poses is None else sensor_poses,
        )

    @property
    def n_steps(self) -> int:
        return self.vehicle_states.shape[0]

    def vehicles_at(self, k: int, ids: npt.ArrayLike) -> FloatArray:
        """True states (n, dx) of the given vehicle ids at step k."""
        return self.vehicle_states[k, index_of(self.vehicle_ids, np.asarray(ids), "vehicle ids")]

    def features_at(self, k: int, ids: npt.ArrayLike) -> FloatArray:
        """True states (n, df) of the given feature ids at step k."""
        return self.feature_states[k, index_of(self.feature_ids, np.asarray(ids), "feature ids")]


@dataclass(frozen=True)
class AssociationTruth:
    """What a known-association reference may read of the truth.

    Attributes
    ----------
    origin : per step, per batch kind, (M,) the true origin id of each row (-1 clutter).
    sensor_poses : (P, 3) poses of the infrastructure sensors (known registration).
    """

    origin: Sequence[Mapping[str, IntArray]]
    sensor_poses: FloatArray

    @classmethod
    def of(cls, truth: Truth) -> AssociationTruth:
        return cls(truth.origin, truth.sensor_poses)


@dataclass(frozen=True)
class Recording:
    """A whole run: static setup, one frame per step, and the truth behind them.

    `frames` is a tuple, or a view of frames made on demand (`cooploc.streams`), which
    a long run uses so that its memory does not grow with the horizon.
    """

    setup: Setup
    frames: Sequence[Frame]
    truth: Truth

    def __post_init__(self) -> None:
        if getattr(self.frames, "is_stream", False):
            # frames made on demand (`cooploc.streams`): each step is checked as it is made
            if len(self.frames) != self.truth.n_steps:
                raise InvalidInputError(f"Recording.frames has {len(self.frames)} frames, "
                                        f"truth has {self.truth.n_steps} steps")
            return
        frames = tuple(self.frames)
        if len(frames) != self.truth.n_steps:
            raise InvalidInputError(
                f"Recording.frames has {len(frames)} frames, truth has {self.truth.n_steps} steps"
            )
        for k, frame in enumerate(frames):
            if frame.k != k:
                raise InvalidInputError(f"Recording.frames[{k}].k must be {k}, got {frame.k}")
            present = self.truth.vehicle_ids[self.truth.vehicle_present[k]]
            stray = np.setdiff1d(frame.vehicles, present)
            if stray.size:
                raise InvalidInputError(
                    f"Recording.frames[{k}].vehicles {stray.tolist()} are not present in truth"
                )
            for kind, batch in frame.batches.items():
                rows = self.truth.origin[k].get(kind)
                if rows is None or rows.size != len(batch):
                    raise InvalidInputError(
                        f"Recording.truth.origin[{k}][{kind!r}] must have {len(batch)} rows, "
                        f"got {None if rows is None else rows.size}"
                    )
        object.__setattr__(self, "frames", frames)

    def time_of(self, k: int) -> float:
        """The time (s) of step k; frames made on demand are not made again for it."""
        time = getattr(self.frames, "time", None)
        return float(time(k)) if callable(time) else self.frames[k].t


@dataclass(frozen=True, slots=True)
class Estimate:
    """What an estimator returns from `step`.

    Attributes
    ----------
    vehicles : beliefs of the vehicles present in the frame.
    features : beliefs of the features, or None if the method does not estimate them.
    info : diagnostics (association marginals, iterations used, bytes exchanged, ...).

    Notes
    -----
    The `info` keys that the runner and the metrics read — this is their one
    definition; every other key is a diagnostic of its estimator, documented there:

    - ``"set_valued"`` (bool): the vehicle ids are slots, not identities (anonymous
      measurements); `metrics.evaluate` scores the set after an optimal assignment.
    - ``"v2f_association"`` ((M,) int): the decided origin (feature id, −1 for clutter
      or undecided) of each V2F row of the frame, for estimators that name features by
      the scenario's ids; scored as association accuracy.
    - ``"v2f_track"`` ((M,) int): the estimator's own track id of each V2F row (−1:
      none), for estimators that start feature tracks of their own; tracks are scored
      as the true feature most of their rows came from (`metrics.score_association`),
      and feature estimates are renamed through that map; and per step, through the
      tracks' positions in `features` (same ids), as `metrics.paired_features` says.
    - ``"v2f_discarded"`` (int): V2F rows left unused this step (with ``"v2f_track"``);
      summed into `discarded_share`.
    - ``"nis"`` ((float, int)): the normalised innovation squared νᵀ S⁻¹ ν of this step's
      measurement updates, summed, and the sum of their degrees of freedom (dim ν) —
      (0.0, 0) on a step without update; reported by Gaussian filters that update with
      innovations (`gaussian.kf_update_nis`). The runner sums both over steps per run;
      summary.json's `nis_mean` is ΣNIS / Σdof.
    - ``"heading"`` ((n,) float, rad): the headings of `vehicles`, in their order, from an
      estimator that estimates them beside a vehicle layout without a heading (`plbp` on
      `sumo-*`); scored against `Truth.vehicle_heading` like a layout's heading.
    """

    vehicles: StateSet
    features: StateSet | None = None
    info: Mapping[str, Any] = field(default_factory=dict)
