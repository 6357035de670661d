"""Shared test helpers: recordings, recording surgery, running estimators, checks.

Imported by the test modules (``from helpers import ...``; ``tests/`` is on the path
through ``tests/conftest.py``). Everything random takes a seed or a generator.

The estimator contract's own pieces live in `cooploc.testing` (public, for plug-in
authors) and are re-exported here: `preset_recording`, `with_traffic`,
`traffic_recording`, `with_empty_frames`, `run_estimator`, `assert_valid_estimate`,
`assert_spd`, `assert_state_set`, `SMALL_STEPS`, `TRAFFIC_ABSENT`. Test-only helpers:

- `froehle_recording` — a small run of the ``froehle2018`` preset.
- `drop_rows` — remove the rows of one batch kind at some steps (missing fixes).
- `with_velocity_fixes` — GNSS rows of the position grown into rows of position and
  velocity (`sumo-*`'s form), with the same position part.
- `position_errors` — (T, N) Euclidean position error per step and vehicle.
- `assert_covariance_close` — a statistical check of samples against a covariance.
- `load_script` — import a benchmark or example script from its file.
- `make_traffic` — a SUMO `Traffic` made by hand (no SUMO needed), for `sumo.lay_sensors`.
"""

from __future__ import annotations

import dataclasses
import importlib.util
from collections.abc import Iterable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from cooploc.geometry import wrap_angle
from cooploc.scenarios.sumo import Traffic
from cooploc.sensors import GnssPosition
from cooploc.testing import (
    SMALL_STEPS,
    TRAFFIC_ABSENT,
    assert_spd,
    assert_state_set,
    assert_valid_estimate,
    preset_recording,
    run_estimator,
    traffic_recording,
    with_empty_frames,
    with_traffic,
)
from cooploc.types import Batch, Estimate, Frame, Recording

__all__ = [
    "SMALL_STEPS",
    "TRAFFIC_ABSENT",
    "assert_covariance_close",
    "assert_spd",
    "assert_state_set",
    "assert_valid_estimate",
    "drop_rows",
    "froehle_recording",
    "load_script",
    "position_errors",
    "preset_recording",
    "run_estimator",
    "traffic_recording",
    "with_empty_frames",
    "with_traffic",
    "with_velocity_fixes",
]

#: the repository root (scripts in benchmarks/ and examples/ are not a package)
ROOT = Path(__file__).resolve().parents[1]


def load_script(relative: str) -> ModuleType:
    """Import a script of the repository (e.g. "benchmarks/icp.py") from its file."""
    path = ROOT / relative
    spec = importlib.util.spec_from_file_location(f"script_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ----------------------------------------------------------------------------
# recordings
# ----------------------------------------------------------------------------


def froehle_recording(seed: Any, **overrides: Any) -> Recording:
    """A ``froehle2018`` run, by default `SMALL_STEPS` long (other fields: the paper's)."""
    overrides.setdefault("n_steps", SMALL_STEPS)
    return preset_recording("froehle2018", seed, overrides)


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


def with_velocity_fixes(recording: Recording, seed: Any, velocity_std: float = 0.5) -> Recording:
    """The same run with every GNSS row z_p = p + w_p (covariance R) grown into a row of
    position and velocity, z = [z_p, v + w_v], as `sumo-*` reports them.

    The covariance of a grown row is [[R, R/2], [R/2, R/4 + σ_v² I]] (σ_v = `velocity_std`):
    the velocity noise is correlated with the position's, w_v = w_p / 2 + σ_v ε, so only
    the marginal — not the conditional — of the position is the original row. The position
    part of every row and covariance stays the original, bit for bit.
    """
    rng = np.random.default_rng(seed)
    setup, truth = recording.setup, recording.truth
    pos, vel = list(setup.vehicle_layout.position), list(setup.vehicle_layout.velocity)
    d = len(pos)

    def grown(cov: np.ndarray) -> np.ndarray:
        out = np.empty((*cov.shape[:-2], 2 * d, 2 * d))
        out[..., :d, :d], out[..., :d, d:], out[..., d:, :d] = cov, cov / 2, cov / 2
        out[..., d:, d:] = cov / 4 + velocity_std**2 * np.eye(d)
        return out

    frames = []
    for k, frame in enumerate(recording.frames):
        gnss = frame.batches["gnss"]
        origin = truth.origin[k]["gnss"]
        state = truth.vehicle_states[k, np.searchsorted(truth.vehicle_ids, origin)]
        state[origin < 0] = 0.0  # clutter: noise about the origin
        w_p = gnss.z - state[:, pos]
        z_v = state[:, vel] + w_p / 2 + velocity_std * rng.standard_normal(w_p.shape)
        rows = Batch(np.concatenate([gnss.z, z_v], axis=1), grown(gnss.cov), gnss.sensor, gnss.subject)
        frames.append(Frame(k, frame.t, frame.vehicles, {**frame.batches, "gnss": rows}, frame.links))
    model = setup.sensors["gnss"]
    sensor = GnssPosition({i: grown(c) for i, c in model.covariances.items()},
                          None if model.default_cov is None else grown(model.default_cov), (*pos, *vel))
    return Recording(dataclasses.replace(setup, sensors={**setup.sensors, "gnss": sensor}), frames, truth)


# ----------------------------------------------------------------------------
# running estimators
# ----------------------------------------------------------------------------


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


def make_traffic(states: np.ndarray, present: np.ndarray, heading: np.ndarray | None = None, *,
                 features: np.ndarray | None = None,
                 junctions: tuple[list[str], np.ndarray, list[int]] | None = None) -> Traffic:
    """A `Traffic` by hand: vehicle states (T, N, 4) with presence (T, N), headings (T, N)
    (default: along the velocity), static features (K, 2), junctions (ids, (J, 2), roads)."""
    T, N = present.shape
    states = np.where(present[..., None], states, 0.0)
    if heading is None:
        heading = np.arctan2(states[..., 3], states[..., 2])
    heading = np.where(present, wrap_angle(heading), 0.0)
    features = np.zeros((0, 2)) if features is None else np.asarray(features, dtype=float)
    ids, xy, roads = junctions if junctions is not None else (["j0"], np.zeros((1, 2)), [4])
    return Traffic(
        t=np.arange(T, dtype=float), vehicle_ids=np.arange(N, dtype=np.int64) * 3 + 1,
        vehicle_states=states, vehicle_present=present,
        pedestrian_ids=np.zeros(0, dtype=np.int64), pedestrian_states=np.zeros((T, 0, 4)),
        pedestrian_present=np.zeros((T, 0), dtype=bool), static_features=features,
        static_kind=np.full(features.shape[0], 2, dtype=np.int64), centre=np.zeros(2),
        bounds=np.array([[-1e3, 1e3], [-1e3, 1e3]]), signals=np.zeros((0, 2)), vehicle_heading=heading,
        junction_ids=np.array(ids, dtype=str), junctions=np.asarray(xy, dtype=float).reshape(-1, 2),
        junction_roads=np.asarray(roads, dtype=np.int64))
