"""`validate_recording` and `load_recording`'s semantic checks (issue 16, item 2).

Each case edits one saved field so that the recording is still well-formed but cannot
mean what it says; loading it must raise `InvalidInputError` naming the file, the
field, the step (where there is one) and the value.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from cooploc.errors import InvalidInputError
from cooploc.experiment import estimate
from cooploc.io import load_recording, save_recording, validate_recording
from cooploc.metrics import evaluate
from cooploc.registry import make_estimator
from cooploc.testing import preset_recording
from test_io import edit_setup


def saved(tmp_path: Path, preset: str) -> Path:
    return save_recording(preset_recording(preset, 0, {"n_steps": 5}), tmp_path / preset)


def edit_column(folder: Path, file: str, column: str, edit: Any) -> None:
    """Replace `column` of `file` by edit(values as a Python list)."""
    table = pq.read_table(folder / file)
    values = edit(table.column(column).to_pylist())
    index = table.column_names.index(column)
    table = table.set_column(index, column, pa.array(values, table.schema.field(column).type))
    pq.write_table(table, folder / file)


def first_of(kind: str):
    """An edit that changes the first row of `kind` in measurements.parquet."""
    def edit(folder: Path, column: str, value: Any) -> None:
        kinds = pq.read_table(folder / "measurements.parquet").column("kind").to_pylist()
        i = kinds.index(kind)
        edit_column(folder, "measurements.parquet", column,
                    lambda values: [*values[:i], value, *values[i + 1:]])
    return edit


def test_gnss_subject_no_vehicle_has(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    first_of("gnss")(folder, "subject", 99)
    with pytest.raises(InvalidInputError, match=r"measurements\.parquet: column 'subject': step 0, "
                       r"kind 'gnss', row 0: id 99 is no entity of the recording"):
        load_recording(folder)


def test_v2f_sensor_no_vehicle_has(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    first_of("v2f")(folder, "sensor", 42)
    with pytest.raises(InvalidInputError, match=r"column 'sensor': step 0, kind 'v2f', row 0: id 42"):
        load_recording(folder)


def test_origin_no_entity_has(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    first_of("v2f")(folder, "origin", 5)
    with pytest.raises(InvalidInputError, match=r"column 'origin': step 0, kind 'v2f', row 0: id 5"):
        load_recording(folder)


def test_sensor_of_a_vehicle_absent_at_that_step(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    edit_column(folder, "truth_vehicles.parquet", "present",
                lambda values: [False, *values[1:]])   # vehicle 0 absent at step 0 ...
    edit_column(folder, "frames.parquet", "vehicles", lambda values: [[1], *values[1:]])
    with pytest.raises(InvalidInputError, match=r"step 0, kind 'gnss', row 0: id 0 is a vehicle absent"):
        load_recording(folder)                           # ... but its GNSS fix is there


def test_batch_kind_the_setup_does_not_declare(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    upper = lambda values: [[k.upper() if k == "gnss" else k for k in v] for v in values]  # noqa: E731
    edit_column(folder, "frames.parquet", "batch_kinds", upper)
    edit_column(folder, "measurements.parquet", "kind", lambda v: [k.upper() if k == "gnss" else k
                                                                   for k in v])
    with pytest.raises(InvalidInputError, match=r"frames\.parquet: column 'batch_kinds': step 0 has a "
                       r"batch of kind 'GNSS', which setup\.sensors does not declare"):
        load_recording(folder)


def test_setup_without_sensors(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    edit_setup(folder, sensors=KeyError)
    with pytest.raises(InvalidInputError, match=r"kind 'gnss', which setup\.sensors does not declare "
                                                r"\(declared: \[\]\)"):
        load_recording(folder)


def test_wrong_batch_dims(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    edit_column(folder, "frames.parquet", "batch_dims", lambda v: [[1, 2]] * len(v))
    for column, width in (("z", 1), ("cov", 1)):
        table = pq.read_table(folder / "measurements.parquet")
        gnss = pc.equal(table.column("kind"), "gnss").to_pylist()
        edit_column(folder, "measurements.parquet", column,
                    lambda values, g=gnss, w=width: [x[:w] if is_gnss else x
                                                     for x, is_gnss in zip(values, g, strict=True)])
    with pytest.raises(InvalidInputError, match=r"column 'batch_dims': step 0, kind 'gnss' has dz = 1, "
                       r"its sensor model \(gnss-position\) measures dz = 2"):
        load_recording(folder)


@pytest.mark.parametrize(("times", "match"), [
    ([0.0, 7.0, 14.0, 21.0, 28.0], r"steps 0 and 1 \(0\.0, 7\.0\) are 7\.0 s apart, setup\.dt is 0\.5"),
    ([2.0, 1.5, 1.0, 0.5, 0.0], r"steps 0 and 1 \(2\.0, 1\.5\) do not increase"),
    ([1.0] * 5, r"steps 0 and 1 \(1\.0, 1\.0\) do not increase"),
])
def test_frame_times_that_disagree_with_dt(tmp_path: Path, times: list[float], match: str) -> None:
    folder = saved(tmp_path, "froehle2018")
    edit_column(folder, "frames.parquet", "t", lambda values: times)
    pq.write_table(pq.read_table(folder / "measurements.parquet").drop_columns(["t"]),
                   folder / "measurements.parquet")
    with pytest.raises(InvalidInputError, match=r"frames\.parquet: column 't': times of " + match):
        load_recording(folder)


def test_dt_that_disagrees_with_the_frames(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    edit_setup(folder, dt=7)
    with pytest.raises(InvalidInputError, match=r"are 0\.5 s apart, setup\.dt is 7\.0"):
        load_recording(folder)


@pytest.mark.parametrize(("value", "match"), [
    (4, r"setup\.json: field 'n_steps': is 4 but the recording has 5 frames"),
    (True, r"setup\.json: field 'n_steps' must be an integer, got True"),
])
def test_n_steps(tmp_path: Path, value: Any, match: str) -> None:
    folder = saved(tmp_path, "froehle2018")
    edit_setup(folder, n_steps=value)
    with pytest.raises(InvalidInputError, match=match):
        load_recording(folder)


def test_prior_ids_matching_no_vehicle(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    data = json.loads((folder / "setup.json").read_text())
    edit_setup(folder, vehicle_prior={**data["vehicle_prior"], "ids": [0, 17]})
    with pytest.raises(InvalidInputError, match=r"field 'vehicle_prior\.ids': ids \[17\] match no "
                                                r"vehicle of the truth \(vehicles: \[0, 1\]\)"):
        load_recording(folder)


def test_infrastructure_ids_without_poses(tmp_path: Path) -> None:
    folder = saved(tmp_path, "gulati-2v")
    edit_setup(folder, infrastructure_ids=[100, 101])
    pq.write_table(pq.read_table(folder / "sensor_poses.parquet").drop_columns([]).slice(0, 1)
                   .set_column(0, "sensor", pa.array([-1], pa.int64())), folder / "sensor_poses.parquet")
    with pytest.raises(InvalidInputError, match=r"sensor_poses\.parquet: 1 sensor poses for the 2 "
                                                r"infrastructure ids \[100, 101\]"):
        load_recording(folder)


def test_ids_shared_by_a_vehicle_and_a_feature(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    data = json.loads((folder / "setup.json").read_text())
    edit_setup(folder, feature_prior={**data["feature_prior"], "ids": [1000, 1001, 1]})
    with pytest.raises(InvalidInputError, match=r"ids \[1\] are both vehicle and feature ids"):
        load_recording(folder)


def test_truth_missing_a_step(tmp_path: Path) -> None:
    folder = saved(tmp_path, "froehle2018")
    table = pq.read_table(folder / "truth_vehicles.parquet")
    pq.write_table(table.filter(pc.not_equal(table.column("step"), 3)), folder / "truth_vehicles.parquet")
    with pytest.raises(InvalidInputError, match=r"frames\[3\]\.vehicles \[0, 1\] are not present"):
        load_recording(folder)


def test_empty_truth_features_loads_and_evaluates(tmp_path: Path) -> None:
    """The docs allow a recording without feature truth: it loads, runs and is scored."""
    folder = saved(tmp_path, "froehle2018")
    table = pq.read_table(folder / "truth_features.parquet")
    pq.write_table(table.slice(0, 0), folder / "truth_features.parquet")
    recording = load_recording(folder)
    assert recording.truth.feature_ids.size == 0
    for name in ("oracle-kf", "rsu-bp", "gnss-kf"):
        estimator = make_estimator(name, recording.setup, None, np.random.default_rng(0),
                                   truth=recording.truth)
        errors = evaluate(recording, estimate(estimator, recording))
        assert np.isfinite(errors.err_pos).all() and errors.err_pos.size == 10


def test_python_built_recordings_are_checked_with_the_same_function() -> None:
    recording = preset_recording("froehle2018", 0, {"n_steps": 3})
    assert validate_recording(recording) is recording
    wrong = dataclasses.replace(recording, setup=dataclasses.replace(recording.setup, dt=2.0))
    with pytest.raises(InvalidInputError, match=r"^frames\[k\]\.t: times of steps 0 and 1 "):
        validate_recording(wrong)


def test_gnss_of_a_vehicle_missing_from_the_frame(tmp_path: Path) -> None:
    """Present in the truth but not in `Frame.vehicles`: estimators would not know it."""
    folder = saved(tmp_path, "gulati-2v")
    edit_column(folder, "frames.parquet", "vehicles", lambda values: [[] for _ in values])
    with pytest.raises(InvalidInputError, match=r"column 'sensor': step 0, kind 'gnss', row 0: id 0 "
                                                r"is a vehicle absent at that step"):
        load_recording(folder)
