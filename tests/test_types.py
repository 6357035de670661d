"""Validation of the data model (`cooploc.types`) and of `Params.with_overrides`.

Every invalid input must raise `InvalidInputError` (resp. `ConfigError`) whose message
names the field and shows the offending value; the matches below check both.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from cooploc.errors import ConfigError, InvalidInputError
from cooploc.motion import ConstantVelocity
from cooploc.scenarios.froehle2018 import FroehleParams
from cooploc.sensors import GnssPosition
from cooploc.types import Batch, Frame, Recording, Setup, StateLayout, StateSet, Truth


def eye_batch(m: int = 2, dz: int = 2, sensor: list[int] | None = None) -> Batch:
    sensor = list(range(m)) if sensor is None else sensor
    return Batch(np.zeros((m, dz)), np.repeat(np.eye(dz)[None], m, 0), sensor, [-1] * m)


def covs(m: int = 2, dz: int = 2) -> np.ndarray:
    return np.repeat(np.eye(dz)[None], m, 0)


# ----------------------------------------------------------------------------
# Batch
# ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"z": np.zeros(3)}, r"Batch\.z must have shape \(M, dz\), got \(3,\)"),
        ({"z": np.zeros((2, 2, 1))}, r"Batch\.z must have shape \(M, dz\), got \(2, 2, 1\)"),
        ({"cov": covs(2, 3)}, r"Batch\.cov must have shape \(2, 2, 2\), got \(2, 3, 3\)"),
        ({"cov": covs(3, 2)}, r"Batch\.cov must have shape \(2, 2, 2\), got \(3, 2, 2\)"),
        ({"cov": np.eye(2)}, r"Batch\.cov must have shape \(2, 2, 2\), got \(2, 2\)"),
        ({"sensor": [0, 1, 2]}, r"Batch\.sensor must have shape \(2\), got \(3,\)"),
        ({"subject": [[0], [1]]}, r"Batch\.subject must have shape \(2\), got \(2, 1\)"),
        ({"sensor": [0.5, 1.0]}, r"Batch\.sensor must hold integer ids, got \[0\.5, 1\. *\]"),
        ({"z": [["a", "b"], ["c", "d"]]}, r"Batch\.z must be numeric, got"),
    ],
)
def test_batch_wrong_shape_or_type(kwargs: dict[str, Any], match: str) -> None:
    args = {"z": np.zeros((2, 2)), "cov": covs(), "sensor": [0, 1], "subject": [-1, -1]}
    with pytest.raises(InvalidInputError, match=match):
        Batch(**{**args, **kwargs})


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_batch_non_finite_z(bad: float) -> None:
    z = np.zeros((3, 2))
    z[1, 0] = bad
    with pytest.raises(InvalidInputError, match=rf"Batch\.z\[1, 0\] is not finite: {bad}"):
        Batch(z, covs(3), [0, 1, 2], [-1] * 3)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_batch_non_finite_cov(bad: float) -> None:
    cov = covs()
    cov[1, 0, 1] = bad
    with pytest.raises(InvalidInputError, match=rf"Batch\.cov\[1, 0, 1\] is not finite: {bad}"):
        Batch(np.zeros((2, 2)), cov, [0, 1], [-1, -1])


def test_batch_non_symmetric_cov() -> None:
    cov = covs()
    cov[1, 0, 1] = 0.5
    with pytest.raises(InvalidInputError,
                       match=r"Batch\.cov\[1\] is not symmetric: \[\[1\. *, 0\.5\]"):
        Batch(np.zeros((2, 2)), cov, [0, 1], [-1, -1])


def test_batch_symmetry_tolerates_round_off() -> None:
    """A Joseph-form update leaves ~1e-16 relative asymmetry; that must be accepted."""
    cov = covs() * 3.0
    cov[0, 0, 1] = 1e-15
    Batch(np.zeros((2, 2)), cov, [0, 1], [-1, -1])


@pytest.mark.parametrize(
    ("matrix", "eig"),
    [
        (np.array([[1.0, 2.0], [2.0, 1.0]]), r"-1"),      # indefinite
        (np.array([[1.0, 1.0], [1.0, 1.0]]), r"[-0-9.e]+"),  # singular (PSD only)
        (-np.eye(2), r"-1"),                             # negative definite
    ],
)
def test_batch_non_positive_definite_cov(matrix: np.ndarray, eig: str) -> None:
    cov = covs()
    cov[1] = matrix
    match = rf"Batch\.cov\[1\] is not positive definite \(smallest eigenvalue {eig}"
    with pytest.raises(InvalidInputError, match=match):
        Batch(np.zeros((2, 2)), cov, [0, 1], [-1, -1])


@pytest.mark.parametrize(("value", "eig"), [(0.0, "0"), (-0.5, "-0.5")])
def test_batch_non_positive_angle_variance(value: float, eig: str) -> None:
    # 1 × 1 covariances (AoA rows) are checked without a factorisation: the same refusal
    cov = np.array([[[0.1]], [[value]], [[0.2]]])
    match = rf"Batch\.cov\[1\] is not positive definite \(smallest eigenvalue {eig}\)"
    with pytest.raises(InvalidInputError, match=match):
        Batch(np.zeros((3, 1)), cov, [0, 1, 2], [1, 2, 0])
    Batch(np.zeros((3, 1)), np.abs(cov) + 1e-300, [0, 1, 2], [1, 2, 0])  # tiny but positive: accepted


def test_batch_empty_and_dim() -> None:
    empty = Batch.empty(3)
    assert len(empty) == 0 and empty.dim == 3
    assert empty.cov.shape == (0, 3, 3)
    assert empty.sensor.dtype == np.int64


# ----------------------------------------------------------------------------
# StateSet, StateLayout
# ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("ids", "mean", "cov", "match"),
    [
        ([1, 2], np.zeros((3, 4)), covs(2, 4),
         r"StateSet\.mean must have shape \(2, 4\), got \(3, 4\)"),
        ([1], np.zeros(4), covs(1, 4), r"StateSet\.mean must have shape \(1, \*\), got \(4,\)"),
        ([1, 2], np.zeros((2, 4)), covs(2, 3),
         r"StateSet\.cov must have shape \(2, 4, 4\), got \(2, 3, 3\)"),
        ([5, 1, 5], np.zeros((3, 2)), covs(3), r"StateSet\.ids has duplicate ids: \[5\]"),
        ([[1, 2]], np.zeros((2, 2)), covs(), r"StateSet\.ids must have shape \(\*\), got \(1, 2\)"),
    ],
)
def test_stateset_invalid(ids: Any, mean: Any, cov: Any, match: str) -> None:
    with pytest.raises(InvalidInputError, match=match):
        StateSet(ids, mean, cov)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_stateset_non_finite_mean(bad: float) -> None:
    mean = np.zeros((2, 4))
    mean[1, 2] = bad
    with pytest.raises(InvalidInputError, match=rf"StateSet\.mean\[1, 2\] is not finite: {bad}"):
        StateSet([1, 2], mean, covs(2, 4))


def test_stateset_non_spd_cov() -> None:
    cov = covs(2, 2)
    cov[0] = [[1.0, 0.0], [0.0, -2.0]]
    match = r"StateSet\.cov\[0\] is not positive definite \(smallest eigenvalue -2\)"
    with pytest.raises(InvalidInputError, match=match):
        StateSet([1, 2], np.zeros((2, 2)), cov)


def test_stateset_take_and_unknown_id() -> None:
    states = StateSet([4, 2, 9], np.arange(6.0).reshape(3, 2), covs(3))
    taken = states.take([9, 4])
    np.testing.assert_array_equal(taken.ids, [9, 4])
    np.testing.assert_array_equal(taken.mean, [[4.0, 5.0], [0.0, 1.0]])
    with pytest.raises(InvalidInputError, match=r"StateSet\.take: unknown ids \[7\]"):
        states.take([2, 7])


@pytest.mark.parametrize("states", [StateSet.empty(4), StateSet([3, 1], np.ones((2, 2)), covs())])
def test_stateset_dict_round_trip(states: StateSet) -> None:
    """Also for an empty set, whose dimension only the dict's "dim" entry carries."""
    back = StateSet.from_dict(states.to_dict())
    np.testing.assert_array_equal(back.ids, states.ids, strict=True)
    np.testing.assert_array_equal(back.mean, states.mean, strict=True)
    np.testing.assert_array_equal(back.cov, states.cov, strict=True)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"dim": 0, "position": (0,)}, r"StateLayout\.dim must be a positive integer, got 0"),
        ({"dim": 4, "position": (0, 4)},
         r"StateLayout indices must lie in \[0, 4\).*position=\(0, 4\)"),
        ({"dim": 4, "position": ()}, r"StateLayout indices must lie in \[0, 4\)"),
        ({"dim": 4, "position": (0, 1), "velocity": (1, 2)},
         r"StateLayout indices overlap: \[0, 1, 1, 2\]"),
        ({"dim": 3, "position": (0, 1), "heading": 5}, r"heading=5"),
    ],
)
def test_state_layout_invalid(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(InvalidInputError, match=match):
        StateLayout(**kwargs)


def test_state_layout_dict_round_trip() -> None:
    for layout in (StateLayout.position_velocity(2), StateLayout(3, (0, 1), None, 2)):
        assert StateLayout.from_dict(layout.to_dict()) == layout


# ----------------------------------------------------------------------------
# Frame
# ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"vehicles": [3, 1, 3]}, r"Frame\.vehicles has duplicate ids: \[3\]"),
        ({"vehicles": [[1, 2]]}, r"Frame\.vehicles must have shape \(\*\), got \(1, 2\)"),
        ({"links": [[1, 2, 3]]}, r"Frame\.links must have shape \(\*, 2\), got \(1, 3\)"),
        ({"links": [1, 2]}, r"Frame\.links must have shape \(\*, 2\), got \(2,\)"),
        ({"links": [[1, 2], [2, 9]]}, r"Frame\.links refer to vehicles not present: \[9\]"),
        ({"links": [[2, 2]]}, r"Frame\.links has self-links: \[\[2, 2\]\]"),
        ({"k": -1}, r"Frame\.k must be a non-negative integer, got -1"),
        ({"k": True}, r"Frame\.k must be a non-negative integer, got True"),
        ({"k": 1.5}, r"Frame\.k must be a non-negative integer, got 1\.5"),
        ({"t": np.nan}, r"Frame\.t.* is not finite: nan"),
        ({"batches": {"gnss": "not a batch"}},
         r"Frame\.batches must map kind names to Batch, got 'gnss': str"),
        ({"batches": {3: Batch.empty(2)}}, r"Frame\.batches must map kind names to Batch, got 3"),
    ],
)
def test_frame_invalid(kwargs: dict[str, Any], match: str) -> None:
    args = {"k": 0, "t": 0.0, "vehicles": [1, 2]}
    with pytest.raises(InvalidInputError, match=match):
        Frame(**{**args, **kwargs})


def test_frame_without_vehicles_and_batch_default() -> None:
    frame = Frame(4, 2.0, [])
    assert frame.vehicles.shape == (0,) and frame.links.shape == (0, 2)
    assert frame.batch("gnss", 2).z.shape == (0, 2)
    with pytest.raises(TypeError):
        frame.batches["gnss"] = Batch.empty(2)  # type: ignore[index]


# ----------------------------------------------------------------------------
# Truth, Setup, Recording
# ----------------------------------------------------------------------------


def truth(**changes: Any) -> Truth:
    args: dict[str, Any] = {
        "vehicle_ids": [0, 1],
        "vehicle_states": np.zeros((2, 2, 4)),
        "vehicle_present": np.ones((2, 2), dtype=bool),
        "feature_ids": [100],
        "feature_states": np.zeros((2, 1, 4)),
        "feature_present": np.ones((2, 1), dtype=bool),
        "origin": [{"gnss": [0, 1]}, {"gnss": [0, 1]}],
    }
    return Truth(**{**args, **changes})


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"vehicle_ids": [1, 1]}, r"Truth\.vehicle_ids has duplicate ids: \[1\]"),
        ({"feature_ids": [100, 100], "feature_states": np.zeros((2, 2, 4)),
          "feature_present": np.ones((2, 2), bool)},
         r"Truth\.feature_ids has duplicate ids: \[100\]"),
        ({"vehicle_states": np.zeros((2, 3, 4))},
         r"Truth\.vehicle_states must have shape \(2, 2, \*\), got \(2, 3, 4\)"),
        ({"vehicle_states": np.zeros((2, 4))},
         r"Truth\.vehicle_states must have shape \(T, N, dx\), got \(2, 4\)"),
        ({"vehicle_present": np.ones((3, 2), bool)},
         r"Truth\.vehicle_present must have shape \(2, 2\), got \(3, 2\)"),
        ({"origin": [{"gnss": [0, 1]}]}, r"Truth\.origin must have 2 steps, got 1"),
        ({"origin": [{"gnss": [0, 1]}, {"gnss": [[0, 1]]}]},
         r"Truth\.origin\[1\]\['gnss'\] must have shape \(\*\), got \(1, 2\)"),
        ({"sensor_poses": np.zeros((2, 2))},
         r"Truth\.sensor_poses must have shape \(\*, 3\), got \(2, 2\)"),
    ],
)
def test_truth_invalid(changes: dict[str, Any], match: str) -> None:
    with pytest.raises(InvalidInputError, match=match):
        truth(**changes)


def test_truth_non_finite_state() -> None:
    states = np.zeros((2, 2, 4))
    states[1, 0, 3] = np.inf
    match = r"Truth\.vehicle_states\[1, 0, 3\] is not finite: inf"
    with pytest.raises(InvalidInputError, match=match):
        truth(vehicle_states=states)


def setup(**changes: Any) -> Setup:
    args: dict[str, Any] = {
        "dt": 0.5,
        "n_steps": 2,
        "vehicle_layout": StateLayout.position_velocity(2),
        "vehicle_motion": ConstantVelocity(0.1),
        "vehicle_prior": StateSet([0, 1], np.zeros((2, 4)), covs(2, 4)),
        "sensors": {"gnss": GnssPosition(default_cov=np.eye(2))},
    }
    return Setup(**{**args, **changes})


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"dt": 0.0}, r"Setup\.dt must be a positive number of seconds, got 0\.0"),
        ({"dt": -1.0}, r"Setup\.dt must be a positive number of seconds, got -1\.0"),
        ({"dt": np.nan}, r"Setup\.dt must be a positive number of seconds, got nan"),
        ({"dt": np.inf}, r"Setup\.dt must be a positive number of seconds, got inf"),
        ({"n_steps": 0}, r"Setup\.n_steps must be a positive integer, got 0"),
        ({"n_steps": 2.5}, r"Setup\.n_steps must be a positive integer, got 2\.5"),
        ({"detection_probability": 0.0},
         r"Setup\.detection_probability must lie in \(0, 1\], got 0\.0"),
        ({"detection_probability": 1.5},
         r"Setup\.detection_probability must lie in \(0, 1\], got 1\.5"),
        ({"detection_probability": np.nan},
         r"Setup\.detection_probability must lie in \(0, 1\], got nan"),
        ({"clutter_rate": -1.0}, r"Setup\.clutter_rate must be >= 0, got -1\.0"),
        ({"clutter_region": [[1.0, -1.0]]}, r"Setup\.clutter_region needs lower < upper"),
        ({"birth_cov": np.eye(3)}, r"Setup\.birth_cov must have shape \(4, 4\), got \(3, 3\)"),
        ({"birth_cov": -np.eye(4)}, r"Setup\.birth_cov\[0\] is not positive definite"),
        ({"vehicle_layout": StateLayout(6, (0, 1))},
         r"Setup\.vehicle_motion has dimension 4, vehicle_layout\.dim is 6"),
        ({"vehicle_prior": StateSet([0], np.zeros((1, 2)), covs(1, 2))},
         r"Setup\.vehicle_prior\.mean must have 4 columns, got 2"),
        ({"feature_layout": StateLayout.position_velocity(2)},
         r"Setup\.feature_motion must be a motion model of dimension 4, got None"),
    ],
)
def test_setup_invalid(changes: dict[str, Any], match: str) -> None:
    with pytest.raises(InvalidInputError, match=match):
        setup(**changes)


def frames(n: int = 2, rows: int = 2) -> list[Frame]:
    return [Frame(k, 0.5 * k, [0, 1], {"gnss": eye_batch(rows)}) for k in range(n)]


def test_recording_valid() -> None:
    recording = Recording(setup(), frames(), truth())
    assert isinstance(recording.frames, tuple)


@pytest.mark.parametrize(
    ("build", "match"),
    [
        (lambda: Recording(setup(), frames(1), truth()),
         r"Recording\.frames has 1 frames, truth has 2 steps"),
        (lambda: Recording(setup(), frames(3), truth()),
         r"Recording\.frames has 3 frames, truth has 2 steps"),
        (lambda: Recording(setup(), frames(), truth(origin=[{"gnss": [0, 1]}, {"gnss": [0]}])),
         r"Recording\.truth\.origin\[1\]\['gnss'\] must have 2 rows, got 1"),
        (lambda: Recording(setup(), frames(), truth(origin=[{"gnss": [0, 1]}, {}])),
         r"Recording\.truth\.origin\[1\]\['gnss'\] must have 2 rows, got None"),
        (lambda: Recording(setup(), [frames()[0], frames()[0]], truth()),
         r"Recording\.frames\[1\]\.k must be 1, got 0"),
        (lambda: Recording(setup(), frames(),
                           truth(vehicle_present=np.array([[True, True], [True, False]]))),
         r"Recording\.frames\[1\]\.vehicles \[1\] are not present in truth"),
    ],
)
def test_recording_invalid(build: Any, match: str) -> None:
    with pytest.raises(InvalidInputError, match=match):
        build()


# ----------------------------------------------------------------------------
# property tests
# ----------------------------------------------------------------------------

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False, width=64)


@st.composite
def spd_batches(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """(z (m, d), cov (m, d, d)) with cov = A Aᵀ + εI, symmetric positive definite."""
    m = draw(st.integers(0, 6))
    d = draw(st.integers(1, 4))
    a = draw(hnp.arrays(np.float64, (m, d, d), elements=st.floats(-10, 10, width=64)))
    eps = draw(st.floats(1e-3, 1e2))
    cov = a @ a.transpose(0, 2, 1) + eps * np.eye(d)
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))
    z = draw(hnp.arrays(np.float64, (m, d), elements=finite))
    return z, cov


@settings(deadline=None, max_examples=60)
@given(spd_batches())
def test_random_spd_covariances_are_accepted(data: tuple[np.ndarray, np.ndarray]) -> None:
    z, cov = data
    m = z.shape[0]
    batch = Batch(z, cov, np.arange(m), np.full(m, -1))
    np.testing.assert_array_equal(batch.cov, cov)
    np.testing.assert_array_equal(batch.z, z)
    states = StateSet(np.arange(m) + 10, z, cov)
    np.testing.assert_array_equal(states.cov, cov)


@settings(deadline=None, max_examples=60)
@given(spd_batches(), st.data())
def test_batch_select_keeps_rows_consistent(data: tuple[np.ndarray, np.ndarray],
                                            draw: st.DataObject) -> None:
    z, cov = data
    m = z.shape[0]
    sensor = np.arange(m) * 3 + 1
    subject = np.arange(m) * 5 - 1
    batch = Batch(z, cov, sensor, subject)
    if draw.draw(st.booleans()):
        rows = np.asarray(draw.draw(st.lists(st.booleans(), min_size=m, max_size=m)), dtype=bool)
        index = np.flatnonzero(rows)
    else:
        index = np.asarray(draw.draw(st.lists(st.integers(0, max(m - 1, 0)),
                                              max_size=m if m else 0)), dtype=np.int64)
        rows = index
    sub = batch.select(rows)
    assert len(sub) == index.size and sub.dim == batch.dim
    # every selected row keeps its own z, cov, sensor and subject together
    np.testing.assert_array_equal(sub.z, z[index])
    np.testing.assert_array_equal(sub.cov, cov[index])
    np.testing.assert_array_equal(sub.sensor, sensor[index])
    np.testing.assert_array_equal(sub.subject, subject[index])
    np.testing.assert_array_equal((sub.sensor - 1) // 3, (sub.subject + 1) // 5)


@settings(deadline=None, max_examples=30)
@given(spd_batches())
def test_arrays_are_read_only_copies(data: tuple[np.ndarray, np.ndarray]) -> None:
    z, cov = data
    m = z.shape[0]
    sensor = np.arange(m)
    batch = Batch(z, cov, sensor, sensor)
    states = StateSet(sensor, z, cov)
    frame = Frame(0, 0.0, sensor, {"x": batch}, links=np.zeros((0, 2), int))
    arrays = [batch.z, batch.cov, batch.sensor, batch.subject, states.ids, states.mean,
              states.cov, frame.vehicles, frame.links]
    for array in arrays:
        assert not array.flags.writeable
        if array.size:
            with pytest.raises(ValueError, match="read-only"):
                array.flat[0] = 1
    # the caller's arrays stay theirs: changing them does not reach the containers
    if m:
        before = batch.z.copy()
        z[0, 0] += 1.0
        sensor[0] += 1
        np.testing.assert_array_equal(batch.z, before)
        assert batch.sensor[0] == 0 and frame.vehicles[0] == 0


def test_truth_arrays_are_read_only() -> None:
    t = truth()
    for name in ("vehicle_ids", "vehicle_states", "vehicle_present", "feature_ids",
                 "feature_states", "feature_present", "sensor_poses"):
        assert not getattr(t, name).flags.writeable, name
    assert not t.origin[0]["gnss"].flags.writeable
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.vehicle_ids = np.zeros(2, int)  # type: ignore[misc]


# ----------------------------------------------------------------------------
# Params.with_overrides (via FroehleParams)
# ----------------------------------------------------------------------------


def test_overrides_unknown_key_lists_valid_keys() -> None:
    with pytest.raises(ConfigError,
                       match=r"froehle2018: unknown key 'n_cars'; valid keys: n_vehicles, "
                             r"n_features, n_steps, dt, .*clutter_extent, shuffle$"):
        FroehleParams().with_overrides({"n_cars": "3"})


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        ({"n_vehicles": "abc"}, r"froehle2018: n_vehicles must be an integer, got 'abc'"),
        ({"n_vehicles": "0"}, r"froehle2018: n_vehicles must be >= 1, got 0"),
        ({"n_vehicles": "2.5"}, r"froehle2018: n_vehicles must be an integer, got '2\.5'"),
        ({"n_vehicles": 2.5}, r"froehle2018: n_vehicles must be an integer, got 2\.5"),
        ({"n_vehicles": True}, r"froehle2018: n_vehicles must be an integer, got True"),
        ({"gnss_variances": "1,x"},
         r"froehle2018: gnss_variances must be a comma-separated list of a number, got '1,x'"),
        ({"gnss_variances": ""},
         r"froehle2018: gnss_variances must have at least one entry, got \(\)"),
        ({"gnss_variances": "1,-2"},
         r"froehle2018: gnss_variances must have every entry in \[1e-12, 1\.6e\+15\] m², "
         r"got \(1\.0, -2\.0\)"),
        ({"gnss_variances": "1,2,3"},
         r"froehle2018: gnss_variances must have at most n_vehicles = 2 entries, "
         r"got \(1\.0, 2\.0, 3\.0\)"),
        ({"dt": "nan"}, r"froehle2018: dt must lie in \(0, 3600\], got nan"),
        ({"dt": "fast"}, r"froehle2018: dt must be a number, got 'fast'"),
        ({"detection_probability": "1.5"},
         r"froehle2018: detection_probability must lie in \(0, 1\], got 1\.5"),
        ({"shuffle": "maybe"}, r"froehle2018: shuffle must be true or false, got 'maybe'"),
    ],
)
def test_overrides_bad_value_names_the_key(overrides: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        FroehleParams().with_overrides(overrides)


def test_overrides_parse_strings_by_type() -> None:
    base = FroehleParams()
    params = base.with_overrides({"gnss_variances": "0.01,15", "n_vehicles": "4", "dt": "0.25",
                                  "shuffle": "false", "n_features": 5})
    assert params.gnss_variances == (0.01, 15.0)
    assert all(type(v) is float for v in params.gnss_variances)
    assert params.n_vehicles == 4 and type(params.n_vehicles) is int
    assert params.dt == 0.25 and params.shuffle is False and params.n_features == 5
    assert base == FroehleParams(), "with_overrides must not change the original"
    assert base.with_overrides({"gnss_variances": "[0.5]"}).gnss_variances == (0.5,)
    assert base.with_overrides({"gnss_variances": [1, 2]}).gnss_variances == (1.0, 2.0)
    assert base.with_overrides({"n_vehicles": 3.0}).n_vehicles == 3


def test_params_dict_round_trip_and_unknown_key() -> None:
    params = FroehleParams().with_overrides({"gnss_variances": "0.5,2,3", "n_vehicles": "3"})
    assert FroehleParams.from_dict(params.to_dict()) == params
    match = r"froehle2018: unknown key 'bogus'; valid keys: n_vehicles"
    with pytest.raises(ConfigError, match=match):
        FroehleParams.from_dict({"bogus": 1})
