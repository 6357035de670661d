"""`ExperimentConfig`: config.toml type errors are one-line `ConfigError`s naming key and value;
`with_overrides` (what `cooploc run --config` applies); `same_experiment` (issue 16, items 3 and 4)."""

from __future__ import annotations

import pytest

from cooploc.errors import ConfigError
from cooploc.experiment import ExperimentConfig

GOOD = ExperimentConfig.build("froehle2018", ["gnss-kf", "oracle-kf"], scenario_overrides={"n_steps": 10},
                              runs=2, seed=1, backend="serial").to_dict()


def _with(**changes):
    data = dict(GOOD)
    for key, value in changes.items():
        if value is ...:
            del data[key]
        else:
            data[key] = value
    return data


@pytest.mark.parametrize(("data", "match"), [
    (_with(estimators=["oracle-kf"]), r"estimators must be a table of estimator tables .*\['oracle-kf'\]"),
    (_with(estimators="oracle-kf"), r"estimators must be a table of estimator tables .*'oracle-kf'"),
    (_with(estimators={"gnss-kf": 3}), r"estimators\.gnss-kf must be a table of parameters, got 3"),
    (_with(estimators={"gnss-kf": ["a"]}), r"estimators\.gnss-kf must be a table of parameters"),
    (_with(estimators={"nope": {}}), r"unknown estimator 'nope'"),
    (_with(scenario_params=3), r"scenario_params must be a table of parameters, got 3"),
    (_with(scenario_params={"n_steps": "x"}), r"n_steps must be an integer, got 'x'"),
    (_with(scenario=3), r"scenario must be a preset name, got 3"),
    (_with(scenario=...), r"missing the key 'scenario'"),
    (_with(runs="10"), r"runs must be a positive integer, got '10'"),
    (_with(runs=2.5), r"runs must be a positive integer, got 2\.5"),
    (_with(runs=True), r"runs must be a positive integer, got True"),
    (_with(seed="1"), r"seed must be a non-negative integer, got '1'"),
    (_with(seed=-1), r"seed must be a non-negative integer, got -1"),
    (_with(backend=3), r"backend must be one of serial, processes, dask, got 3"),
    (_with(backend="threads"), r"backend must be one of serial, processes, dask, got 'threads'"),
    (_with(backend="processes", workers="2"), r"workers must be a positive integer, got '2'"),
    (_with(backend="processes", workers=True), r"workers must be a positive integer, got True"),
    (_with(workers=2), r"workers apply to the processes and dask backends, not serial; got workers = 2"),
    (_with(run=5), r"unknown key 'run'; valid keys: cooploc_version, scenario, runs"),
    ([1, 2], r"configuration must be a table of keys"),
])
def test_bad_config_is_one_line_naming_key_and_value(data, match):
    with pytest.raises(ConfigError, match=match) as info:
        ExperimentConfig.from_dict(data)
    assert "\n" not in str(info.value)


def test_good_config_round_trips():
    config = ExperimentConfig.from_dict(GOOD)
    assert config.to_dict() == GOOD


def test_scenario_params_left_out_are_the_presets():
    # a hand-written config.toml names a few keys; the rest are the preset's, not the
    # parameter class's defaults (which would put sumo-braunschweig-tlr on the grid)
    config = ExperimentConfig.from_dict({"scenario": "sumo-braunschweig-tlr", "estimators": {"gnss-kf": {}},
                                         "scenario_params": {"duration": 30.0}})
    assert config.scenario_params.network == "braunschweig"
    assert config.scenario_params.duration == 30.0
    partial = ExperimentConfig.from_dict({"scenario": "froehle2018", "estimators": {"gnss-kf": {}}})
    assert partial.scenario_params == ExperimentConfig.build("froehle2018", ["gnss-kf"]).scenario_params


def test_with_overrides_keeps_what_is_not_given():
    config = ExperimentConfig.from_dict(GOOD).with_overrides(
        ["oracle-kf", "kf-known-da"], scenario_overrides={"n_features": "4"},
        estimator_overrides={"oracle-kf": {"feature_timeout": "7"}}, seed=9)
    assert [e.name for e in config.estimators] == ["oracle-kf", "kf-known-da"]
    assert config.estimators[0].params.feature_timeout == 7
    assert (config.runs, config.seed, config.backend) == (2, 9, "serial")
    assert (config.scenario_params.n_steps, config.scenario_params.n_features) == (10, 4)


def test_with_overrides_refuses_est_set_of_an_estimator_not_run():
    with pytest.raises(ConfigError, match="--est-set names estimator 'oracle-kf', which is not in -e"):
        ExperimentConfig.from_dict(GOOD).with_overrides(
            ["gnss-kf"], estimator_overrides={"oracle-kf": {"feature_timeout": "7"}})


def test_backend_override_drops_workers_only_where_unused():
    parallel = ExperimentConfig.from_dict(_with(backend="processes", workers=2))
    assert parallel.with_overrides(backend="dask").workers == 2
    assert parallel.with_overrides(backend="serial").workers is None


def test_same_experiment_ignores_backend_and_workers_only():
    config = ExperimentConfig.from_dict(GOOD)
    assert config.same_experiment(config.with_overrides(backend="processes", workers=3))
    assert not config.same_experiment(config.with_overrides(runs=3))
    assert not config.same_experiment(config.with_overrides(scenario_overrides={"n_steps": 11}))


def test_read_names_the_file_when_it_is_missing_or_not_toml(tmp_path):
    import tomli_w

    with pytest.raises(ConfigError, match="no such file"):
        ExperimentConfig.read(tmp_path / "config.toml")
    (tmp_path / "config.toml").write_text("scenario = \n")
    with pytest.raises(ConfigError, match=r"config\.toml is not valid TOML"):
        ExperimentConfig.read(tmp_path / "config.toml")
    config = ExperimentConfig.build("froehle2018", ["gnss-kf"], runs=2, seed=3, backend="serial")
    (tmp_path / "config.toml").write_text(tomli_w.dumps(
        {k: v for k, v in config.to_dict().items() if v is not None}))
    assert ExperimentConfig.read(tmp_path / "config.toml") == config
