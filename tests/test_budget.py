"""Sizes and values checked up front (issue 16, item 6): the memory estimate of
`cooploc.budget`, and the physical bounds of `cooploc.scenarios.limits` on every family."""

from __future__ import annotations

import dataclasses
import typing

import numpy as np
import pytest

import cooploc
import cooploc.budget
from cooploc.budget import Sizes, check_memory, estimate_memory
from cooploc.errors import ConfigError, CooplocError
from cooploc.experiment import ExperimentConfig, run_one
from cooploc.params import Params

#: one preset per family (SUMO's Params are bounded too, but its runs take SUMO minutes)
FAMILIES = {"froehle2018": "gnss-kf", "zhang2016-ct2": "kf-known-da",  # its GNSS is anonymous
            "gulati-2v": "gnss-kf",
            "aoa-grid": "plbp", "brambilla-crossroad": "gnss-kf"}
SMALL = {"froehle2018": {"n_steps": 8}, "zhang2016-ct2": {"n_steps": 8}, "gulati-2v": {"n_steps": 8},
         "aoa-grid": {"n_vehicles": 12}, "brambilla-crossroad": {"n_steps": 6}}


def _config(scenario="froehle2018", names=("gnss-kf",), overrides=None, **kwargs) -> ExperimentConfig:
    return ExperimentConfig.build(scenario, list(names), scenario_overrides=overrides or {}, **kwargs)


def test_every_family_reports_its_sizes():
    for name, preset in cooploc.presets().items():
        sizes = preset.params.sizes()
        assert isinstance(sizes, Sizes) and sizes.n_steps >= 1 and sizes.n_vehicles >= 1, name


def test_memory_grows_with_steps_runs_and_the_joint_state():
    base, _ = estimate_memory(_config(runs=2, backend="serial"))
    assert estimate_memory(_config(overrides={"n_steps": 5010}, runs=2, backend="serial"))[0] > 5 * base
    assert estimate_memory(_config(runs=2000, backend="serial"))[0] > estimate_memory(
        _config(runs=200, backend="serial"))[0] > base
    need, what = estimate_memory(_config(names=("oracle-kf",), overrides={"n_features": 20000}, runs=1))
    dim = 4 * (2 + 20000)
    assert need >= 8 * dim**2 and "oracle-kf's state" in what  # the dense joint covariance


def test_a_streamed_recording_counts_only_what_it_keeps():
    """Long brambilla and SUMO runs make their frames on demand (`cooploc.streams`): their
    worker's recording is counted at the streamed rate, which tracemalloc measured."""
    short = _config("brambilla-crossroad", overrides={"n_steps": 1000}, runs=1, backend="serial")
    long = _config("brambilla-crossroad", overrides={"n_steps": 1001}, runs=1, backend="serial")
    assert not short.scenario_params.sizes().streamed and long.scenario_params.sizes().streamed
    assert estimate_memory(long)[0] < 0.5 * estimate_memory(short)[0]
    assert cooploc.presets()["sumo-grid-tlr"].params.sizes().streamed is False
    long_sumo = cooploc.presets()["sumo-grid-tlr"].params.with_overrides({"duration": 1000.0})
    assert long_sumo.sizes().streamed


def test_a_scenario_without_sizes_is_not_checked(monkeypatch):
    config = dataclasses.replace(_config(), scenario_params=Params())
    assert estimate_memory(config) == (0.0, "")
    monkeypatch.setattr(cooploc.budget, "available_memory", lambda: 1)
    check_memory(config)


def test_check_memory_compares_with_what_is_available(monkeypatch):
    config = _config(runs=10**6)
    need, _ = estimate_memory(config)
    monkeypatch.setattr(cooploc.budget, "available_memory", lambda: int(need * 2))
    check_memory(config)
    monkeypatch.setattr(cooploc.budget, "available_memory", lambda: int(need / 2))
    with pytest.raises(ConfigError, match=r"needs about .* of memory \(mostly the results of 1000000 runs\)"):
        check_memory(config)
    monkeypatch.setattr(cooploc.budget, "available_memory", lambda: None)
    check_memory(config)  # unknown: no check


def test_available_memory_is_known_here():
    have = cooploc.budget.available_memory()
    assert have is None or have > 10**6


def _float_fields(preset_name: str) -> list[str]:
    params = cooploc.get_preset(preset_name).params
    hints = typing.get_type_hints(type(params))
    return [f.name for f in dataclasses.fields(params) if hints[f.name] is float
            and f.name in type(params).constraints()]


@pytest.mark.parametrize("preset", sorted({*FAMILIES, "sumo-berlin-tlr"}))
@pytest.mark.parametrize("value", [1e300, 1e200, -1e300])
def test_overflowing_values_are_refused_with_the_valid_range(preset, value):
    params = cooploc.get_preset(preset).params
    for key in _float_fields(preset):
        with pytest.raises(ConfigError, match=rf"{key} must (lie in|be)") as info:
            params.with_overrides({key: value})
        assert "\n" not in str(info.value)


def _bounds(preset: str, key: str) -> list[float]:
    constraint = type(cooploc.get_preset(preset).params).constraints()[key]
    out = [b for b in (constraint.ge, constraint.le) if b is not None]
    out += [np.nextafter(b, np.inf) for b in (constraint.gt,) if b is not None]
    return out + [np.nextafter(b, -np.inf) for b in (constraint.lt,) if b is not None]


@pytest.mark.slow
@pytest.mark.parametrize("preset", sorted(FAMILIES))
def test_every_bound_runs_cleanly_or_is_refused_in_one_line(preset):
    """At each declared bound of each float field (one field at a time): a run with
    finite errors, or a one-line `CooplocError` — never another exception."""
    refused = []
    for key in _float_fields(preset):
        for value in _bounds(preset, key):
            try:
                config = _config(preset, [FAMILIES[preset]], {**SMALL[preset], key: value}, runs=1,
                                 backend="serial")
                result = run_one(config, 0)
            except CooplocError as exc:
                assert "\n" not in str(exc), (key, value, str(exc))
                refused.append((key, value))
                continue
            failure = result.failures.get(FAMILIES[preset])
            if failure is not None:  # the runner records an estimator's numerical failure
                assert "\n" not in failure.message, (key, value, failure.message)
                refused.append((key, value))
                continue
            errors = result.errors[FAMILIES[preset]]
            assert np.all(np.isfinite(errors.err_pos)), (key, value)
    assert len(refused) <= 5, refused  # cross-field checks (block_size <= grid_size ...) only


def test_time_floor_grows_with_the_cube_of_the_joint_state():
    from cooploc.budget import duration, estimate_seconds

    assert estimate_seconds(_config(names=("gnss-kf",), runs=20)) == 0.0  # declares nothing
    small = estimate_seconds(_config(names=("oracle-kf",), overrides={"n_features": 98}, runs=4,
                                     backend="serial"))
    large = estimate_seconds(_config(names=("oracle-kf",), overrides={"n_features": 198}, runs=4,
                                     backend="serial"))
    np.testing.assert_allclose(large / small, 8.0)  # D = 4 (2 + K): (800 / 400)³, exact arithmetic
    assert duration(90) == "1.5 min" and duration(2 * 86400) == "2 days"


def test_the_python_api_refuses_what_does_not_fit_before_writing(monkeypatch, tmp_path):
    """run_experiment and run_to_folder check memory too, not only the command line;
    run_to_folder before it writes anything."""
    from cooploc.experiment import run_experiment
    from cooploc.results import run_to_folder

    monkeypatch.setattr(cooploc.budget, "available_memory", lambda: 16 * 10**9)
    config = _config(names=("oracle-kf",), overrides={"n_features": 20000}, runs=1, backend="serial")
    with pytest.raises(ConfigError, match="of memory"):
        run_experiment(config)
    with pytest.raises(ConfigError, match="of memory"):
        run_to_folder(config, tmp_path / "out")
    assert not (tmp_path / "out").exists()
