"""Shared test helpers: recordings, recording surgery, running estimators, checks.

Imported by the test modules (``from helpers import ...``; ``tests/`` is on the path
through ``tests/conftest.py``). Everything random takes a seed or a generator.

- `froehle_recording` — a small run of the ``froehle2018`` preset.
- `with_traffic` — rebuild a recording so that vehicles enter and leave.
- `traffic_recording` — the standard traffic case of the test suite: 3 vehicles,
  vehicle 1 enters at step 5, vehicle 2 is away for steps 10–19.
- `with_empty_frames` — frames without vehicles, without batches, with empty batches.
- `drop_rows` — remove the rows of one batch kind at some steps (missing fixes).
- `run_estimator` — construct an estimator through the registry and step it through.
- `position_errors` — (T, N) Euclidean position error per step and vehicle.
- `assert_valid_estimate` — the shape/finiteness/SPD part of the estimator contract.
- `assert_covariance_close` — a statistical check of samples against a covariance.
"""

from __future__ import annotations

import dataclasses
import importlib.util
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from cooploc.estimators import get_estimator, make_estimator
from cooploc.scenarios import get_preset
from cooploc.types import Batch, Estimate, Frame, Recording, StateSet

#: the repository root (scripts in benchmarks/ and examples/ are not a package)
ROOT = Path(__file__).resolve().parents[1]


def load_script(relative: str) -> ModuleType:
    """Import a script of the repository (e.g. "benchmarks/icp.py") from its file."""
    path = ROOT / relative
    spec = importlib.util.spec_from_file_location(f"script_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module

__all__ = [
    "SMALL_STEPS",
    "TRAFFIC_ABSENT",
    "assert_covariance_close",
    "assert_spd",
    "assert_state_set",
    "assert_valid_estimate",
    "drop_rows",
    "froehle_recording",
    "position_errors",
    "preset_recording",
    "run_estimator",
    "traffic_recording",
    "with_empty_frames",
    "with_traffic",
]

#: Length of the small recordings most tests use: long enough for every estimator to
#: leave its start-up transient, short enough that the suite stays fast.
SMALL_STEPS = 40


# ----------------------------------------------------------------------------
# recordings
# ----------------------------------------------------------------------------


def preset_recording(name: str, seed: Any, overrides: Mapping[str, Any] | None = None) -> Recording:
    """One run of preset `name` with parameter overrides, from `default_rng(seed)`."""
    preset = get_preset(name)
    params = preset.params.with_overrides(dict(overrides or {}))
    return preset.generate(np.random.default_rng(seed), params)


def froehle_recording(seed: Any, **overrides: Any) -> Recording:
    """A ``froehle2018`` run, by default `SMALL_STEPS` long (other fields: the paper's)."""
    overrides.setdefault("n_steps", SMALL_STEPS)
    return preset_recording("froehle2018", seed, overrides)


def _vehicle_rows(batch: Batch, origin: np.ndarray, absent: np.ndarray,
                  vehicle_ids: np.ndarray, feature_ids: np.ndarray) -> np.ndarray:
    """Mask of the rows that do not involve an absent vehicle (as sensor, subject or origin)."""
    keep = ~np.isin(batch.sensor, absent) & ~np.isin(batch.subject, absent)
    # origin is an entity id; it names a vehicle only where it is not a feature id
    origin_is_vehicle = np.isin(origin, vehicle_ids) & ~np.isin(origin, feature_ids)
    return keep & ~(origin_is_vehicle & np.isin(origin, absent))


def with_traffic(recording: Recording, absent: Mapping[int, Iterable[int]],
                 keep_prior: bool = False) -> Recording:
    """The same run with vehicles taken away at some steps.

    Parameters
    ----------
    recording : a run in which every vehicle is present at every step.
    absent : vehicle id → steps at which it is not on the road.

    Rows measured by, about, or originating from an absent vehicle are removed from
    every batch (and from `Truth.origin`), links touching it are dropped, its true
    state is zeroed and `Truth.vehicle_present` is cleared. Unless `keep_prior`, the
    prior in the setup keeps only the vehicles present at step 0: a vehicle that enters
    later has no prior and is born from its first GNSS fix
    (`cooploc.estimators.base.birth_beliefs`). With `keep_prior` every vehicle keeps its
    step-0 prior (estimators predict it to the step where the vehicle enters).
    """
    truth = recording.truth
    T = truth.n_steps
    present = np.array(truth.vehicle_present)
    for vehicle, steps in absent.items():
        col = int(np.flatnonzero(truth.vehicle_ids == vehicle)[0])
        present[list(steps), col] = False
    frames, origins = [], []
    for k, frame in enumerate(recording.frames):
        gone = truth.vehicle_ids[~present[k]]
        batches, origin = {}, {}
        for kind, batch in frame.batches.items():
            rows = _vehicle_rows(batch, truth.origin[k][kind], gone, truth.vehicle_ids,
                                 truth.feature_ids)
            batches[kind] = batch.select(rows)
            origin[kind] = truth.origin[k][kind][rows]
        links = frame.links[~np.isin(frame.links, gone).any(axis=1)]
        vehicles = frame.vehicles[~np.isin(frame.vehicles, gone)]
        frames.append(Frame(k, frame.t, vehicles, batches, links))
        origins.append(origin)
    states = np.where(present[..., None], truth.vehicle_states, 0.0)
    new_truth = dataclasses.replace(truth, vehicle_states=states, vehicle_present=present,
                                    origin=origins)
    prior = recording.setup.vehicle_prior
    at_start = prior.ids[np.isin(prior.ids, truth.vehicle_ids[present[0]])]
    setup = recording.setup if keep_prior else dataclasses.replace(
        recording.setup, vehicle_prior=prior.take(at_start))
    assert len(frames) == T
    return Recording(setup, frames, new_truth)


#: The traffic pattern of the suite: vehicle 1 enters at step 5, vehicle 2 leaves for
#: steps 10–19 and comes back at step 20.
TRAFFIC_ABSENT: dict[int, range] = {1: range(0, 5), 2: range(10, 20)}


def traffic_recording(seed: Any, n_steps: int = SMALL_STEPS, **overrides: Any) -> Recording:
    """A 3-vehicle ``froehle2018`` run with the `TRAFFIC_ABSENT` pattern."""
    recording = froehle_recording(seed, n_vehicles=3, n_steps=n_steps, **overrides)
    return with_traffic(recording, TRAFFIC_ABSENT)


def with_empty_frames(
    recording: Recording,
    no_vehicles: Sequence[int] = (0, 1, 15),
    no_batches: Sequence[int] = (5, 6, 7),
    empty_batches: Sequence[int] = (10, 11, 12),
) -> Recording:
    """The same run with degenerate frames at the given steps.

    no_vehicles : frames with no vehicle and no measurement (everybody off the road).
    no_batches : vehicles present, but no batch at all (a dropped radio packet).
    empty_batches : vehicles present, every batch kind there but with zero rows.
    """
    truth = recording.truth
    frames, origins = [], []
    for k, frame in enumerate(recording.frames):
        origin = dict(truth.origin[k])
        if k in no_vehicles:
            frame, origin = Frame(k, frame.t, np.zeros(0, np.int64)), {}
        elif k in no_batches:
            frame, origin = Frame(k, frame.t, frame.vehicles), {}
        elif k in empty_batches:
            batches = {kind: Batch.empty(batch.dim) for kind, batch in frame.batches.items()}
            frame = Frame(k, frame.t, frame.vehicles, batches)
            origin = {kind: np.zeros(0, np.int64) for kind in batches}
        frames.append(frame)
        origins.append(origin)
    return Recording(recording.setup, frames, dataclasses.replace(truth, origin=origins))


def drop_rows(recording: Recording, kind: str, steps: Iterable[int], rows_of: Any) -> Recording:
    """The same run with rows of `kind` removed at `steps`; `rows_of(batch)` gives a mask."""
    truth = recording.truth
    steps = set(steps)
    frames, origins = [], []
    for k, frame in enumerate(recording.frames):
        origin = dict(truth.origin[k])
        if k in steps and kind in frame.batches:
            batch = frame.batches[kind]
            keep = ~np.asarray(rows_of(batch), dtype=bool)
            frame = Frame(k, frame.t, frame.vehicles,
                          {**frame.batches, kind: batch.select(keep)}, frame.links)
            origin[kind] = origin[kind][keep]
        frames.append(frame)
        origins.append(origin)
    return Recording(recording.setup, frames, dataclasses.replace(truth, origin=origins))


# ----------------------------------------------------------------------------
# running estimators
# ----------------------------------------------------------------------------


def run_estimator(name: str, recording: Recording, seed: Any = 0,
                  params: Any = None) -> list[Estimate]:
    """Construct `name` through the registry (truth only if it needs it) and run it."""
    cls = get_estimator(name)
    estimator = make_estimator(name, recording.setup, params, np.random.default_rng(seed),
                               truth=recording.truth if cls.needs_truth else None)
    return [estimator.step(frame) for frame in recording.frames]


def position_errors(estimates: Sequence[Estimate], recording: Recording) -> np.ndarray:
    """(T, N) Euclidean position error of each vehicle (NaN where absent)."""
    truth = recording.truth
    pos = list(recording.setup.vehicle_layout.position)
    out = np.full(truth.vehicle_present.shape, np.nan)
    for k, estimate in enumerate(estimates):
        ids = estimate.vehicles.ids
        cols = np.searchsorted(truth.vehicle_ids, ids)
        diff = estimate.vehicles.mean[:, pos] - truth.vehicle_states[k, cols][:, pos]
        out[k, cols] = np.linalg.norm(diff, axis=1)
    return out


# ----------------------------------------------------------------------------
# checks
# ----------------------------------------------------------------------------


def assert_spd(cov: np.ndarray, name: str = "cov") -> None:
    """Every matrix of `cov (n, d, d)` finite, symmetric and positive definite."""
    assert np.isfinite(cov).all(), f"{name} has non-finite entries"
    # symmetric up to round-off of a Joseph update (relative 1e-10)
    scale = np.abs(cov).max() if cov.size else 1.0
    np.testing.assert_allclose(cov, np.swapaxes(cov, -1, -2), rtol=0, atol=1e-10 * scale,
                               err_msg=f"{name} is not symmetric")
    if cov.size:
        assert (np.linalg.eigvalsh(cov) > 0).all(), f"{name} is not positive definite"


def assert_state_set(states: StateSet, dim: int, name: str) -> None:
    n = len(states)
    assert states.mean.shape == (n, dim), f"{name}.mean has shape {states.mean.shape}"
    assert states.cov.shape == (n, dim, dim), f"{name}.cov has shape {states.cov.shape}"
    assert np.isfinite(states.mean).all(), f"{name}.mean has NaN or inf"
    assert_spd(states.cov, f"{name}.cov")


def assert_valid_estimate(estimate: Estimate, frame: Frame, recording: Recording) -> None:
    """The contract of `Estimator.step`: one belief per present vehicle, finite, SPD."""
    assert isinstance(estimate, Estimate), f"step returned {type(estimate).__name__}"
    vehicles = estimate.vehicles
    assert isinstance(vehicles, StateSet)
    assert sorted(vehicles.ids.tolist()) == sorted(frame.vehicles.tolist()), (
        f"step {frame.k}: estimate has vehicles {vehicles.ids.tolist()}, "
        f"frame has {frame.vehicles.tolist()}"
    )
    assert_state_set(vehicles, recording.setup.vehicle_layout.dim, f"step {frame.k} vehicles")
    if estimate.features is not None:
        assert isinstance(estimate.features, StateSet)
        layout = recording.setup.feature_layout
        dim = layout.dim if layout is not None else estimate.features.mean.shape[1]
        assert_state_set(estimate.features, dim, f"step {frame.k} features")


def assert_covariance_close(samples: np.ndarray, cov: np.ndarray, mean: np.ndarray | None = None,
                            n_sigma: float = 6.0) -> None:
    """Samples (N, d) have covariance `cov` (d, d) — a test that passes for any seed.

    The samples are whitened with cov's range (so singular covariances work); for N
    independent draws every entry of the whitened second moment E[ww^T] − I has
    standard deviation at most sqrt(2/N) (diagonal; sqrt(1/N) off it), and the
    whitened mean sqrt(1/N). Deviations beyond `n_sigma` such deviations fail: with
    n_sigma = 6 and d ≤ 4 (≤ 14 numbers checked) a correct sampler fails with
    probability below 1e-7. Directions outside the range must carry no sample energy.
    """
    samples = np.asarray(samples, dtype=float)
    n, d = samples.shape
    mean = np.zeros(d) if mean is None else np.asarray(mean, dtype=float)
    centred = samples - mean
    eigval, eigvec = np.linalg.eigh(cov)
    rank = eigval > 1e-12 * eigval.max()
    white = centred @ eigvec[:, rank] / np.sqrt(eigval[rank])
    second = white.T @ white / n
    np.testing.assert_allclose(second, np.eye(int(rank.sum())), rtol=0,
                               atol=n_sigma * np.sqrt(2.0 / n),
                               err_msg="sample covariance differs from cov")
    np.testing.assert_allclose(white.mean(axis=0), 0.0, rtol=0, atol=n_sigma / np.sqrt(n),
                               err_msg="sample mean differs from mean")
    if (~rank).any():
        null = centred @ eigvec[:, ~rank]
        # round-off only: relative to the sample spread along the range
        scale = np.sqrt(eigval.max())
        np.testing.assert_allclose(null, 0.0, rtol=0, atol=1e-9 * scale,
                                   err_msg="samples leave the range of a singular cov")
