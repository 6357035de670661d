"""Round trips of `cooploc.io` (bit-exact) and its errors on missing or malformed files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from cooploc.errors import InvalidInputError
from cooploc.io import load_recording, save_recording
from cooploc.motion import ConstantTurn, ConstantVelocity
from cooploc.scenarios import get_preset
from cooploc.sensors import GnssPosition, InfrastructureRadar, RelativePosition
from cooploc.types import Batch, Frame, Recording, Setup, StateLayout, StateSet, Truth

FILES = (
    "setup.json",
    "frames.parquet",
    "measurements.parquet",
    "truth_vehicles.parquet",
    "truth_features.parquet",
    "sensor_poses.parquet",
)


# ----------------------------------------------------------------------------
# exact comparison
# ----------------------------------------------------------------------------


def assert_same(a: Any, b: Any, what: str) -> None:
    """Arrays equal in dtype, shape and every bit (so -0.0 differs from 0.0)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype, f"{what}: dtype {a.dtype} != {b.dtype}"
    np.testing.assert_array_equal(a, b, err_msg=what, strict=True)
    assert a.tobytes() == b.tobytes(), f"{what}: not bit-identical"


def assert_same_optional(a: Any, b: Any, what: str) -> None:
    assert (a is None) == (b is None), what
    if a is not None:
        assert_same(a, b, what)


def assert_same_stateset(a: StateSet | None, b: StateSet | None, what: str) -> None:
    assert (a is None) == (b is None), what
    if a is not None and b is not None:
        assert_same(a.ids, b.ids, f"{what}.ids")
        assert_same(a.mean, b.mean, f"{what}.mean")
        assert_same(a.cov, b.cov, f"{what}.cov")


def assert_same_setup(a: Setup, b: Setup) -> None:
    assert a.dt == b.dt and type(a.dt) is type(b.dt)
    assert a.n_steps == b.n_steps
    assert a.vehicle_layout == b.vehicle_layout
    assert a.feature_layout == b.feature_layout
    assert type(a.vehicle_motion) is type(b.vehicle_motion)
    assert a.vehicle_motion == b.vehicle_motion
    assert type(a.feature_motion) is type(b.feature_motion)
    assert a.feature_motion == b.feature_motion
    assert list(a.sensors) == list(b.sensors)
    for kind in a.sensors:
        sa, sb = a.sensors[kind], b.sensors[kind]
        assert type(sa) is type(sb), kind
        assert sa.to_dict() == sb.to_dict(), kind
    assert_same_stateset(a.vehicle_prior, b.vehicle_prior, "vehicle_prior")
    assert_same_stateset(a.feature_prior, b.feature_prior, "feature_prior")
    assert_same_optional(a.birth_cov, b.birth_cov, "birth_cov")
    assert_same_optional(a.clutter_region, b.clutter_region, "clutter_region")
    assert a.detection_probability == b.detection_probability
    assert a.clutter_rate == b.clutter_rate
    assert a.infrastructure_ids == b.infrastructure_ids
    assert a.description == b.description


def assert_same_recording(a: Recording, b: Recording) -> None:
    assert_same_setup(a.setup, b.setup)
    assert len(a.frames) == len(b.frames)
    for fa, fb in zip(a.frames, b.frames, strict=True):
        k = fa.k
        assert fb.k == k
        assert_same(fa.t, fb.t, f"frame {k} t")
        assert_same(fa.vehicles, fb.vehicles, f"frame {k} vehicles")
        assert_same(fa.links, fb.links, f"frame {k} links")
        assert list(fa.batches) == list(fb.batches), f"frame {k} kinds"
        for kind, ba in fa.batches.items():
            bb = fb.batches[kind]
            for name in ("z", "cov", "sensor", "subject"):
                assert_same(getattr(ba, name), getattr(bb, name), f"frame {k} {kind} {name}")
    ta, tb = a.truth, b.truth
    for name in ("vehicle_ids", "vehicle_states", "vehicle_present", "feature_ids",
                 "feature_states", "feature_present", "sensor_poses"):
        assert_same(getattr(ta, name), getattr(tb, name), f"truth.{name}")
    assert len(ta.origin) == len(tb.origin)
    for k, (oa, ob) in enumerate(zip(ta.origin, tb.origin, strict=True)):
        assert set(oa) == set(ob), f"origin[{k}] kinds"
        for kind in oa:
            assert_same(oa[kind], ob[kind], f"origin[{k}][{kind}]")


def round_trip(recording: Recording, folder: Path) -> Recording:
    path = save_recording(recording, folder)
    assert path == Path(folder)
    loaded = load_recording(folder)
    assert_same_recording(recording, loaded)
    return loaded


# ----------------------------------------------------------------------------
# recordings
# ----------------------------------------------------------------------------


def froehle(**overrides: Any) -> Recording:
    preset = get_preset("froehle2018")
    params = preset.params.with_overrides({"n_steps": 20, **overrides})
    return preset.generate(np.random.default_rng(0), params)


def spd(rng: np.random.Generator, m: int, d: int) -> np.ndarray:
    """m random symmetric positive definite (d, d) matrices with awkward float bits."""
    a = rng.standard_normal((m, d, d)) / 3.0
    return a @ a.transpose(0, 2, 1) + 0.1 * np.eye(d)


def hand_built() -> Recording:
    """Traffic: vehicle 7 leaves after step 1, vehicle 9 enters at step 3; step 2 has no
    vehicles and an empty batch; three kinds of different dimension; links; infrastructure."""
    rng = np.random.default_rng(42)
    ids = np.array([7, 3, 9])
    present = np.array([
        [True, True, False],
        [True, True, False],
        [False, False, False],
        [False, True, True],
    ])
    states = rng.standard_normal((4, 3, 4)) * 1e3
    states[~present] = 0.0
    states[0, 0, 0] = -0.0            # sign of zero must survive
    states[1, 1, 2] = 5e-324          # subnormal
    states[3, 2, 3] = 0.1 + 0.2       # not the shortest repr of 0.3

    def batch(m: int, d: int, sensor: list[int], subject: list[int]) -> Batch:
        return Batch(rng.standard_normal((m, d)) * 1e-7, spd(rng, m, d), sensor, subject)

    frames = [
        Frame(0, 0.0, [7, 3], {"gnss": batch(2, 2, [7, 3], [7, 3]),
                               "v2f": batch(3, 2, [3, 7, 7], [-1, -1, -1])},
              links=[[7, 3]]),
        Frame(1, 0.1, [3, 7], {"v2f": batch(1, 2, [3], [-1]),
                               "radar": batch(4, 3, [-1, -1, 500, 500], [-1, 3, -1, 7]),
                               "gnss": batch(2, 2, [3, 7], [3, 7])},
              links=[[3, 7], [7, 3]]),
        Frame(2, 0.1 + 0.1, [], {"v2f": Batch.empty(2)}),
        Frame(3, 0.30000000000000004, [9, 3], {"gnss": batch(2, 2, [9, 3], [9, 3]),
                                               "radar": Batch.empty(3),
                                               "odometry": batch(1, 1, [9], [9])}),
    ]
    origin = [
        {"gnss": [7, 3], "v2f": [100, -1, 101]},
        {"v2f": [-1], "radar": [7, 3, -1, 7], "gnss": [3, 7]},
        {"v2f": []},
        {"gnss": [9, 3], "radar": [], "odometry": [9]},
    ]
    features = rng.standard_normal((4, 2, 4))
    truth = Truth(
        vehicle_ids=ids, vehicle_states=states, vehicle_present=present,
        feature_ids=[101, 100], feature_states=features,
        feature_present=np.array([[True, True]] * 3 + [[False, True]]),
        origin=origin, sensor_poses=np.array([[1.5, -2.25, 0.1], [-0.0, 3.0, -3.1]]),
    )
    setup = Setup(
        dt=0.1, n_steps=4,
        vehicle_layout=StateLayout.position_velocity(2),
        vehicle_motion=ConstantTurn(turn_rate=0.1 + 0.2, noise_density=1e-300),
        vehicle_prior=StateSet([3], rng.standard_normal((1, 4)), spd(rng, 1, 4)),
        sensors={"gnss": GnssPosition({7: 2.0 * np.eye(2)}, default_cov=spd(rng, 1, 2)[0]),
                 "v2f": RelativePosition(default_cov=np.eye(2) / 3.0),
                 "odometry": GnssPosition(default_cov=[[0.7]], state_indices=(2,)),
                 "radar": InfrastructureRadar(default_cov=np.eye(3), state_indices=(0, 1, 2))},
        feature_layout=StateLayout.position_velocity(2),
        feature_motion=ConstantVelocity(0.5),
        feature_prior=StateSet.empty(4),
        birth_cov=spd(rng, 1, 4)[0],
        detection_probability=0.9,
        clutter_rate=1.25,
        clutter_region=np.array([[-10.0, 10.0], [-0.5, 1.0 / 3.0]]),
        infrastructure_ids=(500, 501),
        description="hand-built: traffic, empty batches, ünïcode",
    )
    return Recording(setup, frames, truth)


# ----------------------------------------------------------------------------
# round trips
# ----------------------------------------------------------------------------


def test_round_trip_froehle(tmp_path: Path) -> None:
    recording = froehle()
    loaded = round_trip(recording, tmp_path / "rec")
    assert loaded.frames[0].batches["v2f"].z.flags.writeable is False


def test_round_trip_with_clutter_and_missed_detections(tmp_path: Path) -> None:
    recording = froehle(detection_probability="0.6", clutter_rate="3", n_vehicles="3",
                        n_features="4")
    counts = [len(f.batches["v2f"]) for f in recording.frames]
    assert len(set(counts)) > 1, "clutter and misses should vary the batch size"
    origins = np.concatenate([o["v2f"] for o in recording.truth.origin])
    assert (origins == -1).any()
    round_trip(recording, tmp_path)


def test_round_trip_without_features(tmp_path: Path) -> None:
    recording = froehle(n_features="0")
    assert all(len(f.batches["v2f"]) == 0 for f in recording.frames)
    loaded = round_trip(recording, tmp_path)
    assert loaded.truth.feature_states.shape == (20, 0, 4)
    assert loaded.setup.feature_prior is not None
    assert loaded.setup.feature_prior.mean.shape == (0, 4)
    assert loaded.frames[5].batches["v2f"].dim == 2


def test_round_trip_hand_built_traffic(tmp_path: Path) -> None:
    recording = hand_built()
    loaded = round_trip(recording, tmp_path)
    assert loaded.frames[2].vehicles.size == 0
    assert list(loaded.frames[2].batches) == ["v2f"]
    assert len(loaded.frames[2].batches["v2f"]) == 0
    assert loaded.frames[3].batches["radar"].dim == 3
    assert list(loaded.frames[1].batches) == ["v2f", "radar", "gnss"]
    assert np.signbit(loaded.truth.vehicle_states[0, 0, 0])


def test_save_overwrites_and_creates_parents(tmp_path: Path) -> None:
    folder = tmp_path / "a" / "b"
    save_recording(froehle(), folder)
    round_trip(hand_built(), folder)


def test_rows_in_any_order_are_sorted_back(tmp_path: Path) -> None:
    """Users may write measurement and truth rows in any order; row/step columns decide."""
    recording = hand_built()
    save_recording(recording, tmp_path)
    for file in ("measurements.parquet", "frames.parquet"):
        table = pq.read_table(tmp_path / file)
        reverse = pa.array(np.arange(table.num_rows)[::-1])
        pq.write_table(table.take(reverse), tmp_path / file)
    assert_same_recording(recording, load_recording(tmp_path))


def test_hand_written_folder_without_optional_columns(tmp_path: Path) -> None:
    """The minimal folder a user writes: list<list> links, no 't' in measurements."""
    recording = froehle(n_steps="3")
    save_recording(recording, tmp_path)
    frames = pq.read_table(tmp_path / "frames.parquet")
    links = pa.array([[[0, 1]], [], [[1, 0]]], pa.list_(pa.list_(pa.int64())))
    frames = frames.set_column(frames.column_names.index("links"), "links", links)
    pq.write_table(frames, tmp_path / "frames.parquet")
    measurements = pq.read_table(tmp_path / "measurements.parquet").drop_columns(["t"])
    pq.write_table(measurements, tmp_path / "measurements.parquet")
    loaded = load_recording(tmp_path)
    assert_same(loaded.frames[0].links, np.array([[0, 1]]), "links")
    assert loaded.frames[1].links.shape == (0, 2)


# ----------------------------------------------------------------------------
# errors
# ----------------------------------------------------------------------------


@pytest.fixture
def saved(tmp_path: Path) -> Path:
    return save_recording(hand_built(), tmp_path / "rec")


def test_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match=r"recording folder .*nowhere.* does not exist"):
        load_recording(tmp_path / "nowhere")


@pytest.mark.parametrize("file", FILES)
def test_missing_file(saved: Path, file: str) -> None:
    (saved / file).unlink()
    with pytest.raises(InvalidInputError, match=rf"{file}: file is missing"):
        load_recording(saved)


def test_setup_not_json(saved: Path) -> None:
    (saved / "setup.json").write_text('{"dt": 0.1,,}')
    with pytest.raises(InvalidInputError, match=r"setup\.json: not valid JSON"):
        load_recording(saved)


def test_setup_not_an_object(saved: Path) -> None:
    (saved / "setup.json").write_text("[1, 2]")
    with pytest.raises(InvalidInputError, match=r"setup\.json: must hold a JSON object, got list"):
        load_recording(saved)


def edit_setup(folder: Path, **changes: Any) -> None:
    data = json.loads((folder / "setup.json").read_text())
    for key, value in changes.items():
        if value is KeyError:
            del data[key]
        else:
            data[key] = value
    (folder / "setup.json").write_text(json.dumps(data))


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"dt": KeyError}, r"setup\.json: field 'dt' is missing"),
        ({"format_version": KeyError}, r"setup\.json: field 'format_version' is missing"),
        ({"format_version": 99}, r"setup\.json: field 'format_version' must be 1, got 99"),
        ({"dt": -0.5}, r"setup\.json: Setup\.dt must be a positive .*-0\.5"),
        ({"dt": "fast"}, r"^setup\.json: field 'dt' must be a number, got 'fast'$"),
        ({"n_steps": True}, r"^setup\.json: field 'n_steps' must be an integer, got True$"),
        ({"clutter_rate": "2"}, r"^setup\.json: field 'clutter_rate' must be a number, got '2'$"),
        ({"vehicle_motion": {"model": "teleport"}},
         r"setup\.json: field 'vehicle_motion'.*'teleport'"),
        ({"vehicle_layout": {"dim": 4}},
         r"setup\.json: field 'vehicle_layout' is malformed.*position"),
        ({"vehicle_prior": {"ids": [3], "mean": [[0.0] * 4], "cov": [(-np.eye(4)).tolist()]}},
         r"setup\.json: field 'vehicle_prior': StateSet\.cov\[0\] is not positive definite"),
        ({"vehicle_prior": {"ids": [3, 3], "mean": [[0.0] * 4] * 2,
                            "cov": [np.eye(4).tolist()] * 2}},
         r"setup\.json: field 'vehicle_prior': StateSet\.ids has duplicate ids: \[3\]"),
        ({"sensors": {"gnss": {"model": "gnss-position", "default_cov": [[1.0, 2.0], [0.0, 1.0]]}}},
         r"setup\.json: field 'sensors\.gnss'.*not symmetric"),
        ({"sensors": [1]}, r"setup\.json: field 'sensors' must map kinds"),
        ({"birth_cov": [[1.0]]}, r"setup\.json: Setup\.birth_cov must have shape \(4, 4\)"),
        ({"description": 3}, r"setup\.json: field 'description' must be a string, got 3"),
    ],
)
def test_malformed_setup(saved: Path, changes: dict[str, Any], match: str) -> None:
    edit_setup(saved, **changes)
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_corrupted_parquet(saved: Path) -> None:
    (saved / "measurements.parquet").write_bytes(b"not parquet at all")
    with pytest.raises(InvalidInputError, match=r"measurements\.parquet: not a readable Parquet"):
        load_recording(saved)


def edit_table(folder: Path, file: str, name: str, values: pa.Array | None) -> None:
    table = pq.read_table(folder / file)
    if values is None:
        table = table.drop_columns([name])
    else:
        table = table.set_column(table.column_names.index(name), name, values)
    pq.write_table(table, folder / file)


def test_missing_column(saved: Path) -> None:
    edit_table(saved, "measurements.parquet", "origin", None)
    match = r"measurements\.parquet: column 'origin' is missing"
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_column_of_wrong_type(saved: Path) -> None:
    n = pq.read_table(saved / "measurements.parquet").num_rows
    edit_table(saved, "measurements.parquet", "sensor", pa.array(["x"] * n))
    match = r"measurements\.parquet: column 'sensor' must be int64"
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_column_with_nulls(saved: Path) -> None:
    n = pq.read_table(saved / "frames.parquet").num_rows
    edit_table(saved, "frames.parquet", "t", pa.array([None] + [1.0] * (n - 1), pa.float64()))
    with pytest.raises(InvalidInputError, match=r"frames\.parquet: column 't' has null values"):
        load_recording(saved)


def test_wrong_measurement_dimension(saved: Path) -> None:
    table = pq.read_table(saved / "measurements.parquet")
    z = table.column("z").to_pylist()
    z[0] = [*z[0], 1.0]
    edit_table(saved, "measurements.parquet", "z", pa.array(z))
    with pytest.raises(InvalidInputError,
                       match=r"measurements\.parquet: column 'z' of step 0, kind 'gnss', row 0 "
                             r"has 3 values, expected 2"):
        load_recording(saved)


def test_duplicate_row_index(saved: Path) -> None:
    table = pq.read_table(saved / "measurements.parquet")
    rows = table.column("row").to_numpy().copy()
    rows[1] = 0
    edit_table(saved, "measurements.parquet", "row", pa.array(rows))
    with pytest.raises(InvalidInputError, match=r"measurements\.parquet: column 'row' must number"):
        load_recording(saved)


def test_measurement_of_unlisted_kind(saved: Path) -> None:
    table = pq.read_table(saved / "measurements.parquet")
    kinds = table.column("kind").to_pylist()
    kinds[0] = "lidar"
    edit_table(saved, "measurements.parquet", "kind", pa.array(kinds))
    with pytest.raises(InvalidInputError,
                       match=r"measurements\.parquet: row 0 has step 0 and kind 'lidar'"):
        load_recording(saved)


def test_nan_measurement(saved: Path) -> None:
    table = pq.read_table(saved / "measurements.parquet")
    z = table.column("z").to_pylist()
    z[2][1] = float("nan")
    edit_table(saved, "measurements.parquet", "z", pa.array(z))
    match = r"measurements\.parquet: step 0, kind 'v2f': Batch\.z\[0, 1\] is not finite"
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_frames_missing_a_step(saved: Path) -> None:
    table = pq.read_table(saved / "frames.parquet")
    pq.write_table(table.slice(1), saved / "frames.parquet")
    match = r"frames\.parquet: column 'step' must hold each step"
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_link_to_absent_vehicle(saved: Path) -> None:
    links = pa.array([[[7, 3]], [[3, 8]], [], []], pa.list_(pa.list_(pa.int64())))
    edit_table(saved, "frames.parquet", "links", links)
    match = r"frames\.parquet: step 1: Frame\.links refer to vehicles not present: \[8\]"
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_truth_state_columns_with_gap(saved: Path) -> None:
    edit_table(saved, "truth_vehicles.parquet", "x_1", None)
    match = r"truth_vehicles\.parquet: state columns must be x_0"
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_truth_duplicate_entry(saved: Path) -> None:
    table = pq.read_table(saved / "truth_features.parquet")
    ids = table.column("id").to_numpy().copy()
    ids[1] = ids[0]
    edit_table(saved, "truth_features.parquet", "id", pa.array(ids))
    match = r"truth_features\.parquet: step 0 has id 101 twice"
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_truth_step_out_of_range(saved: Path) -> None:
    table = pq.read_table(saved / "truth_vehicles.parquet")
    steps = table.column("step").to_numpy().copy()
    steps[-1] = 4
    edit_table(saved, "truth_vehicles.parquet", "step", pa.array(steps))
    with pytest.raises(InvalidInputError,
                       match=r"truth_vehicles\.parquet: column 'step' must lie in \[0, 4\).*got 4"):
        load_recording(saved)


def test_sensor_poses_in_wrong_order(saved: Path) -> None:
    edit_table(saved, "sensor_poses.parquet", "sensor", pa.array([501, 500]))
    match = r"sensor_poses\.parquet: column 'sensor' must list"
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_inconsistent_truth_and_frames(saved: Path) -> None:
    """A frame vehicle that truth says is absent: the Recording check, with the folder named."""
    table = pq.read_table(saved / "truth_vehicles.parquet")
    present = table.column("present").to_numpy(zero_copy_only=False).copy()
    present[0] = False
    edit_table(saved, "truth_vehicles.parquet", "present", pa.array(present))
    match = r"recording .* is inconsistent: Recording\.frames\[0\]\.vehicles \[7\]"
    with pytest.raises(InvalidInputError, match=match):
        load_recording(saved)


def test_save_rejects_non_recording(tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match=r"save_recording needs a Recording, got dict"):
        save_recording({}, tmp_path)  # type: ignore[arg-type]


def test_motion_models_round_trip_through_setup(tmp_path: Path) -> None:
    """ConstantVelocity too (the hand-built recording uses ConstantTurn)."""
    recording = froehle(n_steps="2")
    assert isinstance(recording.setup.vehicle_motion, ConstantVelocity)
    loaded = round_trip(recording, tmp_path)
    assert isinstance(loaded.setup.vehicle_motion, ConstantVelocity)


def test_folder_written_by_hand_from_the_docstring(tmp_path: Path) -> None:
    """The documented format is enough: a user writes every file from plain lists."""
    setup = {
        "format_version": 1, "dt": 0.5, "n_steps": 2,
        "vehicle_layout": {"dim": 4, "position": [0, 1], "velocity": [2, 3]},
        "vehicle_motion": {"model": "constant-velocity", "noise_density": 0.1},
        "vehicle_prior": {"ids": [], "mean": [], "cov": [], "dim": 4},
        "sensors": {"gnss": {"model": "gnss-position", "default_cov": [[4.0, 0.0], [0.0, 4.0]]},
                    "v2f": {"model": "relative-position", "default_cov": [[1.0, 0.0], [0.0, 1.0]]}},
    }
    (tmp_path / "setup.json").write_text(json.dumps(setup))
    pq.write_table(pa.table({
        "step": [1, 0], "t": [0.5, 0.0], "vehicles": [[7, 8], [7]],
        "links": [[[7, 8]], []], "batch_kinds": [["gnss"], ["gnss", "v2f"]],
        "batch_dims": [[2], [2, 2]],
    }), tmp_path / "frames.parquet")
    pq.write_table(pa.table({
        "step": [1, 0, 1], "kind": ["gnss"] * 3, "row": [1, 0, 0], "sensor": [8, 7, 7],
        "subject": [8, 7, 7], "origin": [8, 7, 7],
        "z": [[1.0, 2.0], [12.5, -3.0], [3, 4]], "cov": [[4.0, 0.0, 0.0, 4.0]] * 3,
    }), tmp_path / "measurements.parquet")
    pq.write_table(pa.table({
        "step": [0, 1, 1], "id": [7, 7, 8], "present": [True, True, True],
        "x_0": [0.0, 1.0, 2.0], "x_1": [0.0] * 3, "x_2": [0.0] * 3, "x_3": [0.0] * 3,
    }), tmp_path / "truth_vehicles.parquet")
    pq.write_table(pa.table({"step": pa.array([], pa.int64()), "id": pa.array([], pa.int64()),
                             "present": pa.array([], pa.bool_())}),
                   tmp_path / "truth_features.parquet")
    pq.write_table(pa.table({"sensor": pa.array([], pa.int64()), "x": pa.array([], pa.float64()),
                             "y": pa.array([], pa.float64()), "yaw": pa.array([], pa.float64())}),
                   tmp_path / "sensor_poses.parquet")
    recording = load_recording(tmp_path)
    first, second = recording.frames
    assert list(first.batches) == ["gnss", "v2f"] and len(first.batches["v2f"]) == 0
    assert_same(first.batches["gnss"].z, np.array([[12.5, -3.0]]), "z")
    assert_same(second.batches["gnss"].z, np.array([[3.0, 4.0], [1.0, 2.0]]), "z sorted by row")
    assert_same(second.links, np.array([[7, 8]]), "links")
    assert_same(recording.truth.vehicle_ids, np.array([7, 8]), "ids by first appearance")
    assert_same(recording.truth.vehicle_present, np.array([[True, False], [True, True]]),
                "a missing (step, id) row is an absent vehicle")
    assert recording.truth.feature_states.shape == (2, 0, 0)
    assert set(recording.setup.sensors) == {"gnss", "v2f"} and recording.setup.clutter_rate == 0.0
