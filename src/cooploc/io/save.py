"""`save_recording`: a `Recording` as the folder of `cooploc.io` (format version 1)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from cooploc.errors import InvalidInputError
from cooploc.io.layout import (
    FORMAT_VERSION,
    FRAMES_FILE,
    HEADING_COLUMN,
    INFINITY,
    MEASUREMENTS_FILE,
    SENSOR_POSES_FILE,
    SETUP_FILE,
    TRUTH_FEATURES_FILE,
    TRUTH_VEHICLES_FILE,
)
from cooploc.types import FloatArray, IntArray, Recording, Setup, StateSet

__all__ = ["save_recording"]


def save_recording(recording: Recording, folder: str | Path) -> Path:
    """Write `recording` to `folder` (created if needed; existing files are replaced).

    Returns the folder as a `Path`. See the module docstring for the layout.
    """
    if not isinstance(recording, Recording):
        raise InvalidInputError(
            f"save_recording needs a Recording, got {type(recording).__name__}"
        )
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        # allow_nan=False: Setup validates its numbers as finite, and strict JSON keeps
        # the file readable by tools other than Python's json module.
        text = json.dumps(_setup_to_dict(recording.setup), indent=2, ensure_ascii=False,
                          allow_nan=False, default=_json_default)
    except ValueError as exc:
        raise InvalidInputError(
            f"{SETUP_FILE}: the Setup holds a non-finite number ({exc})"
        ) from exc
    (folder / SETUP_FILE).write_text(text + "\n", encoding="utf-8")
    frames_table, measurements_table = _frame_tables(recording)
    pq.write_table(frames_table, folder / FRAMES_FILE)
    pq.write_table(measurements_table, folder / MEASUREMENTS_FILE)
    truth = recording.truth
    pq.write_table(_truth_table(truth.vehicle_ids, truth.vehicle_states, truth.vehicle_present,
                                truth.vehicle_heading), folder / TRUTH_VEHICLES_FILE)
    pq.write_table(_truth_table(truth.feature_ids, truth.feature_states, truth.feature_present),
                   folder / TRUTH_FEATURES_FILE)
    pq.write_table(_poses_table(truth.sensor_poses, recording.setup.infrastructure_ids),
                   folder / SENSOR_POSES_FILE)
    return folder


def _json_default(value: Any) -> Any:
    """NumPy scalars and arrays that slipped into a to_dict() become plain JSON values."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _encode_infinity(value: Any) -> Any:
    """Infinite floats (a radar's unlimited range) as the strings of `layout.INFINITY`."""
    if isinstance(value, dict):
        return {key: _encode_infinity(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_encode_infinity(item) for item in value]
    if isinstance(value, (float, np.floating)) and np.isinf(value):
        return next(text for text, number in INFINITY.items() if number == value)
    return value


def _prior_to_dict(prior: StateSet | None) -> dict[str, Any] | None:
    if prior is None:
        return None
    # The dimension is stored too: an empty set has no rows to show it.
    return {**prior.to_dict(), "dim": int(prior.mean.shape[1])}


def _setup_to_dict(setup: Setup) -> dict[str, Any]:
    def optional(obj: Any) -> Any:
        return None if obj is None else obj.to_dict()

    return {
        "format_version": FORMAT_VERSION,
        "description": setup.description,
        "dt": setup.dt,
        "n_steps": setup.n_steps,
        "vehicle_layout": setup.vehicle_layout.to_dict(),
        "vehicle_motion": setup.vehicle_motion.to_dict(),
        "vehicle_prior": _prior_to_dict(setup.vehicle_prior),
        "sensors": {kind: _encode_infinity(sensor.to_dict()) for kind, sensor in setup.sensors.items()},
        "feature_layout": optional(setup.feature_layout),
        "feature_motion": optional(setup.feature_motion),
        "feature_prior": _prior_to_dict(setup.feature_prior),
        "birth_cov": None if setup.birth_cov is None else np.asarray(setup.birth_cov).tolist(),
        "detection_probability": setup.detection_probability,
        "clutter_rate": setup.clutter_rate,
        "clutter_region": (None if setup.clutter_region is None
                           else np.asarray(setup.clutter_region).tolist()),
        "infrastructure_ids": list(setup.infrastructure_ids),
    }


def _list_array(lengths: IntArray, values: pa.Array) -> pa.ListArray:
    """A list<…> array whose i-th list holds the next lengths[i] of `values`."""
    offsets = np.zeros(lengths.size + 1, dtype=np.int32)
    np.cumsum(lengths, out=offsets[1:])
    return pa.ListArray.from_arrays(pa.array(offsets, pa.int32()), values)


def _concat(parts: Sequence[np.ndarray], dtype: type, width: int = 0) -> np.ndarray:
    """np.concatenate that also works for an empty list (shape (0,) or (0, width))."""
    if parts:
        return np.concatenate(parts).astype(dtype, copy=False)
    return np.zeros((0, width) if width else 0, dtype=dtype)


def _frame_tables(recording: Recording) -> tuple[pa.Table, pa.Table]:
    """frames.parquet and measurements.parquet, built from one pass over the frames.

    The only Python loop is over frames and their batches (not over rows); all rows are
    gathered with a handful of concatenations.
    """
    frames = recording.frames
    steps = np.arange(len(frames), dtype=np.int64)
    times = np.array([frame.t for frame in frames], dtype=np.float64)
    vehicles = [frame.vehicles for frame in frames]
    links = [frame.links for frame in frames]
    kinds: list[str] = []            # one entry per batch, frame-major
    n_kinds = np.zeros(steps.size, dtype=np.int64)
    dims: list[int] = []
    counts: list[int] = []
    z_parts: list[FloatArray] = []
    cov_parts: list[FloatArray] = []
    sensor_parts: list[IntArray] = []
    subject_parts: list[IntArray] = []
    origin_parts: list[IntArray] = []
    for k, frame in enumerate(frames):
        n_kinds[k] = len(frame.batches)
        for kind, batch in frame.batches.items():
            kinds.append(kind)
            dims.append(batch.dim)
            counts.append(len(batch))
            z_parts.append(batch.z.ravel())
            cov_parts.append(batch.cov.ravel())
            sensor_parts.append(batch.sensor)
            subject_parts.append(batch.subject)
            origin_parts.append(recording.truth.origin[k][kind])

    dim_of_batch = np.array(dims, dtype=np.int64)
    rows_of_batch = np.array(counts, dtype=np.int64)
    step_of_batch = np.repeat(steps, n_kinds)
    frames_table = pa.table({
        "step": pa.array(steps, pa.int64()),
        "t": pa.array(times, pa.float64()),
        "vehicles": _list_array(np.array([v.size for v in vehicles]),
                                pa.array(_concat(vehicles, np.int64), pa.int64())),
        "links": _list_array(
            np.array([e.shape[0] for e in links]),
            pa.FixedSizeListArray.from_arrays(
                pa.array(_concat(links, np.int64, 2).ravel(), pa.int64()), 2),
        ),
        "batch_kinds": _list_array(n_kinds, pa.array(kinds, pa.string())),
        "batch_dims": _list_array(n_kinds, pa.array(dim_of_batch, pa.int64())),
    })

    # one row per measurement: per-batch values repeated over the batch's rows
    batch_of_row = np.repeat(np.arange(rows_of_batch.size), rows_of_batch)
    first_row = np.cumsum(rows_of_batch) - rows_of_batch
    dz_of_row = dim_of_batch[batch_of_row]
    row_steps = step_of_batch[batch_of_row]
    measurements_table = pa.table({
        "step": pa.array(row_steps, pa.int64()),
        "t": pa.array(times[row_steps], pa.float64()),
        "kind": pc.take(pa.array(kinds, pa.string()), pa.array(batch_of_row, pa.int64())),
        "row": pa.array(np.arange(batch_of_row.size) - first_row[batch_of_row], pa.int64()),
        "sensor": pa.array(_concat(sensor_parts, np.int64), pa.int64()),
        "subject": pa.array(_concat(subject_parts, np.int64), pa.int64()),
        "origin": pa.array(_concat(origin_parts, np.int64), pa.int64()),
        "z": _list_array(dz_of_row, pa.array(_concat(z_parts, np.float64), pa.float64())),
        "cov": _list_array(dz_of_row**2, pa.array(_concat(cov_parts, np.float64), pa.float64())),
    })
    return frames_table, measurements_table


def _truth_table(ids: IntArray, states: FloatArray, present: np.ndarray,
                 heading: FloatArray | None = None) -> pa.Table:
    """Every (step, id) pair, step-major, with presence, the state components and the
    heading kept beside them (`Truth.vehicle_heading`), if any."""
    n_steps, n, dim = states.shape
    columns: dict[str, pa.Array] = {
        "step": pa.array(np.repeat(np.arange(n_steps, dtype=np.int64), n), pa.int64()),
        "id": pa.array(np.tile(ids, n_steps), pa.int64()),
        "present": pa.array(present.ravel(), pa.bool_()),
    }
    flat = states.reshape(n_steps * n, dim)
    for i in range(dim):
        columns[f"x_{i}"] = pa.array(np.ascontiguousarray(flat[:, i]), pa.float64())
    if heading is not None:
        columns[HEADING_COLUMN] = pa.array(np.ascontiguousarray(heading).ravel(), pa.float64())
    return pa.table(columns)


def _poses_table(poses: FloatArray, infrastructure_ids: Sequence[int]) -> pa.Table:
    ids = (np.asarray(infrastructure_ids, dtype=np.int64) if len(infrastructure_ids) == len(poses)
           else np.full(len(poses), -1, dtype=np.int64))
    return pa.table({
        "sensor": pa.array(ids, pa.int64()),
        "x": pa.array(np.ascontiguousarray(poses[:, 0]), pa.float64()),
        "y": pa.array(np.ascontiguousarray(poses[:, 1]), pa.float64()),
        "yaw": pa.array(np.ascontiguousarray(poses[:, 2]), pa.float64()),
    })
