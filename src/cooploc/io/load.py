"""`load_recording`: the folder of `cooploc.io` back into a `Recording`.

Every malformed file or field raises `InvalidInputError` naming the file and the field
(and the value), never a pyarrow or NumPy traceback.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
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
    STATE_COLUMN,
    TRUTH_FEATURES_FILE,
    TRUTH_VEHICLES_FILE,
)
from cooploc.io.validate import validate_recording
from cooploc.motion import motion_from_dict
from cooploc.sensors import sensor_from_dict
from cooploc.types import (
    Batch,
    FloatArray,
    Frame,
    IntArray,
    Recording,
    Setup,
    StateLayout,
    StateSet,
    Truth,
)

__all__ = ["load_recording"]


def load_recording(folder: str | Path) -> Recording:
    """Read a recording written by `save_recording` (or by hand, see the module docstring).

    Raises `InvalidInputError` naming the file and the field when a file is missing or
    its content is malformed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InvalidInputError(f"recording folder {str(folder)!r} does not exist")
    setup = _load_setup(folder / SETUP_FILE)
    frames_table = _read_table(folder, FRAMES_FILE)
    measurements_table = _read_table(folder, MEASUREMENTS_FILE)
    frames, origin = _load_frames(frames_table, measurements_table)
    n_steps = len(frames)
    vehicle_ids, vehicle_states, vehicle_present, heading = _load_truth(
        _read_table(folder, TRUTH_VEHICLES_FILE), TRUTH_VEHICLES_FILE, n_steps, heading=True)
    feature_ids, feature_states, feature_present, _ = _load_truth(
        _read_table(folder, TRUTH_FEATURES_FILE), TRUTH_FEATURES_FILE, n_steps)
    poses = _load_poses(_read_table(folder, SENSOR_POSES_FILE), setup.infrastructure_ids)
    try:
        truth = Truth(vehicle_ids, vehicle_states, vehicle_present, feature_ids, feature_states,
                      feature_present, origin, poses, heading)
    except InvalidInputError as exc:
        raise InvalidInputError(f"truth tables of {str(folder)!r}: {exc}") from exc
    try:
        return validate_recording(Recording(setup, frames, truth), files=True)
    except InvalidInputError as exc:
        raise InvalidInputError(f"recording {str(folder)!r} is inconsistent: {exc}") from exc


@contextmanager
def _field_errors(file: str, field: str) -> Iterator[None]:
    """Turn whatever a malformed field makes the parsers raise into one clear error."""
    try:
        yield
    except InvalidInputError as exc:
        raise InvalidInputError(f"{file}: field {field!r}: {exc}") from exc
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise InvalidInputError(
            f"{file}: field {field!r} is malformed ({type(exc).__name__}: {exc})"
        ) from exc


def _load_setup(path: Path) -> Setup:
    file = path.name
    if not path.is_file():
        raise InvalidInputError(f"{file}: file is missing in {str(path.parent)!r}")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidInputError(f"{file}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise InvalidInputError(f"{file}: must hold a JSON object, got {type(data).__name__}")

    def need(key: str) -> Any:
        if key not in data:
            raise InvalidInputError(f"{file}: field {key!r} is missing")
        return data[key]

    version = need("format_version")
    if version != FORMAT_VERSION:
        raise InvalidInputError(
            f"{file}: field 'format_version' must be {FORMAT_VERSION}, got {version!r}"
        )

    def optional(key: str, parse: Any) -> Any:
        value = data.get(key)
        if value is None:
            return None
        with _field_errors(file, key):
            return parse(value)

    with _field_errors(file, "vehicle_layout"):
        vehicle_layout = StateLayout.from_dict(need("vehicle_layout"))
    with _field_errors(file, "vehicle_motion"):
        vehicle_motion = motion_from_dict(need("vehicle_motion"))
    with _field_errors(file, "vehicle_prior"):
        vehicle_prior = StateSet.from_dict(need("vehicle_prior"))
    sensors_raw = data.get("sensors", {})
    if not isinstance(sensors_raw, dict):
        raise InvalidInputError(f"{file}: field 'sensors' must map kinds to sensor models, "
                                f"got {sensors_raw!r}")
    sensors = {}
    for kind, spec in sensors_raw.items():
        with _field_errors(file, f"sensors.{kind}"):
            sensors[kind] = sensor_from_dict(_decode_infinity(spec))
    with _field_errors(file, "infrastructure_ids"):
        infrastructure_ids = tuple(int(i) for i in data.get("infrastructure_ids", ()))
    description = data.get("description", "")
    if not isinstance(description, str):
        raise InvalidInputError(f"{file}: field 'description' must be a string, "
                                f"got {description!r}")
    def number(key: str, default: Any = None, *, integer: bool = False) -> Any:
        value = need(key) if default is None else data.get(key, default)
        kinds = (int,) if integer else (int, float)
        if isinstance(value, bool) or not isinstance(value, kinds):
            raise InvalidInputError(f"{file}: field {key!r} must be "
                                    f"{'an integer' if integer else 'a number'}, got {value!r}")
        return value

    dt, n_steps = number("dt"), number("n_steps", integer=True)
    detection_probability = number("detection_probability", 1.0)
    clutter_rate = number("clutter_rate", 0.0)
    try:
        return Setup(
            dt=dt,
            n_steps=n_steps,
            vehicle_layout=vehicle_layout,
            vehicle_motion=vehicle_motion,
            vehicle_prior=vehicle_prior,
            sensors=sensors,
            feature_layout=optional("feature_layout", StateLayout.from_dict),
            feature_motion=optional("feature_motion", motion_from_dict),
            feature_prior=optional("feature_prior", StateSet.from_dict),
            birth_cov=optional("birth_cov", lambda v: np.asarray(v, dtype=np.float64)),
            detection_probability=detection_probability,
            clutter_rate=clutter_rate,
            clutter_region=optional("clutter_region", lambda v: np.asarray(v, dtype=np.float64)),
            infrastructure_ids=infrastructure_ids,
            description=description,
        )
    except InvalidInputError as exc:
        raise InvalidInputError(f"{file}: {exc}") from exc
    except (TypeError, ValueError) as exc:  # a safety net: every scalar is type-checked above
        raise InvalidInputError(f"{file}: a field has the wrong type ({exc})") from exc


def _decode_infinity(value: Any) -> Any:
    """The strings "inf" / "-inf" that `save_recording` writes for infinite floats, as floats."""
    if isinstance(value, dict):
        return {key: _decode_infinity(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_decode_infinity(item) for item in value]
    if isinstance(value, str) and value in INFINITY:
        return INFINITY[value]
    return value


def _read_table(folder: Path, file: str) -> pa.Table:
    path = folder / file
    if not path.is_file():
        raise InvalidInputError(f"{file}: file is missing in {str(folder)!r}")
    try:
        return pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise InvalidInputError(f"{file}: not a readable Parquet file ({exc})") from exc


def _column(table: pa.Table, file: str, name: str, type_: pa.DataType) -> pa.Array:
    """Column `name` cast (safely) to `type_`, without nulls, as one contiguous array."""
    if name not in table.column_names:
        raise InvalidInputError(
            f"{file}: column {name!r} is missing; found columns {table.column_names}"
        )
    column = table.column(name)
    try:
        column = column.cast(type_, safe=True)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError) as exc:
        raise InvalidInputError(
            f"{file}: column {name!r} must be {type_}, got {column.type} ({exc})"
        ) from exc
    array = column.combine_chunks()
    nulls = array.null_count
    inner = array
    while nulls == 0 and (pa.types.is_list(inner.type) or pa.types.is_large_list(inner.type)):
        inner = inner.flatten()  # null entries inside lists are malformed too
        nulls = inner.null_count
    if nulls:
        raise InvalidInputError(f"{file}: column {name!r} has null values")
    return array


def _numpy(array: pa.Array, dtype: type) -> np.ndarray:
    return np.asarray(array.to_numpy(zero_copy_only=False), dtype=dtype)


def _list_parts(array: pa.Array) -> tuple[IntArray, pa.Array]:
    """Lengths (n,) of a list array's entries and its flattened values."""
    lengths = _numpy(pc.list_value_length(array), np.int64)
    return lengths, array.flatten()


_LIST_INT = pa.large_list(pa.int64())
_LIST_FLOAT = pa.large_list(pa.float64())
_LIST_STR = pa.large_list(pa.large_string())


def _load_frames(
    frames_table: pa.Table, measurements_table: pa.Table
) -> tuple[list[Frame], list[dict[str, IntArray]]]:
    """Frames and the per-step origins from frames.parquet and measurements.parquet."""
    ff, mf = FRAMES_FILE, MEASUREMENTS_FILE
    steps = _numpy(_column(frames_table, ff, "step", pa.int64()), np.int64)
    n_steps = steps.size
    order = np.argsort(steps, kind="stable")
    if not np.array_equal(steps[order], np.arange(n_steps)):
        raise InvalidInputError(
            f"{ff}: column 'step' must hold each step 0..{n_steps - 1} exactly once, "
            f"got {np.sort(steps)[:20].tolist()}"
        )
    if not np.array_equal(order, np.arange(n_steps)):
        frames_table = frames_table.take(pa.array(order))
    times = _numpy(_column(frames_table, ff, "t", pa.float64()), np.float64)
    n_vehicles, vehicles = _list_parts(_column(frames_table, ff, "vehicles", _LIST_INT))
    vehicles_flat = _numpy(vehicles, np.int64)
    # links may be list<fixed_size_list<int64, 2>> (as written) or list<list<int64>>
    n_links, link_items = _list_parts(
        _column(frames_table, ff, "links", pa.large_list(_LIST_INT)))
    pair_sizes, link_values = _list_parts(link_items)
    if (pair_sizes != 2).any():
        raise InvalidInputError(f"{ff}: column 'links' must hold [a, b] pairs, found an entry "
                                f"of length {int(pair_sizes[pair_sizes != 2][0])}")
    links_flat = _numpy(link_values, np.int64).reshape(-1, 2)
    n_kinds, kinds = _list_parts(_column(frames_table, ff, "batch_kinds", _LIST_STR))
    n_dims, dims = _list_parts(_column(frames_table, ff, "batch_dims", _LIST_INT))
    if not np.array_equal(n_kinds, n_dims):
        k = int(np.flatnonzero(n_kinds != n_dims)[0])
        raise InvalidInputError(f"{ff}: step {k} has {n_kinds[k]} batch_kinds but "
                                f"{n_dims[k]} batch_dims")
    kind_of_batch = np.asarray(kinds.to_pylist(), dtype=object)
    dim_of_batch = _numpy(dims, np.int64)
    if (dim_of_batch < 1).any():
        raise InvalidInputError(f"{ff}: column 'batch_dims' must be >= 1, "
                                f"got {int(dim_of_batch.min())}")
    step_of_batch = np.repeat(np.arange(n_steps), n_kinds)
    kind_names = sorted(set(kind_of_batch.tolist()))
    code_of_batch = np.searchsorted(np.array(kind_names, dtype=object), kind_of_batch)
    code_of_batch = code_of_batch.astype(np.int64)
    n_codes = max(len(kind_names), 1)
    batch_key = step_of_batch * n_codes + code_of_batch
    if np.unique(batch_key).size != batch_key.size:
        values, counts = np.unique(batch_key, return_counts=True)
        dup = int(values[counts > 1][0])
        raise InvalidInputError(f"{ff}: step {dup // n_codes} lists kind "
                                f"{kind_names[dup % n_codes]!r} twice in 'batch_kinds'")

    # --- measurement rows → (batch, row), vectorised ---------------------------------
    m_step = _numpy(_column(measurements_table, mf, "step", pa.int64()), np.int64)
    m_kind = _column(measurements_table, mf, "kind", pa.large_string())
    m_row = _numpy(_column(measurements_table, mf, "row", pa.int64()), np.int64)
    m_code = pc.index_in(m_kind, value_set=pa.array(kind_names, pa.large_string()))
    code = _numpy(m_code.fill_null(-1), np.int64)
    key = m_step * n_codes + code
    sorter = np.argsort(batch_key, kind="stable")
    pos = np.minimum(np.searchsorted(batch_key, key, sorter=sorter), max(batch_key.size - 1, 0))
    found = (code >= 0) & (batch_key.size > 0)
    if batch_key.size:
        found &= batch_key[sorter[pos]] == key
    if not found.all():
        i = int(np.flatnonzero(~found)[0])
        raise InvalidInputError(
            f"{mf}: row {i} has step {int(m_step[i])} and kind {m_kind[i].as_py()!r}, "
            f"but {ff} lists no such batch at that step (column 'batch_kinds')"
        )
    batch_of_row = sorter[pos] if batch_key.size else np.zeros(0, dtype=np.int64)
    perm = np.lexsort((m_row, batch_of_row))
    identity = np.array_equal(perm, np.arange(perm.size))
    batch_of_row = batch_of_row[perm]
    rows_of_batch = np.bincount(batch_of_row, minlength=batch_key.size)
    first_row = np.cumsum(rows_of_batch) - rows_of_batch
    expected = np.arange(perm.size) - first_row[batch_of_row]
    if not np.array_equal(m_row[perm], expected):
        i = int(np.flatnonzero(m_row[perm] != expected)[0])
        b = int(batch_of_row[i])
        raise InvalidInputError(
            f"{mf}: column 'row' must number the rows of each batch 0..M-1 exactly once; "
            f"step {int(step_of_batch[b])}, kind {kind_of_batch[b]!r} has row "
            f"{int(m_row[perm][i])} where {int(expected[i])} was expected"
        )
    table = measurements_table if identity else measurements_table.take(pa.array(perm))

    if "t" in table.column_names:  # optional: a convenience copy of the frame time
        m_t = _numpy(_column(table, mf, "t", pa.float64()), np.float64)
        wrong = m_t != times[step_of_batch[batch_of_row]]
        if wrong.any():
            i = int(np.flatnonzero(wrong)[0])
            raise InvalidInputError(f"{mf}: column 't' is {m_t[i]!r} at step "
                                    f"{int(step_of_batch[batch_of_row[i]])}, {ff} says "
                                    f"{times[step_of_batch[batch_of_row[i]]]!r}")
    sensor = _numpy(_column(table, mf, "sensor", pa.int64()), np.int64)
    subject = _numpy(_column(table, mf, "subject", pa.int64()), np.int64)
    origin = _numpy(_column(table, mf, "origin", pa.int64()), np.int64)
    dz_of_row = dim_of_batch[batch_of_row]
    z_len, z_values = _list_parts(_column(table, mf, "z", _LIST_FLOAT))
    cov_len, cov_values = _list_parts(_column(table, mf, "cov", _LIST_FLOAT))
    for name, have, want in (("z", z_len, dz_of_row), ("cov", cov_len, dz_of_row**2)):
        if not np.array_equal(have, want):
            i = int(np.flatnonzero(have != want)[0])
            b = int(batch_of_row[i])
            raise InvalidInputError(
                f"{mf}: column {name!r} of step {int(step_of_batch[b])}, kind "
                f"{kind_of_batch[b]!r}, row {int(expected[i])} has {int(have[i])} values, "
                f"expected {int(want[i])} (batch_dims says dz = {int(dim_of_batch[b])})"
            )
    z_flat = _numpy(z_values, np.float64)
    cov_flat = _numpy(cov_values, np.float64)
    # value offsets of each batch inside the flat z / cov arrays
    z_end = np.cumsum(rows_of_batch * dim_of_batch)
    cov_end = np.cumsum(rows_of_batch * dim_of_batch**2)
    row_end = np.cumsum(rows_of_batch)

    frames: list[Frame] = []
    origins: list[dict[str, IntArray]] = []
    vehicle_end = np.cumsum(n_vehicles)
    link_end = np.cumsum(n_links)
    batch_end = np.cumsum(n_kinds)
    for k in range(n_steps):
        batches: dict[str, Batch] = {}
        step_origin: dict[str, IntArray] = {}
        for b in range(int(batch_end[k] - n_kinds[k]), int(batch_end[k])):
            kind, dz, m = str(kind_of_batch[b]), int(dim_of_batch[b]), int(rows_of_batch[b])
            r0, r1 = int(row_end[b]) - m, int(row_end[b])
            try:
                batches[kind] = Batch(
                    z_flat[int(z_end[b]) - m * dz:int(z_end[b])].reshape(m, dz),
                    cov_flat[int(cov_end[b]) - m * dz * dz:int(cov_end[b])].reshape(m, dz, dz),
                    sensor[r0:r1],
                    subject[r0:r1],
                )
            except InvalidInputError as exc:
                raise InvalidInputError(f"{mf}: step {k}, kind {kind!r}: {exc}") from exc
            step_origin[kind] = origin[r0:r1]
        v1, l1 = int(vehicle_end[k]), int(link_end[k])
        try:
            frames.append(Frame(
                k, times[k], vehicles_flat[v1 - int(n_vehicles[k]):v1], batches,
                links_flat[l1 - int(n_links[k]):l1],
            ))
        except InvalidInputError as exc:
            raise InvalidInputError(f"{ff}: step {k}: {exc}") from exc
        origins.append(step_origin)
    return frames, origins


def _load_truth(
    table: pa.Table, file: str, n_steps: int, *, heading: bool = False
) -> tuple[IntArray, FloatArray, np.ndarray, FloatArray | None]:
    """ids (N,), states (T, N, d), presence (T, N) and, with `heading`, the heading (T, N) of
    the optional column `HEADING_COLUMN` (None without it) from a truth_*.parquet table."""
    step = _numpy(_column(table, file, "step", pa.int64()), np.int64)
    ids = _numpy(_column(table, file, "id", pa.int64()), np.int64)
    present = _numpy(_column(table, file, "present", pa.bool_()), bool)
    indices = sorted(int(m.group(1)) for c in table.column_names
                     if (m := STATE_COLUMN.fullmatch(c)))
    if indices != list(range(len(indices))):
        raise InvalidInputError(
            f"{file}: state columns must be x_0 … x_{{d-1}} without gaps, got "
            f"{[f'x_{i}' for i in indices]}"
        )
    dim = len(indices)
    bad = (step < 0) | (step >= n_steps)
    if bad.any():
        raise InvalidInputError(f"{file}: column 'step' must lie in [0, {n_steps}) "
                                f"(frames.parquet has {n_steps} steps), got {int(step[bad][0])}")
    # ids in order of first appearance, so that a file written step-major keeps its order
    unique, first, inverse = np.unique(ids, return_index=True, return_inverse=True)
    rank = np.empty(unique.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(unique.size)
    column_of_row = rank[inverse.ravel()]
    entity_ids = unique[np.argsort(first, kind="stable")]
    cell = step * unique.size + column_of_row
    if np.unique(cell).size != cell.size:
        values, counts = np.unique(cell, return_counts=True)
        dup = int(values[counts > 1][0])
        raise InvalidInputError(f"{file}: step {dup // unique.size} has id "
                                f"{int(entity_ids[dup % unique.size])} twice")
    states = np.zeros((n_steps, unique.size, dim), dtype=np.float64)
    presence = np.zeros((n_steps, unique.size), dtype=bool)
    for i in range(dim):
        states[step, column_of_row, i] = _numpy(
            _column(table, file, f"x_{i}", pa.float64()), np.float64)
    presence[step, column_of_row] = present
    headings = None
    if heading and HEADING_COLUMN in table.column_names:
        headings = np.zeros((n_steps, unique.size), dtype=np.float64)
        headings[step, column_of_row] = _numpy(_column(table, file, HEADING_COLUMN, pa.float64()), np.float64)
    return entity_ids, states, presence, headings


def _load_poses(table: pa.Table, infrastructure_ids: Sequence[int]) -> FloatArray:
    file = SENSOR_POSES_FILE
    sensor = _numpy(_column(table, file, "sensor", pa.int64()), np.int64)
    columns = [_numpy(_column(table, file, name, pa.float64()), np.float64)
               for name in ("x", "y", "yaw")]
    poses = np.stack(columns, axis=1).reshape(-1, 3)
    if (sensor != -1).any() and not np.array_equal(sensor, np.asarray(infrastructure_ids)):
        raise InvalidInputError(
            f"{file}: column 'sensor' must list setup.json's infrastructure_ids "
            f"{list(infrastructure_ids)} in order (or -1), got {sensor.tolist()}"
        )
    return poses
